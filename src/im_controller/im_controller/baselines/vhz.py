"""
The industry's V/Hz controllers (observer-based and open loop) as ROS-free laws.

The designs are motulator 0.18's ``ObserverBasedVHzController`` and its open-loop
parametrization (issue 43's plan, a.3, a.6, a.7), written from their math in the stack's
**power-invariant** units (τ = n_p Im(i_s ψ_s*), no factor 3/2: the breakdown torque's factor
(3/2)·(1/2) = 3/4 becomes 1/2) and inverse-Γ parameters (L_σ, L_M, R_R; ψ_R = θ φ_r). Space
vectors are Python complex numbers, x = x_α + j x_β in stator coordinates.

V/Hz sets the frequency, not the torque: the laws take the speed reference ω_M* (after an
optional rate limiter) and the measured current only — no speed, no position — so they do the
speed task only (:func:`check_task`).

**Observer-based V/Hz** (:class:`ObserverBasedVHz`), one call per control period t_k:

1. :class:`VHzFluxObserver`, the reduced-order flux observer with the *sensorless* gain
   k_o = (α/2 + 0.2|ω_m|)/(α − jω_m) and h = 0, given the speed *reference* as the rotor speed
   (ω_m = n_p ω_M*). It estimates the slip ω̂_r from the fluxes, so the frame speed
   ω_c = n_p ω_M* + ω̂_r is slip-compensated: in the steady state the shaft turns at ω_M*.
2. The stator-flux reference ψ_s* = min(ψ_s,nom, k_u v_limit/|ω_c|, L_σ i_max + |ψ̂_R|) (nominal,
   field weakening, current limit; each when its limit is given) and as torque reference the
   low-passed torque estimate τ̂_lpf (τ̂_lpf ← τ̂_lpf + T_s α_f (τ̂ − τ̂_lpf)), limited by the
   breakdown torque τ_b = ½ n_p k_b (L_M/(L_M + L_σ)) ψ_s*²/L_σ.
3. :class:`FluxTorqueController` (a.6) with α_i = 0: u = R_s i + jω_c ψ̂_s + α_ψ(ψ_s* − |ψ̂_s|) t_ψ
   + α_τ(τ* − τ̂) t_τ in observer coordinates. The torque channel, with τ* = τ̂_lpf, is a
   high-pass **active damping** (it tracks nothing); the flux channel holds |ψ̂_s| at ψ_s*.
4. The voltage is rotated to αβ with the angle advance e^{j k_comp T_s ω_c} (k_comp = d + ½: the
   computational delay plus half a period of the hold) and limited to the v_limit circle.
5. The law's memory of its commands (an :class:`im_common.delay.CommandDelay` of the plant's
   length, as the current-vector controller's) gives the command acting over [t_k, t_{k+1}],
   V_{k−d}: the observer integrates it; the integral states (α_i > 0 only) take the realized
   voltage centred on t_k, ½(V_{k−d−1} + V_{k−d}).

**Open-loop V/Hz** (:class:`OpenLoopVHz`). motulator obtains it from the same class with
L_M = ∞, L_σ = 0 (and R_R = 0): the observer's gain is k_o = 1 with h = 1, which with L_σ = 0
freezes ψ̂_s at its initial value ψ_s,nom (the pure current model of a rotor without resistance);
i_a = 0, ω̂_r = 0 and τ̂ = 0, so t_ψ = 1 and the flux channel's error is zero. What remains is
written here directly:

    u = R_s i + j n_p ω_M* ψ_s,nom     (observer coordinates, θ_c = ∫ n_p ω_M* dt)

V/Hz with the full-vector IR compensation (R_s = 0 gives the pure V/Hz law). It has no slip
compensation, so under a load the shaft runs slower than ω_M* by the slip, ω_r/n_p with
ω_r = R_R τ/(n_p |ψ_R|²) (:func:`open_loop_droop`). It cannot magnetize the motor at ω_M* = 0
(the compensation cancels the resistance, the stator flux stays where it is), and an
unmagnetized start leaves a stator-flux offset that nothing decays: start it magnetized
(:meth:`OpenLoopVHz.preset`).

**The nominal stator flux** (:func:`nominal_stator_flux`): by default the stator flux of the
unloaded motor whose rotor flux is the thesis's level φ_r = φ_d (:data:`THESIS_FLUX_LEVELS`,
1.2 Wb in the stack's units, ψ_R = θ φ_d): ψ_s,nom = ψ_R (L_M + L_σ)/L_M = (L_s/L_sr) φ_d
(1.2385 Wb on the thesis motor), so that the magnetizing current ψ_s,nom/(L_M + L_σ) = φ_d/L_sr
is the current-vector controller's i_sd*: the baselines compare at the same flux.
"""
from __future__ import annotations

