"""
A baseline law in the thesis law's place inside :class:`im_controller.control_law.DriveController`.

The drive around the law stays the stack's: the same references (the thesis trajectories or
setpoints, their feedforward torque J θ̈* + b θ̇* + the load model), the same flux strategy
(its rotor-flux target, filtered and capped above base speed, docs/controller.md), the same
limits (v_limit, current_limit, torque_limit, speed_limit) and the inverter-error compensation
after them. What changes is how the voltage is made (docs/baselines.md):

* ``current_vector`` (:class:`~.current_vector.CurrentVectorController`): the speed PI takes
  ω_cmd = ω* (speed task) or ω* + α_p (θ* − θ) (position task, a P loop around it), clipped to
  ±speed_limit; with ``feedforward`` (the default) the reference's torque and the P path on the
  error are fed forward, as the thesis law gets them, else motulator's PI as shipped; the
  torque task gives τ* straight to the current reference. The rotor-flux reference is the
  strategy's, ψ_R* = θ φ*; the torque the strategy sizes the flux for is the one the law asked
  for at the previous step.
* ``flux_vector`` (:class:`~.flux_vector.FluxVectorController`): the stator flux and the torque
  controlled directly, no current loop; the speed and position loops and the feedforward as the
  current-vector controller's; the stator-flux reference is the unloaded stator flux of the
  strategy's rotor flux, (L_s/L_sr) φ*, sized for the torque the law asked for.
* ``vhz`` (:class:`~.vhz.ObserverBasedVHz`): the speed task only (ω* clipped to ±speed_limit;
  no torque_limit: it makes no torque reference); the stator-flux reference is
  the unloaded stator flux of the strategy's rotor flux, (L_s/L_sr) φ*, sized for the law's
  low-passed torque estimate.

Both start from the drive's state at the first step: the rotor flux the stack's observer
estimates (ψ_R = θ φ̂, zero on a demagnetized motor), the measured current and speed.
"""
from __future__ import annotations

import math
from typing import Optional, Tuple

from im_common.params import MotorParams, THESIS_FLUX_LEVELS
from im_common.validation import InvalidParameter

from .current_vector import CurrentVectorController
from .flux_vector import FluxVectorController, FluxVectorGains
from .gains import BaselineGains
from .vhz import nominal_stator_flux, ObserverBasedVHz, VHZ_TASKS, VHzGains

#: the control laws a drive can run: the thesis's and the baselines (ControllerConfig.law)
LAWS = ('thesis', 'current_vector', 'flux_vector', 'vhz')
#: each baseline's gains, the ``baseline:`` block of a run file (node parameters baseline.*)
GAINS = {'current_vector': BaselineGains, 'flux_vector': FluxVectorGains, 'vhz': VHzGains}
#: the baselines whose speed loop is a speed PI (the position loop and feedforward around it)
SPEED_PI_LAWS = ('current_vector', 'flux_vector')
#: the tasks of the baselines that cannot do every task (one refuses another in one line)
TASKS = {'vhz': VHZ_TASKS}


def gains_model(law: str):
    """Return the gains model of a baseline law (its ``baseline:`` block); None: the thesis's."""
    return GAINS.get(law)


def check_law_task(law: str, task: str, field: str = 'law') -> None:
    """Refuse, in one line naming ``field``, a task the law cannot do (V/Hz positioning)."""
    if law in TASKS and task not in TASKS[law]:
        raise InvalidParameter(field, law, f'{law} cannot do the {task!r} task: it does '
                               + ', '.join(TASKS[law]) + (
                                   ' (V/Hz sets the frequency: a speed, nothing else)'
                                   if law == 'vhz' else ''))


