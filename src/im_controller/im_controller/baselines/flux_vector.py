"""
The flux-vector controller (FVC), sensored, as a ROS-free law: stator flux and torque controlled.

The design is motulator 0.18's ``FluxVectorController`` (Tiitinen–Hinkkanen–Harnefors 2025, the
family of direct torque control: no current loop, the stator-flux magnitude and the torque are
the controlled quantities), written from its math in the stack's **power-invariant** units
(τ = n_p Im(i_s ψ_s*), no factor 3/2) and inverse-Γ parameters (L_σ, L_M, R_R; ψ_R = θ φ_r).
Space vectors are Python complex numbers, x = x_α + j x_β in stator coordinates. It is motulator's
*sensored* mode: the observer takes the shaft speed it is given (the drive gives the measured
speed, or the stack's estimate when it runs sensorless); motulator's own sensorless speed
estimation is not reproduced.

One call per control period t_k (:meth:`FluxVectorController.compute`):

1. :class:`~.current_vector.ReducedOrderFluxObserver` (the sensored gain k_o = 1 + 0.2|ω_m|/
   (α − jω_m), h = 1, as the current-vector controller's) gives ψ̂_s, ψ̂_R, the frame angle θ_c
   and speed ω_c = ω_m + ω̂_r at t_k.
2. :class:`~.current_vector.SpeedPI` makes the torque reference τ* from ω* and the speed
   (speed mode; the torque mode takes τ* as given).
3. The references (:meth:`FluxVectorController.flux_reference`, :meth:`~FluxVectorController.
   limit_torque`, motulator's reference generator): ψ_s* = min(ψ_s,nom, k_u v_limit/|ω_c|,
   L_σ i_max + |ψ̂_R|) (nominal, field weakening, current limit; each when its limit is given);
   τ* limited in magnitude by τ_max, by k_b times the breakdown torque τ_b = ½ n_p (L_M/(L_M +
   L_σ)) ψ_s*²/L_σ (power-invariant: motulator's 0.75 on peak-scaled fluxes is ½ here) and, with
   a current limit, by τ_cl = n_p |ψ̂_R| ψ_sq/L_σ, the torque with the stator flux on the ψ_s*
   circle within L_σ i_max of ψ̂_R: ψ_sd = (ψ_s*² + |ψ̂_R|² − (L_σ i_max)²)/(2|ψ̂_R|),
   ψ_sq = √(ψ_s*² − max(ψ_sd, 0)²) (0 without rotor flux). The limited τ* goes back to the speed
   PI's anti-windup.
4. :class:`~.vhz.FluxTorqueController` (a.6) with integral action α_i > 0 (motulator's default
   α_i = α_τ): u = R_s i + jω_c ψ̂_s + x_ψ t_ψ + x_τ t_τ − α_i(|ψ̂_s| t_ψ + τ̂ t_τ)
   + α_ψ(ψ_s* − |ψ̂_s|) t_ψ + α_τ(τ* − τ̂) t_τ in observer coordinates, the directions t_ψ, t_τ
   decoupling the channels. On the ideal model each channel is the first order α/(s + α) (the
   integral states only reject disturbances: with z = x_ψ − α_i|ψ_s|, dz/dt = −α_i z).
5. The voltage is rotated to αβ with the angle advance e^{j k_comp T_s ω_c} (k_comp = d + ½) and
   limited to the v_limit circle; the law's own :class:`im_common.delay.CommandDelay` gives the
   command acting over [t_k, t_{k+1}], V_{k−d}: the observer integrates it; the integral states
   take the realized voltage centred on t_k, ½(V_{k−d−1} + V_{k−d}) (the anti-windup).

Differences from motulator, by design: the stator-flux cap L_σ i_max + |ψ̂_R| and τ_cl apply
only when a current limit is given (motulator always has one); field weakening is
k_u v_limit/|ω_c| with a circular voltage clip (motulator: k_u u_dc/√3 and its PWM's
overmodulation; the same ψ_s* when v_limit = √(3/2) u_dc/√3, as the cross-check's
``--voltage-limit`` shows while the voltage is not clipped); the torque limit τ_max acts in the
reference generator (as motulator's ``tau_M_max``) in both modes, the speed PI itself has no
clip; the fallback directions without flux are :func:`~.vhz.flux_torque_directions`' (for
|c_τ| ≤ 1e-12; motulator's for c_τ ≤ 0). tools/crosscheck_flux_vector.py measures the rest.
"""
from __future__ import annotations

import math
from typing import Optional, Tuple

from im_common.delay import check_delay
from im_common.params import MotorParams, THESIS_FLUX_LEVELS
from im_common.validation import check_real, InvalidParameter, parameter_spec
from pydantic import Field