import cmath
import math
from typing import Optional, Tuple

from im_common.delay import check_delay
from im_common.params import MotorParams, THESIS_FLUX_LEVELS
from im_common.validation import check_real, InvalidParameter, parameter_spec
from pydantic import Field

from .current_vector import CommandOutput, K_DAMP, limit_to_circle, ReducedOrderFluxObserver
from .gains import LawGains

#: the flux channel's bandwidth α_ψ, 2π·100 rad/s (a.7)
DEFAULT_ALPHA_PSI = 2.0 * math.pi * 100.0
#: the torque channel's bandwidth α_τ of V/Hz's active damping, 2π·20 rad/s (a.7)
DEFAULT_ALPHA_TAU = 2.0 * math.pi * 20.0
#: the bandwidth α_f of the torque estimate's low-pass filter, 2π·1 rad/s (a.7)
DEFAULT_ALPHA_F = 2.0 * math.pi * 1.0
#: the tasks V/Hz does: it sets the frequency, so it follows a speed and nothing else
VHZ_TASKS = ('speed',)
#: below this |c_τ| [N·m/Wb·...] the directions fall back to the flux axis (no flux yet)
MIN_C_TAU = 1e-12


class VHzGains(LawGains):
    """The V/Hz laws' gains, a ``baseline:`` block (SI, rad/s; the module doc)."""

    alpha_psi: float = Field(DEFAULT_ALPHA_PSI, gt=0, description='flux-channel bandwidth '
                             'alpha_psi [rad/s]')
    alpha_tau: float = Field(DEFAULT_ALPHA_TAU, ge=0, description='torque-channel bandwidth '
                             'alpha_tau [rad/s] (V/Hz: the active damping; 0: none)')
    alpha_f: float = Field(DEFAULT_ALPHA_F, gt=0, description='bandwidth of the low-pass '
                           'filter of the torque estimate [rad/s]')
    alpha_i: float = Field(0.0, ge=0, description='integral bandwidth of the flux and torque '
                           'channels [rad/s] (V/Hz: 0)')
    slew_rate: Optional[float] = Field(None, gt=0, description='rate limit of the speed '
                                       'reference [rad/s^2] (None: none)',
                                       json_schema_extra=parameter_spec(
                                           0.0, sentinels=((0.0, None, 'none'),)))
    k_u: float = Field(0.9, gt=0, le=1, description='share of v_limit the field weakening '
                       'allows')
    k_b: float = Field(0.9, gt=0, le=1, description='share of the breakdown torque the torque '
                       'reference may reach')


def check_task(task: str) -> str:
    """Return ``task`` if V/Hz can do it (speed), else one InvalidParameter line naming it."""
    if task not in VHZ_TASKS:
        raise InvalidParameter('controller', 'vhz', f'vhz: the {task!r} task is not possible, '
                                                    'V/Hz sets the frequency: speed only')
    return task


def nominal_stator_flux(motor: MotorParams,
                        phi_r: float = THESIS_FLUX_LEVELS['phi_d']) -> float:
    """Return the unloaded stator flux |ψ_s| [Wb] at the rotor flux |φ_r| (the module doc)."""
    check_real('phi_r', phi_r, 0.0, lo_open=True)
    return motor.theta * phi_r * (motor.L_M + motor.L_sigma) / motor.L_M