class BaselineDrive:
    """
    One baseline law and what it needs from the drive around it (the module doc).

    ``law``: ``current_vector`` or ``vhz``; ``motor``: the control model; ``gains``: the law's
    gains model or block (None: its defaults); ``mode``: the task; ``phi_max``: the largest flux
    the strategy asks (checked against the current limit); the limits as the drive's.
    """

    def __init__(self, law: str, motor: MotorParams, T_s: float, gains=None, *, delay: int = 0,
                 mode: str = 'speed', phi_max: float = THESIS_FLUX_LEVELS['phi_max'],
                 v_limit: Optional[float] = None,
                 current_limit: Optional[float] = None, torque_limit: Optional[float] = None,
                 speed_limit: Optional[float] = None):
        if law not in GAINS:
            raise InvalidParameter('law', law, 'not a baseline law (' + ', '.join(GAINS) + ')')
        check_law_task(law, mode)
        self.law, self.mode, self.motor = law, mode, motor
        self.speed_limit = speed_limit
        if law in SPEED_PI_LAWS:
            cls = CurrentVectorController if law == 'current_vector' else FluxVectorController
            self.ctl = cls(motor, T_s, gains, delay=delay, phi_r_ref=phi_max,
                           current_limit=current_limit, v_limit=v_limit, tau_max=torque_limit)
        else:
            if torque_limit is not None:
                raise InvalidParameter('torque_limit', torque_limit, 'vhz makes no torque '
                                       'reference to limit (its torque follows the load)')
            self.ctl = ObserverBasedVHz(motor, T_s, gains, delay=delay, v_limit=v_limit,
                                        current_limit=current_limit,
                                        psi_s_nom=nominal_stator_flux(motor, phi_max))
        self.gains = self.ctl.gains

    @property
    def torque(self) -> float:
        """Return the torque the law asks for now [N·m] (what the flux strategy sizes for)."""
        return self.ctl.tau_lpf if self.law == 'vhz' else self.ctl.tau_ref

    @property
    def rotor_flux(self) -> complex:
        """Return the law's own rotor-flux estimate ψ̂_R at the last step (αβ) [Wb]."""
        return self.ctl.psi_R_hat

    def preset(self, psi_R: complex, i_s: complex, theta: float, omega: float, theta_ref: float,
               omega_ref: float, tau_ff: float) -> None:
        """
        Start from the drive's state: rotor flux ψ_R (αβ), current i_s (αβ), shaft and references.

        The speed PI's integrator holds the torque of the present current less what the
        feedforward gives at the first step (a steady start stays steady).
        """
        ctl = self.ctl
        if self.law == 'vhz':
            ctl.preset(psi_R, i_s, self._speed_command(theta, theta_ref, omega_ref))
            return
        ctl.preset(psi_R, i_s, omega)
        ctl.speed.u_i -= self._speed_feedforward(tau_ff, theta, theta_ref, omega_ref)

    def _speed_command(self, theta: float, theta_ref: float, omega_ref: float) -> float:
        """Return ω_cmd: ω* (+ α_p (θ* − θ) in the position task), clipped to ±speed_limit."""
        w_cmd = omega_ref
        if self.mode == 'position':
            w_cmd += self.ctl.gains.alpha_p * (theta_ref - theta)
        if self.speed_limit is not None:
            w_cmd = max(-self.speed_limit, min(self.speed_limit, w_cmd))
        return w_cmd

    def _speed_feedforward(self, tau_ff: float, theta: float, theta_ref: float,
                           omega_ref: float) -> float:
        """Return the speed PI's u_ff: the reference's torque and (k_p − k_t) ω_cmd, or 0."""
        sp = self.ctl.speed
        if self.mode == 'torque' or not self.ctl.gains.feedforward:
            return 0.0
        return tau_ff + (sp.k_p - sp.k_t) * self._speed_command(theta, theta_ref, omega_ref)

    def voltage(self, t: float, i_s: complex, theta: float, omega: float, theta_ref: float,
                omega_ref: float, tau_ff: float, phi_ref: float) -> Tuple[float, float]:
        """
        Return the voltage command (v_α, v_β) of the step at t.

        From the measured current ``i_s`` (αβ), the shaft (θ, ω), the references (θ*, ω*, the
        feedforward torque τ_ff, or the torque setpoint in the torque task) and the strategy's
        rotor-flux reference |φ_r*| [Wb].
        """
        m, ctl = self.motor, self.ctl
        w_cmd = self._speed_command(theta, theta_ref, omega_ref)
        if self.law == 'vhz':
            ctl.psi_s_nom = nominal_stator_flux(m, phi_ref)
            return ctl.compute(t, i_s.real, i_s.imag, w_cmd)
        if self.law == 'current_vector':
            ctl.psi_R_ref = m.theta * phi_ref
        else:           # flux-vector: the unloaded stator flux of the strategy's rotor flux
            ctl.psi_s_nom = nominal_stator_flux(m, phi_ref)
        if self.mode == 'torque':
            return ctl.compute_torque(t, i_s.real, i_s.imag, theta, omega, tau_ff)
        return ctl.compute(t, i_s.real, i_s.imag, theta, omega, w_cmd,
                           self._speed_feedforward(tau_ff, theta, theta_ref, omega_ref))

    def references(self) -> dict:
        """Return the step's references: current and flux (αβ, dq), field angle ρ, slip."""
        psi = self.ctl.psi_R_hat
        rho = math.atan2(psi.imag, psi.real) if psi != 0 else 0.0
        turn = complex(math.cos(rho), math.sin(rho))
        m, obs = self.motor, self.ctl.observer
        if self.law == 'current_vector':
            i_dq = self.ctl.i_ref
            phi = self.ctl.psi_R_ref / m.theta
        else:       # no current reference: the magnetizing current of its stator flux's
            i_dq = complex(self.ctl.psi_ref / (m.L_M + m.L_sigma))
            phi = self.ctl.psi_ref * m.L_M / (m.theta * (m.L_M + m.L_sigma))
        i_ref = i_dq * turn
        return {'i_alpha_ref': i_ref.real, 'i_beta_ref': i_ref.imag, 'i_d_ref': i_dq.real,
                'i_q_ref': i_dq.imag, 'phi_alpha_ref': phi * turn.real,
                'phi_beta_ref': phi * turn.imag, 'rho': rho,
                'omega_sl': obs.omega_c - obs.omega_m}    # the law's own slip estimate