from .current_vector import CommandOutput, ReducedOrderFluxObserver, SpeedLoop, SpeedPI
from .gains import SpeedLoopGains
from .vhz import FluxTorqueController, nominal_stator_flux, StatorFluxReference

#: the torque channel's bandwidth α_τ, 2π·100 rad/s (motulator's FVC default; α_ψ, α_i = α_τ)
DEFAULT_ALPHA_TAU = 2.0 * math.pi * 100.0
#: node parameters of the optional bandwidths: 0 (alpha_psi) / -1 (alpha_i, where 0 is a value)
ALPHA_PSI_SENTINEL = parameter_spec(0.0, sentinels=((0.0, None, 'alpha_tau'),))
ALPHA_I_SENTINEL = parameter_spec(-1.0, sentinels=((-1.0, None, 'alpha_tau'),))


class FluxVectorGains(SpeedLoopGains):
    """The ``baseline:`` block of the flux-vector controller (SI, rad/s; the module doc)."""

    alpha_tau: float = Field(DEFAULT_ALPHA_TAU, gt=0, description='torque-channel bandwidth '
                             'alpha_tau [rad/s]')
    alpha_psi: Optional[float] = Field(None, gt=0, description='flux-channel bandwidth '
                                       'alpha_psi [rad/s] (None: alpha_tau)',
                                       json_schema_extra=ALPHA_PSI_SENTINEL)
    alpha_i: Optional[float] = Field(None, ge=0, description='integral bandwidth of the flux and '
                                     'torque channels [rad/s] (None: alpha_tau; 0: no integral '
                                     'action)', json_schema_extra=ALPHA_I_SENTINEL)
    k_u: float = Field(0.9, gt=0, le=1, description='share of v_limit the field weakening '
                       'allows')
    k_b: float = Field(0.9, gt=0, le=1, description='share of the breakdown torque the torque '
                       'reference may reach')

    @property
    def alpha_psi_value(self) -> float:
        """Return the flux-channel bandwidth [rad/s]."""
        return self.alpha_tau if self.alpha_psi is None else self.alpha_psi

    @property
    def alpha_i_value(self) -> float:
        """Return the integral bandwidth of the flux and torque channels [rad/s]."""
        return self.alpha_tau if self.alpha_i is None else self.alpha_i


def current_limited_torque(psi_s: float, psi_R: float, L_sigma: float, n_p: int,
                           i_max: float) -> float:
    """
    Return τ_cl [N·m]: the largest torque with |ψ_s| = psi_s and |i_s| ≤ i_max at |ψ_R| = psi_R.

    i_s = (ψ_s − ψ_R)/L_σ, so the stator flux lies within L_σ i_max of ψ_R; on the circle
    |ψ_s| = psi_s the torque n_p |ψ_R| ψ_sq/L_σ is largest where the two circles cross,
    ψ_sd = (psi_s² + psi_R² − (L_σ i_max)²)/(2 psi_R) (or on the q axis when ψ_sd < 0). 0 without
    rotor flux.
    """
    if psi_R <= 0.0:
        return 0.0
    psi_sd = (psi_s * psi_s + psi_R * psi_R - (L_sigma * i_max) ** 2) / (2.0 * psi_R)
    psi_sq = math.sqrt(max(psi_s * psi_s - max(psi_sd, 0.0) ** 2, 0.0))
    return n_p * psi_R * psi_sq / L_sigma


