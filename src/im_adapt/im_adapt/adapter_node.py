"""``ros2 run im_adapt adapter``: online estimates of R_r and θ = L_sr/L_r (seed 000 §4.2).

A thin shell around the adaptation law. At step k it waits for the measured current and speed,
the voltage command and the observer's estimate stamped t_k, updates the estimates, and publishes
p̂_k+1 stamped t_k+1 for the controller (eq. 4.10-4.12) and the observer (eq. 4.13).
With ``enable`` false it holds its estimates (and still keeps the lock-step); ``enable`` can be
switched while running.
"""
from __future__ import annotations

import sys

from rcl_interfaces.msg import SetParametersResult
from sensor_msgs.msg import JointState

from im_common import topics as T
from im_common.conversions import JointStateOut, period_ns, shaft_in, xy_in
from im_common.lockstep import LockstepNode, StepGate, lockstep_qos, node_main
from im_common.node_params import declare_motor, declare_run
from im_adapt.adaptation import declare_law


class AdapterNode(LockstepNode):
    """Online adaptation of the rotor resistance and of L_sr/L_r."""

    def __init__(self, **kwargs):
        super().__init__('adapter', **kwargs)
        self.T_s, self.duration, timeout, startup = declare_run(self)
        params = declare_motor(self, what='adapter model (nominal estimates)')
        p = self.param
        R_r0 = p('R_r_initial', float(params.R_r), 'initial estimate of R_r [ohm]', 1e-6, 100.0)
        theta0 = p('theta_initial', float(params.theta), 'initial estimate of L_sr/L_r', 1e-3, 1.0)
        self.enable = p('enable', False, 'adapt (true) or hold the initial estimates (false)',
                        read_only=False)
        self.law = declare_law(self, params, R_r0, theta0)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.period = period_ns(self.T_s)
        self.last_step = round(self.duration / self.T_s) if self.duration > 0 else None
        q = lockstep_qos()
        self.pub = self.create_publisher(JointState, T.ADAPT_ESTIMATE, q)
        self.out = JointStateOut(T.ESTIMATE_NAMES)
        self.gate = StepGate([T.MEAS_CURRENT, T.MEAS_SHAFT, T.CMD_VOLTAGE, T.OBS_FLUX],
                             self.period)
        for topic in (T.MEAS_CURRENT, T.CMD_VOLTAGE, T.OBS_FLUX):
            self.gate_input(topic, xy_in)
        self.gate_input(T.MEAS_SHAFT, shaft_in)
        self.start_watchdog(timeout, startup)
        self.publish_estimate(0)

    def ready(self, inputs) -> None:
        while inputs is not None and not self.done:
            self.mark_started()
            k = self.gate.expected // self.period
            if self.enable:
                i_a, i_b = inputs[T.MEAS_CURRENT]
                v_a, v_b = inputs[T.CMD_VOLTAGE]
                f_a, f_b = inputs[T.OBS_FLUX]
                try:
                    self.law.update(self.T_s, v_a, v_b, i_a, i_b, inputs[T.MEAS_SHAFT][1],
                                    f_a, f_b)
                except (ValueError, ArithmeticError) as exc:
                    self.fail(f'adapter failed at step {k} (t = {k * self.T_s:.9f} s): {exc}')
                    return
            self.publish_estimate(k + 1)
            if self.last_step is not None and k + 1 >= self.last_step:
                self.finish()
                return
            inputs = self.gate.advance()

    def _on_set_parameters(self, parameters):
        """``enable`` may be switched at run time (from the next step on)."""
        for prm in parameters:
            if prm.name == 'enable':
                if not isinstance(prm.value, bool):
                    return SetParametersResult(successful=False,
                                               reason="parameter 'enable' must be true or false")
                self.enable = prm.value
        return SetParametersResult(successful=True)

    def publish_estimate(self, k: int) -> None:
        e = self.law.estimates()
        self.pub.publish(self.out.fill(k * self.period, [e[n] for n in T.ESTIMATE_NAMES]))


def main(argv=None) -> None:
    sys.exit(node_main(AdapterNode, argv))


if __name__ == '__main__':
    main()