def open_loop_droop(motor: MotorParams, psi_s: float, tau: float) -> float:
    """
    Return the steady slip speed ω_r/n_p [rad/s] at the stator flux |ψ_s| and the torque τ.

    Steady state in rotor-flux axes: i_d = |ψ_R|/L_M, i_q = τ/(n_p|ψ_R|), ψ_s = ψ_R + L_σ i,
    so |ψ_s|² = k²x + (L_σ τ/n_p)²/x with x = |ψ_R|², k = 1 + L_σ/L_M; the stable (larger) root
    x = (|ψ_s|² + √(|ψ_s|⁴ − 4k²(L_σ τ/n_p)²))/(2k²). The slip ω_r = R_R i_q/|ψ_R|
    = R_R τ/(n_p x), in shaft speed ω_r/n_p. Raises ValueError beyond the breakdown torque.
    """
    n_p, L_s, L_M = motor.pole_pairs, motor.L_sigma, motor.L_M
    k = 1.0 + L_s / L_M
    a = L_s * tau / n_p
    disc = psi_s ** 4 - 4.0 * k * k * a * a
    if disc < 0.0:
        raise ValueError(f'tau = {tau:g} N m is beyond the breakdown torque at {psi_s:g} Wb')
    x = (psi_s * psi_s + math.sqrt(disc)) / (2.0 * k * k)
    return motor.R_R * tau / (n_p * x) / n_p


def sensorless_k_o(alpha: float, w_m: float) -> complex:
    """Return the sensorless observer gain k_o = (α/2 + 0.2|ω_m|)/(α − jω_m) (a.3)."""
    return (0.5 * alpha + K_DAMP * abs(w_m)) / (alpha - 1j * w_m)


class VHzFluxObserver(ReducedOrderFluxObserver):
    """
    The reduced-order flux observer with the sensorless gain and h = 0 (a.3), for V/Hz.

    As :class:`ReducedOrderFluxObserver` (its :meth:`output` gives ψ̂_R, the slip and ω_c), with
    the rotor speed given being the speed *reference*. The correction of the voltage model by the
    current model's mismatch e = ψ̂_R,pred − ψ̂_R is k_o e + k_o (ψ̂_R/ψ̂_R*) e* = 2 k_o ψ̂_R
    Re(e/ψ̂_R): only the mismatch along ψ̂_R (the flux magnitude) is corrected; the part across it,
    the speed-error signal, is dropped (h = 0 and no speed estimation), so the reference speed's
    error does not bend the flux estimate.
    """

    def correction(self, err: complex) -> complex:
        """Return k_o e + k_o (ψ̂_R/ψ̂_R*) e* (the class doc), the sensorless k_o."""
        k_o = sensorless_k_o(self.alpha, self.omega_m)
        rot = self.psi_R / self.psi_R.conjugate() if abs(self.psi_R) > 0.0 else 1.0
        return k_o * err + k_o * rot * err.conjugate()

    def torque(self) -> float:
        """Return the torque estimate τ̂ = n_p Im(i ψ̂_s*) at t_k (after :meth:`output`)."""
        return self.n_p * (self.i * self.psi_s.conjugate()).imag


def flux_torque_directions(psi_s: complex, psi_R: complex, L_sigma: float,
                           n_p: int) -> Tuple[complex, complex, complex]:
    """
    Return (t_ψ, t_τ, i_a): the flux and torque directions of the stator flux (a.6).

    i_a = ψ_R/L_σ, c_τ = n_p Re(i_a ψ_s*), t_ψ = n_p |ψ_s| i_a/c_τ, t_τ = jψ_s/c_τ, so that
    Re(t_ψ ψ_s*)/|ψ_s| = 1, Re(t_τ ψ_s*) = 0 (t_τ does not change |ψ_s|), and the torque
    gradient at a frozen ψ_R, n_p Im(dψ i_a*), is 0 along t_ψ and 1 along t_τ. Without flux
    (|c_τ| tiny) t_ψ is the flux axis ψ_s/|ψ_s| (1 at ψ_s = 0) and t_τ = 0.
    """
    i_a = psi_R / L_sigma
    c_tau = n_p * (i_a * psi_s.conjugate()).real
    mag = abs(psi_s)
    if abs(c_tau) <= MIN_C_TAU:
        return (psi_s / mag if mag > 0.0 else 1.0 + 0j), 0j, i_a
    return n_p * mag * i_a / c_tau, 1j * psi_s / c_tau, i_a


