"""
The induction-motor model: the one home of the plant's equations.

Stationary αβ frame, power-invariant transformation (seed 000 eq. 1.111-1.112 / 1.126-1.127).
The state is integrated in flux-linkage form so that time-varying inductances keep the energy
books consistent:

    x = [ψ_sα, ψ_sβ, φ_rα, φ_rβ, θ_r, ω_r]

    [ψ_s]   [L_s  L_sr] [i_s]          dψ_s/dt = V_s − R_s i_s
    [φ_r] = [L_sr L_r ] [i_r]          dφ_r/dt = −R_r i_r + v ω_r 𝒥₂ φ_r,   𝒥₂ = [[0, −1], [1, 0]]

    τ_m = v (L_sr/L_r)(i_sβ φ_rα − i_sα φ_rβ)          (eq. 1.127)
    J dω_r/dt = τ_m − b ω_r − τ_L(t, θ_r, ω_r),   dθ_r/dt = ω_r    (eq. 1.111)

With constant inductances, substituting i_r = (φ_r − L_sr i_s)/L_r gives exactly eq. 1.112
(γ, K, T_r of eq. 1.113); ``tests/test_model.py`` checks that equivalence numerically.

Power balance (exact, including time-varying inductances; W = ½ iᵀ L i the magnetic energy):

    V·i_s = R_s|i_s|² + R_r|i_r|² + τ_m ω_r + dW/dt + ½ iᵀ (dL/dt) i

The last term, P_param, is the power the parameter variation itself absorbs; it is zero for a
motor with constant inductances. The mechanical side: τ_m ω_r = b ω_r² + τ_L ω_r + d(½Jω_r²)/dt.

Core loss (eq. 3.34-3.38) is an *accounting model*: it does not act on the state (the thesis's
model has no core-loss branch), it is integrated beside it and reported with the losses, and it is
not part of the balance above. The thesis prints P_c = (k_h + k_e f_e) f_e φ^m with coefficients in
W·s/Wb²; the units call for φ^m squared, which is the default (``core_loss_exponent = 2``).
f_e is the electrical frequency of the air-gap flux, here taken from the actual rotation rate of
the rotor flux vector (the thesis uses v(ω_r + ω_sl) from the controller's slip, which is the same
quantity in steady state), and φ^m ≈ (L_sr/L_r)|φ_r| (eq. 3.38).
"""
from __future__ import annotations

import math
from typing import NamedTuple, Sequence, Tuple

import numpy as np

from .loads import Load, NoLoad
from .params import MotorParams, ParameterSchedule, THESIS_MOTOR

TWO_PI = 2.0 * math.pi

# Indices of the augmented state integrated by the plant.
PSI_SA, PSI_SB, PHI_RA, PHI_RB, THETA, OMEGA = range(6)
E_IN, E_CU_S, E_CU_R, E_CORE, E_FRICTION, W_LOAD, E_PARAM = range(6, 13)
N_STATE = 6
N_AUG = 13
ENERGY_NAMES = ('E_in', 'E_cu_s', 'E_cu_r', 'E_core', 'E_friction', 'W_load', 'E_param')


def currents(psi_sa, psi_sb, phi_ra, phi_rb, L_s, L_r, L_sr):
    """Return the stator and rotor currents of the flux linkages: (i_sα, i_sβ, i_rα, i_rβ)."""
    det = L_s * L_r - L_sr * L_sr
    i_sa = (L_r * psi_sa - L_sr * phi_ra) / det
    i_sb = (L_r * psi_sb - L_sr * phi_rb) / det
    i_ra = (L_s * phi_ra - L_sr * psi_sa) / det
    i_rb = (L_s * phi_rb - L_sr * psi_sb) / det
    return i_sa, i_sb, i_ra, i_rb


