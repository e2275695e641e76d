"""
The industry's current-vector controller (CVC), sensored, as a ROS-free law.

The design is motulator 0.18's ``CurrentVectorController`` (issue 43's plan, a.2-a.5), written
from its math in the stack's power-invariant units (τ = n_p Im(i_s ψ_s*)) and inverse-Γ
parameters (L_σ = L_s − L_sr²/L_r, L_M = θ L_sr, R_R = θ² R_r, ψ_R = θ φ_r, α = R_R/L_M). Space
vectors are Python complex numbers, x = x_α + j x_β in stator coordinates.

One call per control period t_k (:meth:`CurrentVectorController.compute`):

1. :class:`ReducedOrderFluxObserver` gives the estimates at t_k (ψ̂_R, the frame angle θ_c and
   speed ω_c) from the measured current and speed.
2. :class:`SpeedPI` makes the torque reference τ* from ω* and the measured speed.
3. The current reference in estimated rotor-flux coordinates: i_sd* = ψ_R*/L_M (ψ_R* =
   θ φ_r*), i_sq* = τ*/(n_p |ψ̂_R|), limited with d-axis priority by the current limit and by
   |ψ̂_R|/L_σ + i_sd*; the torque it gives, n_p |ψ̂_R| i_sq*, goes back to the speed PI.
4. :class:`ComplexPICurrentController` makes the voltage in observer coordinates; it is rotated
   to αβ with the angle advance e^{j k_comp T_s ω_c} (k_comp = delay + ½: the delay plus half a
   period of the hold) and limited to the v_limit circle.
5. The law's memory of the voltages it sent (an :class:`im_common.delay.CommandDelay` of the
   plant's length, filled by the first command as the plant's is) gives the command acting over
   [t_k, t_{k+1}], V_{k−d}: the observer integrates it, and the controllers' anti-windup takes
   the realized voltage centred on t_k, ½(V_{k−d−1} + V_{k−d}).
"""
from __future__ import annotations

import cmath
import math
from typing import Optional, Tuple

from im_common.delay import check_delay, CommandDelay
from im_common.params import MotorParams, THESIS_FLUX_LEVELS
from im_common.validation import check_real, InvalidParameter

from .gains import BaselineGains

#: the observer's speed-dependent damping of its gain k_o = 1 + K_DAMP |ω_m|/(α − jω_m)
K_DAMP = 0.2
#: below this Re(ψ̂_s ψ̂_R*) [Wb²] the observer takes no slip (no flux to orient on yet)
MIN_FLUX2 = 1e-10


def hold_equivalent(w: float, T_s: float) -> Tuple[complex, complex]:
    """
    Return (Φ, Γ) of dx/dt = −jw x + u over T_s with u held: Φ = e^{−jwT_s}, Γ = (1 − Φ)/(jw).

    Γ = T_s sinc(wT_s/2) e^{−jwT_s/2}, which is T_s at w = 0.
    """
    x = 0.5 * w * T_s
    sinc = math.sin(x) / x if x != 0.0 else 1.0
    return cmath.exp(-2j * x), T_s * sinc * cmath.exp(-1j * x)