class FluxTorqueController:
    """
    Stator-flux and torque control with decoupled channels (Tiitinen–Hinkkanen–Harnefors; a.6).

    In observer coordinates (frame speed ω_c), with the directions of
    :func:`flux_torque_directions`:

        u_ff = R_s i + jω_c ψ̂_s + x_ψ t_ψ + x_τ t_τ − α_i(|ψ̂_s| t_ψ + τ̂ t_τ)
        u = u_ff + α_ψ(ψ_s* − |ψ̂_s|) t_ψ + α_τ(τ* − τ̂) t_τ

    so each channel is first order, d|ψ_s|/dt ≈ α_ψ(ψ_s* − |ψ_s|), dτ/dt ≈ α_τ(τ* − τ). The
    integral states take the realized voltage, Δu = u_real − u_ff: x_ψ ← x_ψ + T_s (α_i/|ψ̂_s|)
    Re(ψ̂_s Δu*), x_τ ← x_τ + T_s n_p α_i Re(j i_a Δu*). V/Hz runs it with α_i = 0 (no integral
    action; the states stay 0); α_i > 0 (the flux-vector controller's) is written but not yet
    exercised by this module's laws.
    """

    def __init__(self, motor: MotorParams, T_s: float, alpha_psi: float, alpha_tau: float,
                 alpha_i: float = 0.0):
        self.T_s = T_s
        self.R_s = motor.R_s
        self.L_sigma = motor.L_sigma
        self.n_p = motor.pole_pairs
        self.alpha_psi, self.alpha_tau, self.alpha_i = alpha_psi, alpha_tau, alpha_i
        self.x_psi = 0.0
        self.x_tau = 0.0
        self.u_ff = 0j
        self._psi_s = 0j
        self._i_a = 0j

    def output(self, i: complex, psi_s: complex, psi_R: complex, omega_c: float,
               psi_ref: float, tau_ref: float) -> complex:
        """Return the voltage u (observer coordinates) for the references ψ_s*, τ*."""
        t_psi, t_tau, i_a = flux_torque_directions(psi_s, psi_R, self.L_sigma, self.n_p)
        mag = abs(psi_s)
        tau = self.n_p * (i * psi_s.conjugate()).imag
        self.u_ff = (self.R_s * i + 1j * omega_c * psi_s + self.x_psi * t_psi
                     + self.x_tau * t_tau - self.alpha_i * (mag * t_psi + tau * t_tau))
        self._psi_s, self._i_a = psi_s, i_a
        return (self.u_ff + self.alpha_psi * (psi_ref - mag) * t_psi
                + self.alpha_tau * (tau_ref - tau) * t_tau)

    def update(self, u_real: complex) -> None:
        """Advance the integral states with the realized voltage u_real (observer coordinates)."""
        if not self.alpha_i:
            return
        du = u_real - self.u_ff
        mag = abs(self._psi_s)
        if mag > 0.0:
            self.x_psi += self.T_s * self.alpha_i / mag * (self._psi_s * du.conjugate()).real
        self.x_tau += self.T_s * self.n_p * self.alpha_i * (1j * self._i_a * du.conjugate()).real


class RateLimiter:
    """Limit the rate of a signal to ±rate per second (None: pass it through)."""

    def __init__(self, T_s: float, rate: Optional[float] = None, y0: float = 0.0):
        self.step = math.inf if rate is None else rate * T_s
        self.y = y0

    def __call__(self, u: float) -> float:
        """Return the limited signal for the input u (one control period on)."""
        self.y += max(-self.step, min(self.step, u - self.y))
        return self.y