def stator_flux(i_sa, i_sb, phi_ra, phi_rb, L_s, L_r, L_sr):
    """ψ_s = σ L_s i_s + (L_sr/L_r) φ_r: the flux-linkage state from currents and rotor flux."""
    sls = L_s - L_sr * L_sr / L_r
    k = L_sr / L_r
    return sls * i_sa + k * phi_ra, sls * i_sb + k * phi_rb


class Eq112(NamedTuple):
    """Coefficients of eq. 1.112 (γ, K, 1/T_r of eq. 1.113) at one parameter point."""

    inv_sigma_Ls: float     # 1/(σL_s), the voltage gain of the current rows [1/H]
    gamma: float            # (R_s + R_r (L_sr/L_r)²)/(σL_s) = R_eq/(σL_s) [1/s]
    K: float                # L_sr/(σ L_s L_r) [1/H]
    inv_Tr: float           # R_r/L_r [1/s]
    L_sr: float             # [H]


def eq112_coefficients(R_s, R_r, L_s, L_r, L_sr) -> Eq112:
    """
    γ, K, 1/T_r of eq. 1.113 for the (i_s, φ_r) form of the electrical model (constant L).

    With i_r = (φ_r − L_sr i_s)/L_r the flux-linkage equations above become, with 𝒥 = [[0, −1], [1,
    0]] and ω_e = v ω_r,

        di_s/dt = −γ i_s + (K/T_r) φ_r − ω_e K 𝒥 φ_r + V/(σL_s)
        dφ_r/dt = (L_sr/T_r) i_s − φ_r/T_r + ω_e 𝒥 φ_r

    Raises ValueError when σL_s = L_s − L_sr²/L_r is not positive.
    """
    k = L_sr / L_r
    sigma_Ls = L_s - L_sr * k
    if not sigma_Ls > 0.0:
        raise ValueError(f'sigma*L_s = L_s - L_sr^2/L_r = {sigma_Ls:.4g} H must be > 0 '
                         f'(L_sr^2 < L_s L_r)')
    inv = 1.0 / sigma_Ls
    return Eq112(inv, (R_s + R_r * k * k) * inv, k * inv, R_r / L_r, L_sr)


def eq112_matrices(R_s, R_r, L_s, L_r, L_sr, pole_pairs, omega_r):
    """
    A(ω_r) (4×4) and B (4×2) of seed 000 eq. 1.112, numpy arrays.

    State ``[i_sα, i_sβ, φ_rα, φ_rβ]``, input ``[V_sα, V_sβ]``; see :func:`eq112_coefficients`.
    """
    c = eq112_coefficients(R_s, R_r, L_s, L_r, L_sr)
    we = pole_pairs * omega_r
    kf, ks, r_f = c.K * c.inv_Tr, we * c.K, c.L_sr * c.inv_Tr
    A = np.array([[-c.gamma, 0.0, kf, ks],
                  [0.0, -c.gamma, -ks, kf],
                  [r_f, 0.0, -c.inv_Tr, -we],
                  [0.0, r_f, we, -c.inv_Tr]])
    B = np.array([[c.inv_sigma_Ls, 0.0], [0.0, c.inv_sigma_Ls], [0.0, 0.0], [0.0, 0.0]])
    return A, B


def torque(i_sa, i_sb, phi_ra, phi_rb, L_r, L_sr, pole_pairs):
    """Electromagnetic torque τ_m = v (L_sr/L_r)(i_sβ φ_rα − i_sα φ_rβ) [N·m] (eq. 1.127)."""
    return pole_pairs * L_sr / L_r * (i_sb * phi_ra - i_sa * phi_rb)