class ReducedOrderFluxObserver:
    """
    Sensored reduced-order flux observer (Hinkkanen–Harnefors–Luomi 2010), the full one.

    The gain is motulator's sensored k_o = 1 + 0.2|ω_m|/(α − jω_m) with h = 1 (the measured
    speed, no speed-error signal): the correction blends the voltage model with the current model
    so that the estimation error decays as −(α − jω_m + 0.2|ω_m|) — the current model's pole
    damped by 0.2|ω_m| at speed. k_o = 1 would be the pure current model.

    State: the stator flux ψ̂_s in **observer coordinates** (rotating at the frame speed ω_c, at
    the angle θ_c), the current model's prediction ψ̂_R,pred made at the previous step, and θ_c.
    The frame speed is ω_c = ω_m + ω̂_r, ω̂_r = ω_rb Im(ψ̂_s ψ̂_R*)/Re(ψ̂_s ψ̂_R*) (= R_R i_q/|ψ_R|
    in the steady state), so the frame follows the estimated rotor flux. Discretized by the hold
    equivalent (:func:`hold_equivalent`): the voltage model is exact for a voltage held constant
    in stator coordinates, the current model holds its input in observer coordinates.
    """

    def __init__(self, motor: MotorParams, T_s: float):
        self.T_s = check_real('T_s', T_s, 0.0, lo_open=True)
        self.R_s = motor.R_s
        self.L_sigma = motor.L_sigma
        self.L_M = motor.L_M
        self.R_R = motor.R_R
        self.alpha = self.R_R / self.L_M
        self.w_rb = self.R_R * (1.0 / self.L_sigma + 1.0 / self.L_M)
        self.n_p = motor.pole_pairs
        self.psi_s = 0j             # ψ̂_s at t_k, observer coordinates
        self.psi_R_pred = 0j        # ψ̂_R at t_k as the current model predicted it at t_{k-1}
        self.theta_c = 0.0
        # the outputs at t_k (set by output())
        self.i = 0j
        self.psi_R = 0j
        self.omega_m = 0.0
        self.omega_c = 0.0

    def preset(self, psi_R: complex, i_s: complex = 0j) -> None:
        """Start from the rotor flux ψ_R (αβ) and the stator current i_s (αβ) as they are."""
        self.theta_c = cmath.phase(psi_R) if psi_R != 0 else 0.0
        mag = abs(psi_R)
        self.psi_s = mag + self.L_sigma * i_s * cmath.exp(-1j * self.theta_c)
        self.psi_R_pred = complex(mag)

    def output(self, i_s: complex, omega_M: float) -> complex:
        """
        Return ψ̂_R at t_k in αβ from the measured current i_s (αβ) and shaft speed ω_M.

        Sets :attr:`i`, :attr:`psi_R` (observer coordinates), :attr:`omega_c` for this step.
        """
        self.i = i_s * cmath.exp(-1j * self.theta_c)
        self.omega_m = self.n_p * omega_M
        self.psi_R = self.psi_s - self.L_sigma * self.i
        prod = self.psi_s * self.psi_R.conjugate()
        w_r = self.w_rb * prod.imag / prod.real if prod.real > MIN_FLUX2 else 0.0
        self.omega_c = self.omega_m + w_r
        return self.psi_R * cmath.exp(1j * self.theta_c)

    def correction(self, err: complex) -> complex:
        """Return the voltage model's correction by the current model's mismatch ``err``."""
        w_m = self.omega_m
        return (1.0 + K_DAMP * abs(w_m) / (self.alpha - 1j * w_m)) * err

    def update(self, u_zoh: complex) -> None:
        """Correct, then predict to t_{k+1} with the voltage u_zoh (αβ) held over the period."""
        T_s, w_m, w_c, i = self.T_s, self.omega_m, self.omega_c, self.i
        psi_s = self.psi_s + self.correction(self.psi_R_pred - self.psi_R)
        psi_R = psi_s - self.L_sigma * i
        u = u_zoh * cmath.exp(-1j * self.theta_c)
        phi, gam = hold_equivalent(w_c, T_s)
        self.psi_s = phi * (psi_s + T_s * u) - gam * self.R_s * i
        phi_r, gam_r = hold_equivalent(w_c - w_m, T_s)
        self.psi_R_pred = phi_r * psi_R + gam_r * (self.R_R * i - self.alpha * psi_R)
        self.theta_c = math.remainder(self.theta_c + T_s * w_c, 2.0 * math.pi)