class FluxVectorController(SpeedLoop, StatorFluxReference):
    """
    The sensored flux-vector controller: speed PI → flux and torque references → a.6 (module doc).

    Parameters
    ----------
    motor : MotorParams
        The control model (its inverse-Γ parameters).
    T_s : float
        Control period [s].
    gains : FluxVectorGains or mapping
        The gains (None: the defaults).
    delay : int
        Computational delay [periods] of the plant: the command of step k acts over step k + d.
    phi_r_ref : float
        Rotor-flux level |φ_r| [Wb] whose unloaded stator flux is the initial ψ_s,nom
        (:func:`~.vhz.nominal_stator_flux`; the default φ_d gives ``nominal_stator_flux(motor)``).
    psi_s_nom : float or None
        Nominal stator flux [Wb], overriding phi_r_ref's (None: from phi_r_ref). The attribute
        :attr:`psi_s_nom` may be set between steps (the drive's flux strategy).
    current_limit, v_limit : float or None
        Current-vector and voltage-vector limits [A], [V] (None: none).
    tau_max : float or None
        Torque limit of the torque reference [N·m], both modes (None: none).

    """

    def __init__(self, motor: MotorParams, T_s: float, gains=None, *, delay: int = 0,
                 phi_r_ref: float = THESIS_FLUX_LEVELS['phi_d'],
                 psi_s_nom: Optional[float] = None, current_limit: Optional[float] = None,
                 v_limit: Optional[float] = None, tau_max: Optional[float] = None):
        self.motor = motor
        self.T_s = check_real('T_s', T_s, 0.0, lo_open=True)
        self.gains = FluxVectorGains() if gains is None else FluxVectorGains.from_block(gains)
        self.delay = check_delay(delay)
        self.psi_s_nom = (nominal_stator_flux(motor, phi_r_ref) if psi_s_nom is None
                          else check_real('psi_s_nom', psi_s_nom, 0.0, lo_open=True))
        for name, value in (('current_limit', current_limit), ('v_limit', v_limit),
                            ('tau_max', tau_max)):
            check_real(name, value, 0.0, lo_open=True, allow_none=True)
        self.current_limit, self.v_limit = current_limit, v_limit
        self.tau_max = math.inf if tau_max is None else tau_max
        self.n_p = motor.pole_pairs
        self.L_sigma = motor.L_sigma
        self.L_M = motor.L_M
        i_mag = self.psi_s_nom / (self.L_M + self.L_sigma)
        if current_limit is not None and i_mag > current_limit:
            raise InvalidParameter('psi_s_nom' if psi_s_nom is not None else 'phi_r_ref',
                                   psi_s_nom if psi_s_nom is not None else phi_r_ref,
                                   f'needs a magnetizing current of {i_mag:.4g} A, above the '
                                   f'current limit {current_limit:g} A')
        g = self.gains
        self.k_comp = g.k_comp_for(self.delay)
        self.observer = ReducedOrderFluxObserver(motor, self.T_s)
        self.control = FluxTorqueController(motor, self.T_s, g.alpha_psi_value, g.alpha_tau,
                                            g.alpha_i_value)
        self.speed = SpeedPI(*g.speed_gains(motor.J), self.T_s)
        self.out = CommandOutput(self.delay)
        # the last step's figures, for traces and tests
        self.tau_hat = 0.0          # τ̂ = n_p Im(i ψ̂_s*) at t_k [N·m]
        self.tau_ref = 0.0          # the limited torque reference [N·m]
        self.psi_ref = 0.0          # ψ_s* [Wb]
        self.psi_R_hat = 0j         # ψ̂_R at t_k, αβ [Wb]

    def preset(self, psi_R: complex, i_s: complex = 0j, omega_M: float = 0.0) -> None:
        """
        Start in the steady state: the observer at ψ_R and i_s (αβ), the integrators at ω_M.

        The flux-torque integral states hold the steady voltage R_s i + jω_c ψ̂_s (x_ψ = α_i|ψ̂_s|,
        x_τ = α_i τ̂); the speed integrator the torque of the present current.
        """
        obs = self.observer
        obs.preset(psi_R, i_s)
        obs.output(i_s, omega_M)
        tau = self.n_p * (obs.i * obs.psi_s.conjugate()).imag
        a_i = self.control.alpha_i
        self.control.x_psi = a_i * abs(obs.psi_s)
        self.control.x_tau = a_i * tau
        self.speed.u_i = tau + (self.speed.k_p - self.speed.k_t) * omega_M

    def limit_torque(self, tau_ref: float, psi_s: float, psi_R_mag: float) -> float:
        """Return τ* limited in magnitude by τ_max, k_b τ_b and τ_cl (module doc) [N·m]."""
        lim = min(self.tau_max, self.breakdown_torque(psi_s))
        if self.current_limit is not None:
            lim = min(lim, current_limited_torque(psi_s, psi_R_mag, self.L_sigma, self.n_p,
                                                  self.current_limit))
        return math.copysign(min(abs(tau_ref), lim), tau_ref) if tau_ref != 0.0 else 0.0

    def compute_torque(self, t: float, i_alpha: float, i_beta: float, theta_r: float,
                       omega_r: float, tau_ref: float) -> Tuple[float, float]:
        """Return the voltage command (v_α, v_β) of step k for the torque reference τ*."""
        obs = self.observer
        self.psi_R_hat = obs.output(complex(i_alpha, i_beta), omega_r)
        omega_c = obs.omega_c
        psi_R_mag = abs(obs.psi_R)
        self.tau_hat = self.n_p * (obs.i * obs.psi_s.conjugate()).imag
        self.psi_ref = self.flux_reference(omega_c, psi_R_mag)
        self.tau_ref = self.limit_torque(tau_ref, self.psi_ref, psi_R_mag)
        u = self.control.output(obs.i, obs.psi_s, obs.psi_R, omega_c, self.psi_ref,
                                self.tau_ref)
        v, v_now, u_real = self.out.emit(u, obs.theta_c, self.k_comp * self.T_s * omega_c,
                                         self.v_limit)
        obs.update(v_now)
        self.control.update(u_real)
        return v.real, v.imag