class MotorModel:
    """
    Right-hand side of the plant: ``rhs(t, x, v_alpha, v_beta)`` on the augmented state.

    Parameters
    ----------
    schedule : ParameterSchedule or MotorParams
        Electrical parameters (possibly time-varying); J, b, v, k_e, k_h come from its base.
    load : Load
        Shaft load τ_L(t, θ, ω).
    core_loss_exponent : float
        Exponent of the air-gap flux in the core-loss model (2: the units of k_e, k_h).
    locked : bool
        The shaft is held (a locked-rotor test): dω_r/dt = 0 whatever the torque.

    """

    def __init__(self, schedule: ParameterSchedule | MotorParams = THESIS_MOTOR,
                 load: Load | None = None, core_loss_exponent: float = 2.0,
                 locked: bool = False):
        if isinstance(schedule, MotorParams):
            schedule = ParameterSchedule(schedule)
        self.schedule = schedule
        self.params = schedule.base
        self.load = load if load is not None else NoLoad()
        if core_loss_exponent not in (1.0, 2.0):
            raise ValueError('core_loss_exponent must be 1 or 2')
        self.core_loss_exponent = float(core_loss_exponent)
        self.locked = bool(locked)

    def rhs(self, t: float, x: Sequence[float], v_a: float, v_b: float) -> Tuple[float, ...]:
        """Time derivative of the 13-element augmented state (6 states + 7 energy integrals)."""
        R_s, R_r, L_s, L_r, L_sr = self.schedule.values(t)
        p = self.params
        vp = p.pole_pairs
        psi_sa, psi_sb, phi_ra, phi_rb, theta, omega = x[0], x[1], x[2], x[3], x[4], x[5]
        det = L_s * L_r - L_sr * L_sr
        i_sa = (L_r * psi_sa - L_sr * phi_ra) / det
        i_sb = (L_r * psi_sb - L_sr * phi_rb) / det
        i_ra = (L_s * phi_ra - L_sr * psi_sa) / det
        i_rb = (L_s * phi_rb - L_sr * psi_sb) / det
        we = vp * omega
        d_phi_ra = -R_r * i_ra - we * phi_rb
        d_phi_rb = -R_r * i_rb + we * phi_ra
        tau_m = vp * L_sr / L_r * (i_sb * phi_ra - i_sa * phi_rb)
        tau_l = self.load.torque(t, theta, omega)
        d_omega = 0.0 if self.locked else (tau_m - p.b * omega - tau_l) / p.J
        # Energy integrands.
        p_in = v_a * i_sa + v_b * i_sb
        p_cu_s = R_s * (i_sa * i_sa + i_sb * i_sb)
        p_cu_r = R_r * (i_ra * i_ra + i_rb * i_rb)
        flux2 = phi_ra * phi_ra + phi_rb * phi_rb
        if flux2 > 1e-18:
            f_e = abs(phi_ra * d_phi_rb - phi_rb * d_phi_ra) / (TWO_PI * flux2)
            k = L_sr / L_r
            phi_m = k * math.sqrt(flux2) if self.core_loss_exponent == 1.0 else k * k * flux2
            p_core = (p.k_h + p.k_e * f_e) * f_e * phi_m
        else:
            p_core = 0.0
        if self.schedule.inductances_constant:
            p_param = 0.0
        else:
            dL_s, dL_r, dL_sr = self.schedule.inductance_rates(t)
            p_param = 0.5 * (dL_s * (i_sa * i_sa + i_sb * i_sb)
                             + 2.0 * dL_sr * (i_sa * i_ra + i_sb * i_rb)
                             + dL_r * (i_ra * i_ra + i_rb * i_rb))
        return (v_a - R_s * i_sa, v_b - R_s * i_sb, d_phi_ra, d_phi_rb, omega, d_omega,
                p_in, p_cu_s, p_cu_r, p_core, p.b * omega * omega, tau_l * omega, p_param)

    def outputs(self, t: float, x: Sequence[float]) -> dict:
        """Currents, torque and stored energies at (t, x), for ground truth and tests."""
        R_s, R_r, L_s, L_r, L_sr = self.schedule.values(t)
        p = self.params
        i_sa, i_sb, i_ra, i_rb = currents(x[0], x[1], x[2], x[3], L_s, L_r, L_sr)
        tau_m = torque(i_sa, i_sb, x[2], x[3], L_r, L_sr, p.pole_pairs)
        w_mag = 0.5 * (i_sa * x[0] + i_sb * x[1] + i_ra * x[2] + i_rb * x[3])
        return {
            'i_alpha': i_sa, 'i_beta': i_sb, 'i_r_alpha': i_ra, 'i_r_beta': i_rb,
            'phi_r_alpha': x[2], 'phi_r_beta': x[3], 'theta_r': x[4], 'omega_r': x[5],
            'tau_m': tau_m, 'tau_L': self.load.torque(t, x[4], x[5]),
            'W_mag': w_mag, 'E_kin': 0.5 * p.J * x[5] * x[5],
            'R_s': R_s, 'R_r': R_r, 'L_s': L_s, 'L_r': L_r, 'L_sr': L_sr,
        }