class ComplexPICurrentController:
    """
    2DOF complex-vector PI current controller (Briz–Degner–Lorenz 2000), motulator's design.

    Continuous design, in the frame rotating at ω_c: u = k_t i* − k_p i + (k_i + jω_c k_t)/s
    (i* − i), which on L_σ di/dt = u − jω_c L_σ i gives i/i* = α_c/(s + α_c) exactly. Discrete
    realization in disturbance-estimate form, the anti-windup from the realized voltage u_real:

        v = u_i − (k_p − k_t) i,   u = k_t (i* − i) + v,   u_i ← u_i + T_s (α_i + jω_c)(u_real − v)

    with α_i = k_i/k_t.
    """

    def __init__(self, k_t: float, k_p: float, k_i: float, T_s: float):
        self.k_t, self.k_p, self.k_i, self.T_s = k_t, k_p, k_i, T_s
        self.alpha_i = k_i / k_t
        self.u_i = 0j
        self.v = 0j

    def output(self, i_ref: complex, i: complex) -> complex:
        """Return the voltage reference u for the reference i_ref and the current i."""
        self.v = self.u_i - (self.k_p - self.k_t) * i
        return self.k_t * (i_ref - i) + self.v

    def update(self, u_real: complex, omega_c: float) -> None:
        """Advance the integral state with the realized voltage u_real (same coordinates)."""
        self.u_i += self.T_s * (self.alpha_i + 1j * omega_c) * (u_real - self.v)

    def preset(self, u: complex, i: complex) -> None:
        """Set the integral state so that u is the output at i* = i (a steady start)."""
        self.u_i = u + (self.k_p - self.k_t) * i


def limit_to_circle(v: complex, v_limit: Optional[float]) -> complex:
    """Return v scaled onto the v_limit circle when beyond it (None: no limit)."""
    mag = abs(v)
    return v * (v_limit / mag) if v_limit is not None and mag > v_limit else v


class CommandOutput:
    """
    A law's voltage out, the one path of every baseline law (current-vector, flux-vector, V/Hz).

    :meth:`emit` rotates the observer-frame voltage u to αβ with the angle advance (the frame's
    turn over k_comp periods), limits it to the v_limit circle, and keeps the commands over the
    computational delay (:class:`im_common.delay.CommandDelay`). It returns (v, v_now, u_real):
    the command of step k (αβ), the command that acts over [t_k, t_k+1] (V_{k−d}, what the
    observer integrates) and the realized voltage centred on t_k in observer coordinates,
    ½(V_{k−d−1} + V_{k−d}) e^{−jθ_c} (what the integral states take).
    """

    def __init__(self, delay: int):
        self.line = CommandDelay(delay)
        self._v_prev: Optional[complex] = None     # V_{k-d-1}, the command that acted before

    def emit(self, u: complex, theta_c: float, advance: float,
             v_limit: Optional[float]) -> Tuple[complex, complex, complex]:
        """Return (v, v_now, u_real) of the voltage u (observer frame at θ_c; the class doc)."""
        v = limit_to_circle(u * cmath.exp(1j * (theta_c + advance)), v_limit)
        v_a, v_b = self.line.push(v.real, v.imag)
        v_now = complex(v_a, v_b)
        v_prev = v_now if self._v_prev is None else self._v_prev
        self._v_prev = v_now
        return v, v_now, 0.5 * (v_prev + v_now) * cmath.exp(-1j * theta_c)


class SpeedPI:
    """
    2DOF speed PI with anti-windup on the limited torque (motulator's speed controller).

    v = u_i − (k_p − k_t) ω + u_ff, τ* = clip(k_t (ω* − ω) + v, ±τ_max),
    u_i ← u_i + T_s α_i (τ_real − v), α_i = k_i/k_t, τ_real the torque the current reference
    realized. With k_t = α_s J, k_p = 2 α_s J, k_i = α_s² J on J dω/dt = τ: ω/ω* = α_s/(s + α_s);
    sampled, with the torque held over each period, ω_k/ω*_k = α_s T_s/(z − 1 + α_s T_s).
    """

    def __init__(self, k_t: float, k_p: float, k_i: float, T_s: float,
                 tau_max: Optional[float] = None):
        self.k_t, self.k_p, self.k_i, self.T_s = k_t, k_p, k_i, T_s
        self.alpha_i = k_i / k_t
        self.tau_max = math.inf if tau_max is None else tau_max
        self.u_i = 0.0
        self.v = 0.0

    def output(self, omega_ref: float, omega: float, u_ff: float = 0.0) -> float:
        """Return the torque reference τ* (limited to ±τ_max)."""
        self.v = self.u_i - (self.k_p - self.k_t) * omega + u_ff
        tau = self.k_t * (omega_ref - omega) + self.v
        return max(-self.tau_max, min(self.tau_max, tau))

    def update(self, tau_real: float) -> None:
        """Advance the integral state with the torque the drive realized."""
        self.u_i += self.T_s * self.alpha_i * (tau_real - self.v)


