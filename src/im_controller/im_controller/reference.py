"""
State reference model and voltage feedforward.

Seed 000 eq. 3.13, 3.21-3.22, 3.26, 3.29; 4.10-4.12.

The reference is written in the rotor-flux frame (dq, angle ρ) in terms of the torque τ* and the
rotor-flux magnitude φ* with their time derivatives, which is eq. 3.13 after the substitution
φ* = √(R_r τ*/(v ω_sl)) (eq. 3.22) — and has no singularity at τ* = 0 as long as φ* > 0:

    i_ds* = (φ* + T_r dφ*/dt)/L_sr        i_qs* = L_r τ*/(v L_sr φ*)
    i_dr* = −(dφ*/dt)/R_r                  i_qr* = −τ*/(v φ*)
    ω_sl  = R_r τ*/(v φ*²)                 (electrical slip angular frequency, rad/s)
    dρ/dt = v ω_r + ω_sl

These satisfy the constraints (3.7) torque = τ*, (3.8) φ_q = 0 and the rotor equations
(3.11)-(3.12). The slip of (3.13)/(3.19)/(3.22) is the *electrical* slip angular frequency: with it
(3.12) reads φ_d ω_sl + R_r i_qr = 0. (The printed (3.12) multiplies ω_sl by v, which contradicts
(3.13) for v ≠ 1; ω_sl^0 = R_r/(L_r√σ) of (3.19) minimizes the magnetic energy only as an
electrical slip.)

In αβ (eq. 3.26, stator currents and rotor fluxes): i* = e^{𝒥ρ}(i_ds*, i_qs*), φ* = e^{𝒥ρ}(φ*, 0).

Feedforward (eq. 3.29 with the measured speed, i.e. the (ω_r − ω_r*) term of (3.29) turns the
reference speed in 𝒞(ω_r, x*) into the measured one): the exact inverse of the stator equation

    V* = σL_s di*/dt + R_eq i* − (R_r L_sr/L_r²) φ* + v ω_r (L_sr/L_r) 𝒥 φ*,
    R_eq = R_s + R_r (L_sr/L_r)²,

which in the rotating frame (d/dt e^{𝒥ρ} y = e^{𝒥ρ}(ẏ + ρ̇ 𝒥 y)) is

    V_d* = σL_s (di_ds*/dt − ρ̇ i_qs*) + R_eq i_ds* − (R_r L_sr/L_r²) φ*
    V_q* = σL_s (di_qs*/dt + ρ̇ i_ds*) + R_eq i_qs* + v ω_r (L_sr/L_r) φ*.

Because dρ/dt uses the measured ω_r, the reference rotor flux obeys the plant's rotor equation
at the actual speed, so a motor started on the reference and fed V* stays on it (tested).
"""
from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Optional

from im_common.params import IDENTIFIABLE_NAMES, MotorParams, THESIS_MOTOR