def rk4_step(f, t: float, x: Sequence[float], h: float, v_a: float, v_b: float) -> list:
    """One classical Runge-Kutta step of ``f(t, x, v_a, v_b)`` with the input held (ZOH)."""
    n = len(x)
    k1 = f(t, x, v_a, v_b)
    h2 = 0.5 * h
    x2 = [x[i] + h2 * k1[i] for i in range(n)]
    k2 = f(t + h2, x2, v_a, v_b)
    x3 = [x[i] + h2 * k2[i] for i in range(n)]
    k3 = f(t + h2, x3, v_a, v_b)
    x4 = [x[i] + h * k3[i] for i in range(n)]
    k4 = f(t + h, x4, v_a, v_b)
    h6 = h / 6.0
    return [x[i] + h6 * (k1[i] + 2.0 * (k2[i] + k3[i]) + k4[i]) for i in range(n)]


# The real plant's model (docs/plant.md): inverse-Γ form, optional saturation and iron loss -------
#: the real plant's augmented state: the model's 13 plus the inverter's loss integral
E_INV = 13
N_AUG_REAL = 14


def iron_rotation(w0: float, R_R: float, k_h: float, k_e: float) -> float:
    """
    Return the rotation rate ω of ψ_R with the iron loss acting, from ω₀ without it (§3).

    2π f = sgn(ω₀) max(0, (4π²|ω₀| − 2π R_R k_h)/(4π² + R_R k_e)); the difference ω₀ − ω is
    the rate the iron-loss conductance takes off the flux's rotation (docs/plant.md §3).
    """
    c = TWO_PI * TWO_PI
    w = max(0.0, (c * abs(w0) - TWO_PI * R_R * k_h) / (c + R_R * k_e))
    return math.copysign(w, w0)