class StatorFluxReference:
    """
    The stator-flux reference and torque bound of the laws that set the stator flux (motulator's).

    A mixin of :class:`ObserverBasedVHz` and the flux-vector controller: it reads ``psi_s_nom``,
    ``v_limit``, ``current_limit``, ``gains.k_u``, ``gains.k_b``, ``L_sigma``, ``L_M``, ``n_p``.
    """

    def flux_reference(self, omega_c: float, psi_R_mag: float) -> float:
        """Return ψ_s* = min(ψ_s,nom, k_u v_limit/|ω_c|, L_σ i_max + |ψ̂_R|) [Wb]."""
        psi = self.psi_s_nom
        if self.v_limit is not None and omega_c != 0.0:
            psi = min(psi, self.gains.k_u * self.v_limit / abs(omega_c))
        if self.current_limit is not None:
            psi = min(psi, self.L_sigma * self.current_limit + psi_R_mag)
        return psi

    def breakdown_torque(self, psi_s: float) -> float:
        """Return k_b τ_b = k_b ½ n_p (L_M/(L_M + L_σ)) ψ_s²/L_σ [N·m] (power-invariant units)."""
        return (0.5 * self.n_p * self.gains.k_b * self.L_M / (self.L_M + self.L_sigma)
                * psi_s * psi_s / self.L_sigma)


class _VHzBase:
    """What both V/Hz laws share: the checks, the rate limiter, the angle advance."""

    def __init__(self, motor: MotorParams, T_s: float, gains, delay: int,
                 psi_s_nom: Optional[float], v_limit: Optional[float]):
        self.motor = motor
        self.T_s = check_real('T_s', T_s, 0.0, lo_open=True)
        self.gains = VHzGains() if gains is None else VHzGains.from_block(gains)
        self.delay = check_delay(delay)
        self.psi_s_nom = (nominal_stator_flux(motor) if psi_s_nom is None
                          else check_real('psi_s_nom', psi_s_nom, 0.0, lo_open=True))
        self.v_limit = check_real('v_limit', v_limit, 0.0, lo_open=True, allow_none=True)
        self.n_p = motor.pole_pairs
        self.k_comp = self.gains.k_comp_for(self.delay)
        self.limiter = RateLimiter(self.T_s, self.gains.slew_rate)
        self.omega_ref = 0.0        # the limited speed reference of the last step [rad/s]

    @classmethod
    def for_task(cls, task: str, *args, **kwargs):
        """Return the law for ``task``; a task other than speed is one InvalidParameter line."""
        check_task(task)
        return cls(*args, **kwargs)


class ObserverBasedVHz(_VHzBase, StatorFluxReference):
    """
    The observer-based V/Hz controller: slip-compensated, actively damped (the module doc).

    Parameters
    ----------
    motor : MotorParams
        The control model (its inverse-Γ parameters).
    T_s : float
        Control period [s].
    gains : VHzGains or mapping
        The gains (None: the defaults).
    delay : int
        Computational delay [periods] of the plant: the command of step k acts over step k + d.
    psi_s_nom : float or None
        Nominal stator flux [Wb] (None: :func:`nominal_stator_flux` of the motor).
    v_limit, current_limit : float or None
        Voltage-vector and current-vector limits [V], [A] (None: none). The voltage is clipped
        to v_limit and the flux reference weakened to k_u v_limit/|ω_c|; the current limit caps
        the flux reference at L_σ i_max + |ψ̂_R| (what magnetizes a motor from rest).

    """

    def __init__(self, motor: MotorParams, T_s: float, gains=None, delay: int = 0,
                 psi_s_nom: Optional[float] = None, v_limit: Optional[float] = None,
                 current_limit: Optional[float] = None):
        super().__init__(motor, T_s, gains, delay, psi_s_nom, v_limit)
        self.current_limit = check_real('current_limit', current_limit, 0.0, lo_open=True,
                                        allow_none=True)
        g = self.gains
        self.L_sigma = motor.L_sigma
        self.L_M = motor.L_M
        self.observer = VHzFluxObserver(motor, self.T_s)
        self.control = FluxTorqueController(motor, self.T_s, g.alpha_psi, g.alpha_tau,
                                            g.alpha_i)
        self.out = CommandOutput(self.delay)
        self.tau_lpf = 0.0          # τ̂_lpf, the torque reference [N·m]
        # the last step's figures, for traces and tests
        self.tau_hat = 0.0          # τ̂ at t_k [N·m]
        self.tau_ref = 0.0          # the limited torque reference [N·m]
        self.psi_ref = 0.0          # ψ_s* [Wb]
        self.psi_R_hat = 0j         # ψ̂_R at t_k, αβ [Wb]

    def preset(self, psi_R: complex, i_s: complex = 0j, omega_M: float = 0.0) -> None:
        """Start in the steady state: the observer at ψ_R and i_s (αβ), ω_M* and τ̂_lpf as now."""
        obs = self.observer
        obs.preset(psi_R, i_s)
        obs.output(i_s, omega_M)
        self.tau_lpf = obs.torque()
        self.limiter.y = self.omega_ref = omega_M

    def compute(self, t: float, i_alpha: float, i_beta: float,
                omega_ref: float) -> Tuple[float, float]:
        """Return the voltage command (v_α, v_β) of step k for the speed reference ω_M*."""
        w = self.omega_ref = self.limiter(omega_ref)
        obs = self.observer
        self.psi_R_hat = obs.output(complex(i_alpha, i_beta), w)
        omega_c = obs.omega_c
        self.tau_hat = obs.torque()
        self.psi_ref = self.flux_reference(omega_c, abs(obs.psi_R))
        tau_b = self.breakdown_torque(self.psi_ref)
        self.tau_ref = max(-tau_b, min(tau_b, self.tau_lpf))
        u = self.control.output(obs.i, obs.psi_s, obs.psi_R, omega_c, self.psi_ref,
                                self.tau_ref)
        v, v_now, u_real = self.out.emit(u, obs.theta_c, self.k_comp * self.T_s * omega_c,
                                         self.v_limit)
        obs.update(v_now)
        self.control.update(u_real)
        self.tau_lpf += self.T_s * self.gains.alpha_f * (self.tau_hat - self.tau_lpf)
        return v.real, v.imag


