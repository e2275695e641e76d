"""``ros2 run im_observer observer``: full-order rotor-flux observer (seed 000 eq. 3.27 / 4.13).

A thin shell around :class:`im_observer.observer.RotorFluxObserver`. At step k it waits for the
measured current and speed and the voltage command stamped t_k (and the adapter's estimates
stamped t_k when ``use_adapter``), integrates the observer over [t_k, t_k+1] and publishes the
estimate x̂_k+1 stamped t_k+1 — in parallel with the plant's own integration.
"""
from __future__ import annotations

import sys

from geometry_msgs.msg import Vector3Stamped

from im_common import topics as T
from im_common.conversions import Vector3Out, estimates_in, period_ns, shaft_in, xy_in
from im_common.lockstep import LockstepNode, StepGate, data_qos, lockstep_qos, node_main
from im_common.node_params import declare_motor, declare_run
from im_observer.observer import RotorFluxObserver


class ObserverNode(LockstepNode):
    """Full-order observer of stator currents and rotor fluxes."""

    def __init__(self, **kwargs):
        super().__init__('observer', **kwargs)
        self.T_s, self.duration, timeout, startup = declare_run(self)
        params = declare_motor(self, what='observer model (nominal estimates)')
        p = self.param
        k_e = p('k_e_injection', 0.0,
                'current-error injection gain k_e of eq. 3.27 [V/A] (0: the thesis value 1/sigma)',
                0.0, 1e6)
        gain = p('injection_gain', [0.0],
                 'discrete-time 4x2 injection gain, row-major, from design_gains ([0.0]: unused)')
        gain_period = p('gain_period', 0.0, 'period the injection_gain was designed for [s]',
                        0.0, 1.0)
        self.use_adapter = p('use_adapter', False,
                             'wait for and use the adapter estimates (eq. 4.13)')
        x0 = p('initial_state', [0.0, 0.0, 0.0, 0.0],
               'initial estimate [i_alpha, i_beta, phi_alpha, phi_beta] [A, Wb]')
        if len(x0) != 4:
            raise ValueError(f"invalid parameter 'initial_state' = {list(x0)!r}: 4 values")
        max_sub = p('max_substep', 1e-4, 'longest integration sub-step [s]', 1e-7, 0.1)
        self.publish_every = p('estimate_decimation', 10,
                               'publish the current estimate every N steps (the flux estimate is '
                               'published every step: the controller needs it)', 1, 1000000)
        gain = list(gain) if len(gain) == 8 else None
        if gain is not None and abs(gain_period - self.T_s) > 1e-12:
            raise ValueError(f"invalid parameter 'gain_period' = {gain_period!r}: the injection "
                             f"gain was designed for another period than T_s = {self.T_s}")
        self.obs = RotorFluxObserver(params, k_e=k_e or None, max_substep=max_sub, x0=tuple(x0),
                                     injection_gain=gain, gain_period=gain_period or None)
        self.period = period_ns(self.T_s)
        self.last_step = round(self.duration / self.T_s) if self.duration > 0 else None
        q = lockstep_qos()
        self.pub_flux = self.create_publisher(Vector3Stamped, T.OBS_FLUX, q)
        self.pub_current = self.create_publisher(Vector3Stamped, T.OBS_CURRENT, data_qos())
        self.out_flux, self.out_current = Vector3Out(), Vector3Out()
        required = [T.MEAS_CURRENT, T.MEAS_SHAFT, T.CMD_VOLTAGE]
        if self.use_adapter:
            required.append(T.ADAPT_ESTIMATE)
        self.gate = StepGate(required, self.period)
        self.gate_input(T.MEAS_CURRENT, xy_in)
        self.gate_input(T.MEAS_SHAFT, shaft_in)
        self.gate_input(T.CMD_VOLTAGE, xy_in)
        if self.use_adapter:
            self.gate_input(T.ADAPT_ESTIMATE, estimates_in)
        self.start_watchdog(timeout, startup)
        self.publish_estimate(0)

    def ready(self, inputs) -> None:
        while inputs is not None and not self.done:
            self.mark_started()
            self.step(inputs)
            inputs = self.gate.advance()

    def step(self, inputs: dict) -> None:
        k = self.gate.expected // self.period
        if self.use_adapter:
            self.obs.set_estimates(**inputs[T.ADAPT_ESTIMATE])
        v_a, v_b = inputs[T.CMD_VOLTAGE]
        i_a, i_b = inputs[T.MEAS_CURRENT]
        try:
            self.obs.step(self.T_s, v_a, v_b, i_a, i_b, inputs[T.MEAS_SHAFT][1])
        except (ValueError, ArithmeticError) as exc:
            self.fail(f'observer failed at step {k} (t = {k * self.T_s:.9f} s): {exc}')
            return
        self.publish_estimate(k + 1)
        if self.last_step is not None and k + 1 >= self.last_step:
            self.finish()

    def publish_estimate(self, k: int) -> None:
        ns = k * self.period
        i_a, i_b, f_a, f_b = self.obs.state
        self.pub_flux.publish(self.out_flux.fill(ns, f_a, f_b))
        if k % self.publish_every == 0 or (self.last_step is not None and k >= self.last_step):
            self.pub_current.publish(self.out_current.fill(ns, i_a, i_b))


def main(argv=None) -> None:
    sys.exit(node_main(ObserverNode, argv))


if __name__ == '__main__':
    main()