class RealMotorModel:
    """
    The plant's equations with main-flux saturation and an iron loss that acts (docs/plant.md).

    The same state as :class:`MotorModel` (ψ_s, φ_r, θ_r, ω_r and the energy integrals, plus the
    inverter's loss ``E_inv``), written in the inverse-Γ circuit of the motor's gauge θ =
    L_sr/L_r: rotor flux ψ_R = θ φ_r on the magnetizing inductance L_M (= L_sr²/L_r, or the
    curve of ``saturation``), leakage L_σ = L_s − L_M0, rotor resistance R_R = θ² R_r. With the
    magnetizing current i_μ = ψ_R/L_M(|ψ_R|), i_s = (ψ_s − ψ_R)/L_σ and the branch voltage e:

        dψ_s/dt = v − (R_s + r_on) i_s − d,        dψ_R/dt = e,
        e₀ = R_R (i_s − i_μ) + j ω_e ψ_R           (e without iron loss)

    ``iron_loss``: a conductance across the magnetizing branch acting on e's rotational part
    (the part that rotates ψ_R at ω_ψ); with P = (k_h + k_e f) f |ψ_R|² (the loss the ideal plant
    books, f = ω_ψ/2π) its conductance is g = (k_h + k_e f)/(4π² f), which solved with the branch
    gives ω_ψ in closed form: 2π f = sgn(ω₀) max(0, (2π|ω₀| − R_R k_h)/(4π² + R_R k_e))·2π with
    ω₀ = ψ_R × e₀/|ψ_R|² (docs/plant.md §3). The rotor current is i_R = i_s − i_μ − i_Fe and the
    torque τ = v ψ_R × i_R. ``fs``, ``fr`` scale R_s, R_r (the winding temperatures, set per
    period); ``drop`` (d) is the devices' on-state voltage vector and ``r_on`` their resistance,
    whose losses integrate into E_inv.
    """

    def __init__(self, schedule, load=None, core_loss_exponent: float = 2.0,
                 locked: bool = False, saturation=None, iron_loss: bool = False,
                 r_on: float = 0.0):
        base = MotorModel(schedule, load, core_loss_exponent, locked)
        self.schedule = base.schedule
        self.params = base.params
        self.load = base.load
        self.core_loss_exponent = base.core_loss_exponent
        self.locked = base.locked
        if not self.schedule.inductances_constant:
            raise ValueError('the real plant takes no time-varying inductance (the variation '
                             'of L_s, L_r or L_sr); vary R_s or R_r, or use the ideal plant')
        if iron_loss and self.core_loss_exponent != 2.0:
            raise ValueError('an acting iron loss needs core_loss_exponent 2 (a resistance '
                             'dissipates |psi|^2)')
        self.saturation = saturation
        self.iron_loss = bool(iron_loss)
        self.r_on = float(r_on)
        self.drop = (0.0, 0.0)
        self._const = None
        self._base = None
        self.set_temperature_factors(1.0, 1.0)

    def set_temperature_factors(self, fs: float, fr: float) -> None:
        """Scale R_s and R_r by ``fs``, ``fr`` (the winding temperatures; held over a period)."""
        self.fs = fs
        self.fr = fr
        if self.schedule.is_constant:
            if self._base is None:
                R_s, R_r, L_s, L_r, L_sr = self.schedule.values(0.0)
                th = L_sr / L_r
                self._base = (R_s, R_r * th * th, th, L_s - L_sr * th, 1.0 / (L_sr * th))
            R_s, R_R, th, L_sig, inv_LM0 = self._base
            self._const = (R_s * fs, R_R * fr, th, 1.0 / L_sig, inv_LM0)
            self._circuit = (R_s * fs, R_R * fr, th, L_sig, inv_LM0)

    @property
    def base_circuit(self):
        """
        Return the constant schedule's circuit without the temperature factors, else None.

        (R_s, R_R, θ, L_σ, 1/L_M0); None while the parameters vary in time (the compiled period
        of the real plant takes only a constant schedule).
        """
        return self._base if self._const is not None else None

    def circuit(self, t: float):
        """Return the inverse-Γ circuit at t: (R_s, R_R, θ, L_σ, 1/L_M0), R's at temperature."""
        if self._const is not None:
            return self._circuit
        R_s, R_r, L_s, L_r, L_sr = self.schedule.values(t)
        th = L_sr / L_r
        return R_s * self.fs, R_r * self.fr * th * th, th, L_s - L_sr * th, 1.0 / (L_sr * th)

    def currents(self, t: float, x: Sequence[float]):
        """
        Return (i_sα, i_sβ, i_Rα, i_Rβ): the stator current and the inverse-Γ rotor current.

        i_R = i_s − i_μ − i_Fe, the branch balance of :meth:`rhs` (what :meth:`outputs` gives
        as −i_r/θ), without the energy integrands: the real plant's per-period outputs.
        """
        R_s, R_R, th, L_sig, inv_LM0 = self.circuit(t)
        pa = th * x[2]
        pb = th * x[3]
        i_sa = (x[0] - pa) / L_sig
        i_sb = (x[1] - pb) / L_sig
        psi2 = pa * pa + pb * pb
        sat = self.saturation
        m = inv_LM0 if sat is None else sat.inv_L(math.sqrt(psi2))
        i_ra = i_sa - m * pa
        i_rb = i_sb - m * pb
        if self.iron_loss and psi2 > 1e-18:
            we = self.params.pole_pairs * x[5]
            w0 = (pa * (R_R * i_rb + we * pa) - pb * (R_R * i_ra - we * pb)) / psi2
            dw = (w0 - iron_rotation(w0, R_R, self.params.k_h, self.params.k_e)) / R_R
            i_ra += dw * pb
            i_rb -= dw * pa
        return i_sa, i_sb, i_ra, i_rb

    def _split(self, t, x):
        """Return the circuit at (t, x): R's, θ, L_σ, R_R, i_s, ψ_R, i_μ."""
        R_s, R_r, L_s, L_r, L_sr = self.schedule.values(t)
        th = L_sr / L_r
        L_M0 = L_sr * th
        L_sig = L_s - L_M0
        pa, pb = th * x[2], th * x[3]
        i_sa = (x[0] - pa) / L_sig
        i_sb = (x[1] - pb) / L_sig
        psi2 = pa * pa + pb * pb
        sat = self.saturation
        m = sat.inv_L(math.sqrt(psi2)) if sat is not None else 1.0 / L_M0
        return (R_s * self.fs, R_r * self.fr * th * th, th, L_sig, i_sa, i_sb, pa, pb, psi2,
                m * pa, m * pb, L_M0)

    def rhs(self, t: float, x: Sequence[float], v_a: float, v_b: float) -> Tuple[float, ...]:
        """Time derivative of the 14-element augmented state (6 states + 8 energy integrals)."""
        if self._const is None:
            R_s, R_R, th, L_sig, i_sa, i_sb, pa, pb, psi2, i_ma, i_mb, _ = self._split(t, x)
        else:                                   # constant parameters: the hot path
            R_s, R_R, th, inv_sig, inv_LM0 = self._const
            pa = th * x[2]
            pb = th * x[3]
            i_sa = (x[0] - pa) * inv_sig
            i_sb = (x[1] - pb) * inv_sig
            psi2 = pa * pa + pb * pb
            sat = self.saturation
            m = inv_LM0 if sat is None else sat.inv_L(math.sqrt(psi2))
            i_ma = m * pa
            i_mb = m * pb
        p = self.params
        vp = p.pole_pairs
        omega = x[5]
        we = vp * omega
        e_a = R_R * (i_sa - i_ma) - we * pb
        e_b = R_R * (i_sb - i_mb) + we * pa
        i_fa = i_fb = 0.0
        p_core = 0.0
        if psi2 > 1e-18:
            w0 = (pa * e_b - pb * e_a) / psi2          # rotation rate of ψ_R without iron loss
            if self.iron_loss:
                w = iron_rotation(w0, R_R, p.k_h, p.k_e)
                dw = (w0 - w) / R_R
                i_fa, i_fb = -dw * pb, dw * pa         # i_Fe = (e₀ − e)/R_R, along 𝒥ψ_R
                e_a -= (w0 - w) * -pb
                e_b -= (w0 - w) * pa
                p_core = dw * w * psi2
            else:                                      # booked, as MotorModel
                f_e = abs(w0) / TWO_PI
                phi_m = math.sqrt(psi2) if self.core_loss_exponent == 1.0 else psi2
                p_core = (p.k_h + p.k_e * f_e) * f_e * phi_m
        i_ra = i_sa - i_ma - i_fa
        i_rb = i_sb - i_mb - i_fb
        tau_m = vp * (pa * i_rb - pb * i_ra)
        theta = x[4]
        tau_l = self.load.torque(t, theta, omega)
        d_omega = 0.0 if self.locked else (tau_m - p.b * omega - tau_l) / p.J
        r_on = self.r_on
        va = v_a - r_on * i_sa
        vb = v_b - r_on * i_sb
        i2 = i_sa * i_sa + i_sb * i_sb
        da, db = self.drop
        return (va - R_s * i_sa, vb - R_s * i_sb, e_a / th, e_b / th, omega, d_omega,
                va * i_sa + vb * i_sb, R_s * i2, R_R * (i_ra * i_ra + i_rb * i_rb), p_core,
                p.b * omega * omega, tau_l * omega, 0.0, r_on * i2 + da * i_sa + db * i_sb)

    def stator_current(self, t: float, x: Sequence[float]):
        """Return (i_sα, i_sβ) = (ψ_s − θ φ_r)/L_σ at (t, x)."""
        _, _, th, L_sig, _ = self.circuit(t)
        return (x[0] - th * x[2]) / L_sig, (x[1] - th * x[3]) / L_sig

    def outputs(self, t: float, x: Sequence[float]) -> dict:
        """Currents, torque, stored energies and parameters at (t, x), as MotorModel.outputs."""
        R_s, R_R, th, L_sig, i_sa, i_sb, pa, pb, psi2, i_ma, i_mb, L_M0 = self._split(t, x)
        p = self.params
        d = self.rhs(t, x, 0.0, 0.0)
        # the rotor current in the model's gauge: i_r = −θ i_R (i_R from the branch balance)
        e_a, e_b = d[2] * th, d[3] * th
        we = p.pole_pairs * x[5]
        i_Ra = (e_a + we * pb) / R_R
        i_Rb = (e_b - we * pa) / R_R
        psi = math.sqrt(psi2)
        sat = self.saturation
        w_m = sat.energy(psi) if sat is not None else 0.5 * psi2 / L_M0
        R_s0, R_r0, L_s, L_r, L_sr = self.schedule.values(t)
        return {
            'i_alpha': i_sa, 'i_beta': i_sb, 'i_r_alpha': -th * i_Ra, 'i_r_beta': -th * i_Rb,
            'phi_r_alpha': x[2], 'phi_r_beta': x[3], 'theta_r': x[4], 'omega_r': x[5],
            'tau_m': p.pole_pairs * (pa * i_Rb - pb * i_Ra),
            'tau_L': self.load.torque(t, x[4], x[5]),
            'W_mag': 0.5 * L_sig * (i_sa * i_sa + i_sb * i_sb) + w_m,
            'E_kin': 0.5 * p.J * x[5] * x[5],
            'R_s': R_s, 'R_r': R_r0 * self.fr, 'L_s': L_s, 'L_r': L_r,
            'L_sr': L_sr if sat is None else L_sr * sat.L_M(psi) / L_M0,
        }

    def rk4(self, t: float, x: Sequence[float], h: float, v_a: float, v_b: float) -> list:
        """
        Return one RK4 step of :meth:`rhs` with the input held: the same as :func:`rk4_step`.

        The energy integrals do not feed back, so the intermediate stages carry the six states
        only; the 14 components combine at the end (the real plant's hot loop).
        """
        f = self.rhs
        h2 = 0.5 * h
        k1 = f(t, x, v_a, v_b)
        x2 = [x[0] + h2 * k1[0], x[1] + h2 * k1[1], x[2] + h2 * k1[2], x[3] + h2 * k1[3],
              x[4] + h2 * k1[4], x[5] + h2 * k1[5]]
        k2 = f(t + h2, x2, v_a, v_b)
        x3 = [x[0] + h2 * k2[0], x[1] + h2 * k2[1], x[2] + h2 * k2[2], x[3] + h2 * k2[3],
              x[4] + h2 * k2[4], x[5] + h2 * k2[5]]
        k3 = f(t + h2, x3, v_a, v_b)
        x4 = [x[0] + h * k3[0], x[1] + h * k3[1], x[2] + h * k3[2], x[3] + h * k3[3],
              x[4] + h * k3[4], x[5] + h * k3[5]]
        k4 = f(t + h, x4, v_a, v_b)
        h6 = h / 6.0
        return [a + h6 * (b + 2.0 * (c + d) + e) for a, b, c, d, e in zip(x, k1, k2, k3, k4)]