@dataclass(frozen=True)
class ModelCoefficients:
    """
    Electrical coefficients of the (i_s, φ_r) model used by the controller (nominal or estimated).

    With the chapter-4 estimates (R̂_r, θ̂ = L̂_sr/L̂_r) and fixed R̂_s, L̂_s, L̂_sr, use
    :meth:`from_params` with ``R_r`` and ``theta``: then L̂_r = L̂_sr/θ̂, σ̂L̂_s = L̂_s − L̂_sr θ̂
    and R̂_eq = R̂_s + R̂_r θ̂², exactly the entries of D̂, R̂ in eq. 4.12. With the inverse-Γ
    estimates (L̂_M, R̂_R, L̂_σ, R̂_s) every coefficient follows them (``from_params(params,
    L_M=...)``).
    """

    R_s: float
    R_r: float
    L_s: float
    L_r: float
    L_sr: float
    v: int
    J: float
    b: float

    @classmethod
    def from_params(cls, params: MotorParams = THESIS_MOTOR, R_r: Optional[float] = None,
                    theta: Optional[float] = None, **identifiable) -> 'ModelCoefficients':
        """
        Return the coefficients of ``params`` with adapted estimates.

        The estimates come in one of two
        parametrizations:

        * ``R_r``, ``theta`` — the thesis's (eq. 4.10-4.12): L̂_s, L̂_sr stay, L̂_r = L̂_sr/θ̂;
        * ``L_M``, ``R_R``, ``L_sigma`` (and optionally ``R_s``) — the inverse-Γ parameters the
          terminals identify (docs/adaptation.md §1, §7), in the rotor gauge θ of ``params``
          (:meth:`MotorParams.with_identifiable`): every coefficient follows them.
        """
        if identifiable:
            unknown = set(identifiable) - set(IDENTIFIABLE_NAMES)
            if unknown:
                raise ValueError(f'estimate {sorted(unknown)[0]!r} is not an inverse-Gamma '
                                 'parameter (R_s, L_sigma, L_M, R_R)')
            if R_r is not None or theta is not None:
                raise ValueError("estimates: give either 'R_r'/'theta' (the thesis's "
                                 "parametrization) or 'L_M'/'R_R'/'L_sigma', not both")
            try:
                p = params.with_identifiable(**identifiable)
            except ValueError as exc:
                raise ValueError(f'estimate {exc}') from None
            return cls(p.R_s, p.R_r, p.L_s, p.L_r, p.L_sr, p.pole_pairs, p.J, p.b)
        Rr = params.R_r if R_r is None else float(R_r)
        Lr = params.L_r if theta is None else params.L_sr / float(theta)
        if not (math.isfinite(Rr) and Rr > 0.0):
            raise ValueError(f"estimate 'R_r' = {R_r!r} must be a positive finite resistance")
        if not (math.isfinite(Lr) and Lr > 0.0):
            raise ValueError(f"estimate 'theta' = {theta!r} must be positive and finite")
        if params.L_s * Lr - params.L_sr ** 2 <= 0.0:
            raise ValueError(f"estimate 'theta' = {theta!r} makes sigma = 1 - L_sr*theta/L_s <= 0")
        return cls(params.R_s, Rr, params.L_s, Lr, params.L_sr, params.pole_pairs, params.J,
                   params.b)

    @property
    def theta(self) -> float:
        return self.L_sr / self.L_r

    @property
    def sigma(self) -> float:
        return 1.0 - self.L_sr * self.L_sr / (self.L_s * self.L_r)

    @property
    def sigma_L_s(self) -> float:
        return self.L_s - self.L_sr * self.L_sr / self.L_r

    @property
    def R_eq(self) -> float:
        k = self.L_sr / self.L_r
        return self.R_s + self.R_r * k * k

    @property
    def k_phi(self) -> float:
        """R_r L_sr / L_r² [Ω/H]: the rotor-flux term of the stator equation."""
        return self.R_r * self.L_sr / (self.L_r * self.L_r)

    @property
    def T_r(self) -> float:
        return self.L_r / self.R_r

    @property
    def slip_min_energy(self) -> float:
        """ω_sl⁰ = R_r/(L_r √σ) [rad/s, electrical] (eq. 3.18-3.19)."""
        return self.R_r / (self.L_r * math.sqrt(self.sigma))


def dq_reference(c: ModelCoefficients, tau: float, dtau: float, phi: float, dphi: float,
                 ddphi: float):
    """
    Eq. 3.13 in flux form. Returns (i_ds, i_qs, di_ds, di_qs, i_dr, i_qr, omega_sl).

    ``phi`` must be > 0 (the flux strategies keep it ≥ φ_min).
    """
    L_sr, L_r, R_r, v = c.L_sr, c.L_r, c.R_r, c.v
    inv_phi = 1.0 / phi
    T_r = L_r / R_r
    i_ds = (phi + T_r * dphi) / L_sr
    di_ds = (dphi + T_r * ddphi) / L_sr
    g = L_r / (v * L_sr)
    i_qs = g * tau * inv_phi
    di_qs = g * (dtau - tau * dphi * inv_phi) * inv_phi
    i_dr = -dphi / R_r
    i_qr = -tau * inv_phi / v
    omega_sl = R_r * tau * inv_phi * inv_phi / v
    return i_ds, i_qs, di_ds, di_qs, i_dr, i_qr, omega_sl