class OpenLoopVHz(_VHzBase):
    """
    Open-loop V/Hz with IR compensation: u = R_s i + j n_p ω_M* ψ_s,nom (the module doc).

    The parameters are :class:`ObserverBasedVHz`'s (only α_ψ's channel is idle: the frozen flux
    estimate has no error, so of the gains only slew_rate and k_comp act), and ``R_s``, the
    resistance of the IR compensation (None: the motor's, motulator's parametrization; 0: pure
    V/Hz). The voltage is made in the frame at θ_c = ∫ n_p ω_M* dt and rotated to αβ with the
    angle advance e^{j k_comp T_s n_p ω_M*}; the delay acts through k_comp only (nothing here
    integrates the voltage).

    The full compensation cancels the stator resistance, the only damping of the stator-flux
    mode: on the thesis motor under load the speed then oscillates and grows (slowly with no
    delay, fast with one period), while R_s = 0 or a part of it settles
    (tests/test_baseline_vhz.py).
    """

    def __init__(self, motor: MotorParams, T_s: float, gains=None, delay: int = 0,
                 psi_s_nom: Optional[float] = None, v_limit: Optional[float] = None,
                 R_s: Optional[float] = None):
        super().__init__(motor, T_s, gains, delay, psi_s_nom, v_limit)
        self.R_s = motor.R_s if R_s is None else check_real('R_s', R_s, 0.0)
        self.theta_c = 0.0

    def preset(self, psi_s: complex, omega_M: float = 0.0) -> None:
        """Start with the frame on the stator flux ψ_s (αβ) and the speed reference at ω_M."""
        self.theta_c = cmath.phase(psi_s) if psi_s != 0 else 0.0
        self.limiter.y = self.omega_ref = omega_M

    def compute(self, t: float, i_alpha: float, i_beta: float,
                omega_ref: float) -> Tuple[float, float]:
        """Return the voltage command (v_α, v_β) of step k for the speed reference ω_M*."""
        w = self.omega_ref = self.limiter(omega_ref)
        omega_c = self.n_p * w
        rot = cmath.exp(-1j * self.theta_c)
        i = complex(i_alpha, i_beta) * rot
        u = self.R_s * i + 1j * omega_c * self.psi_s_nom
        advance = self.k_comp * self.T_s * omega_c
        v = limit_to_circle(u * cmath.exp(1j * (self.theta_c + advance)), self.v_limit)
        self.theta_c = math.remainder(self.theta_c + self.T_s * omega_c, 2.0 * math.pi)
        return v.real, v.imag