class SpeedLoop:
    """
    The speed PI around a law's torque mode: τ* from ω*, the law, the realized τ back (a mixin).

    Of :class:`CurrentVectorController` and the flux-vector controller: it reads ``speed`` (a
    :class:`SpeedPI`), ``compute_torque`` and the ``tau_ref`` the law realized.
    """

    def compute(self, t: float, i_alpha: float, i_beta: float, theta_r: float, omega_r: float,
                omega_ref: float, tau_ff: float = 0.0) -> Tuple[float, float]:
        """Return the voltage command (v_α, v_β) of step k (speed mode; τ_ff the PI's u_ff)."""
        tau = self.speed.output(omega_ref, omega_r, tau_ff)
        out = self.compute_torque(t, i_alpha, i_beta, theta_r, omega_r, tau)
        self.speed.update(self.tau_ref)
        return out


class CurrentVectorController(SpeedLoop):
    """
    The sensored current-vector controller: speed PI → current reference → complex PI (module doc).

    Parameters
    ----------
    motor : MotorParams
        The control model (its inverse-Γ parameters).
    T_s : float
        Control period [s].
    gains : BaselineGains
        Bandwidths (None: the defaults).
    delay : int
        Computational delay [periods] of the plant: the command of step k acts over step k + d.
    phi_r_ref : float
        Rotor-flux reference |φ_r*| [Wb] in the stack's units (ψ_R* = θ φ_r*).
    current_limit, v_limit : float or None
        Current-vector and voltage-vector magnitude limits [A], [V] (None: none).
    tau_max : float or None
        Torque limit of the speed PI [N·m] (None: none).

    """

    def __init__(self, motor: MotorParams, T_s: float, gains: Optional[BaselineGains] = None, *,
                 delay: int = 0, phi_r_ref: float = THESIS_FLUX_LEVELS['phi_d'],
                 current_limit: Optional[float] = None, v_limit: Optional[float] = None,
                 tau_max: Optional[float] = None):
        self.motor = motor
        self.T_s = check_real('T_s', T_s, 0.0, lo_open=True)
        self.gains = BaselineGains() if gains is None else BaselineGains.from_block(gains)
        self.delay = check_delay(delay)
        check_real('phi_r_ref', phi_r_ref, 0.0, lo_open=True)
        for name, value in (('current_limit', current_limit), ('v_limit', v_limit),
                            ('tau_max', tau_max)):
            check_real(name, value, 0.0, lo_open=True, allow_none=True)
        self.n_p = motor.pole_pairs
        self.L_sigma = motor.L_sigma
        self.L_M = motor.L_M
        self.psi_R_ref = motor.theta * phi_r_ref
        self.current_limit = current_limit
        self.v_limit = v_limit
        self.k_comp = self.gains.k_comp_for(self.delay)
        if current_limit is not None and self.psi_R_ref / self.L_M > current_limit:
            raise InvalidParameter('phi_r_ref', phi_r_ref,
                                   f'needs i_sd = {self.psi_R_ref / self.L_M:.4g} A, above the '
                                   f'current limit {current_limit:g} A')
        self.observer = ReducedOrderFluxObserver(motor, self.T_s)
        self.current = ComplexPICurrentController(*self.gains.current_gains(self.L_sigma),
                                                  self.T_s)
        self.speed = SpeedPI(*self.gains.speed_gains(motor.J), self.T_s, tau_max)
        self.out = CommandOutput(self.delay)
        # the last step's figures, for traces and tests
        self.i_ref = 0j             # i_s* in estimated rotor-flux coordinates [A]
        self.tau_ref = 0.0          # the torque the current reference realizes [N·m]
        self.psi_R_hat = 0j         # ψ̂_R at t_k, αβ [Wb]

    def preset(self, psi_R: complex, i_s: complex = 0j, omega_M: float = 0.0) -> None:
        """
        Start in the steady state: the observer at ψ_R (αβ), the PIs at i_s (αβ) and ω_M.

        The current integrator holds the steady voltage R_s i + jω_c ψ̂_s of the frame; the speed
        integrator the torque n_p Im(i ψ̂_R*) of the present current (a steady start under load).
        """
        obs = self.observer
        obs.preset(psi_R, i_s)
        obs.output(i_s, omega_M)
        u = self.motor.R_s * obs.i + 1j * obs.omega_c * obs.psi_s
        self.current.preset(u, obs.i)
        tau = self.n_p * (obs.i * obs.psi_R.conjugate()).imag
        self.speed.u_i = tau + (self.speed.k_p - self.speed.k_t) * omega_M

    def reference(self, tau_ref: float, psi_R_mag: float) -> Tuple[complex, float]:
        """
        Return (i_s*, τ) in rotor-flux coordinates for τ* at the flux |ψ̂_R| (d-axis priority).

        τ is the torque the limited reference gives, n_p |ψ̂_R| i_sq*.
        """
        i_sd = self.psi_R_ref / self.L_M
        i_sq = tau_ref / (self.n_p * psi_R_mag) if psi_R_mag > 0.0 else 0.0
        i_sq_max = psi_R_mag / self.L_sigma + i_sd
        if self.current_limit is not None:
            i_sd = min(i_sd, self.current_limit)
            i_sq_max = min(i_sq_max, math.sqrt(self.current_limit ** 2 - i_sd * i_sd))
        i_sq = max(-i_sq_max, min(i_sq_max, i_sq))
        return complex(i_sd, i_sq), self.n_p * psi_R_mag * i_sq

    def compute_torque(self, t: float, i_alpha: float, i_beta: float, theta_r: float,
                       omega_r: float, tau_ref: float) -> Tuple[float, float]:
        """Return the voltage command of step k for the torque reference τ* (torque mode)."""
        i_s = complex(i_alpha, i_beta)
        self.psi_R_hat = self.observer.output(i_s, omega_r)
        i_ref, self.tau_ref = self.reference(tau_ref, abs(self.observer.psi_R))
        return self._voltage(i_ref)

    def compute_current(self, t: float, i_alpha: float, i_beta: float, theta_r: float,
                        omega_r: float, i_sd_ref: float, i_sq_ref: float) -> Tuple[float, float]:
        """Return the voltage command of step k for a current reference in rotor-flux axes."""
        i_s = complex(i_alpha, i_beta)
        self.psi_R_hat = self.observer.output(i_s, omega_r)
        self.tau_ref = self.n_p * abs(self.observer.psi_R) * i_sq_ref
        return self._voltage(complex(i_sd_ref, i_sq_ref))

    def _voltage(self, i_ref: complex) -> Tuple[float, float]:
        """Run the current PI, rotate and limit its voltage, update the observer and the PI."""
        obs = self.observer
        self.i_ref = i_ref
        psi_R = obs.psi_R
        to_obs = psi_R / abs(psi_R) if psi_R != 0 else 1.0   # rotor-flux → observer coordinates
        u = self.current.output(i_ref * to_obs, obs.i)
        omega_c = obs.omega_c
        v, v_now, u_real = self.out.emit(u, obs.theta_c, self.k_comp * self.T_s * omega_c,
                                         self.v_limit)
        obs.update(v_now)
        self.current.update(u_real, omega_c)
        return v.real, v.imag