def feedforward_dq(c: ModelCoefficients, i_ds: float, i_qs: float, di_ds: float, di_qs: float,
                   phi: float, rho_dot: float, omega_r: float):
    """Stator voltage (V_d*, V_q*) of eq. 3.29 in the reference frame (see module docstring)."""
    sLs = c.sigma_L_s
    R_eq = c.R_eq
    v_d = sLs * (di_ds - rho_dot * i_qs) + R_eq * i_ds - c.k_phi * phi
    v_q = sLs * (di_qs + rho_dot * i_ds) + R_eq * i_qs + c.v * omega_r * c.theta * phi
    return v_d, v_q


def reference_alpha_beta(c: ModelCoefficients, rho: float, i_ds: float, i_qs: float, phi: float):
    """Eq. 3.26: (i_α*, i_β*, φ_α*, φ_β*) from the dq reference at angle ρ."""
    cr, sr = math.cos(rho), math.sin(rho)
    return (cr * i_ds - sr * i_qs, sr * i_ds + cr * i_qs, cr * phi, sr * phi)


def torque_alpha_beta(c: ModelCoefficients, i_a: float, i_b: float, phi_a: float,
                      phi_b: float) -> float:
    """τ = v (L_sr/L_r)(i_β φ_α − i_α φ_β) (eq. 3.3)."""
    return c.v * c.theta * (i_b * phi_a - i_a * phi_b)


def steady_state(c: ModelCoefficients, tau: float, phi: float, omega_r: float,
                 rho: float = 0.0) -> dict:
    """
    Return the constant-torque, constant-flux operating point of the reference model.

    Returns the αβ state at angle ρ, the dq currents, the slip and the stator voltage — used to
    start a run on the reference (speed task) and by tests.
    """
    i_ds, i_qs, _, _, i_dr, i_qr, w_sl = dq_reference(c, tau, 0.0, phi, 0.0, 0.0)
    rho_dot = c.v * omega_r + w_sl
    v_d, v_q = feedforward_dq(c, i_ds, i_qs, 0.0, 0.0, phi, rho_dot, omega_r)
    i_a, i_b, p_a, p_b = reference_alpha_beta(c, rho, i_ds, i_qs, phi)
    cr, sr = math.cos(rho), math.sin(rho)
    return {'i_alpha': i_a, 'i_beta': i_b, 'phi_alpha': p_a, 'phi_beta': p_b,
            'i_ds': i_ds, 'i_qs': i_qs, 'i_dr': i_dr, 'i_qr': i_qr, 'omega_sl': w_sl,
            'rho_dot': rho_dot, 'v_alpha': cr * v_d - sr * v_q, 'v_beta': sr * v_d + cr * v_q}


def steady_losses(c: ModelCoefficients, tau: float, phi: float, omega_r: float,
                  k_e: float = 0.0, k_h: float = 0.0, core_exponent: float = 2.0) -> float:
    """
    Steady-state copper + core loss [W] at torque τ and rotor flux φ (eq. 3.34-3.38).

    Copper: R_s(i_ds² + i_qs²) + R_r i_qr²; core: (k_h + k_e f_e) f_e (θφ)^m with
    f_e = |v ω_r + ω_sl|/(2π) the rotation rate of the flux and θφ the air-gap flux of (3.38).
    """
    i_ds = phi / c.L_sr
    i_qs = c.L_r * tau / (c.v * c.L_sr * phi)
    i_qr = tau / (c.v * phi)
    w_sl = c.R_r * tau / (c.v * phi * phi)
    f_e = abs(c.v * omega_r + w_sl) / (2.0 * math.pi)
    phi_m = c.theta * phi
    core = (k_h + k_e * f_e) * f_e * (phi_m * phi_m if core_exponent == 2.0 else phi_m)
    return c.R_s * (i_ds * i_ds + i_qs * i_qs) + c.R_r * i_qr * i_qr + core
