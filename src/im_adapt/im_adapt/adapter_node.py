"""
``ros2 run im_adapt adapter``: online estimates of R_r and θ = L_sr/L_r (seed 000 §4.2).

A thin shell around the adaptation law. At step k it takes the measured current and speed, the
voltage command and the observer's estimate stamped t_k, updates the estimates, and publishes
p̂_k+1 stamped t_k+1 for the controller (eq. 4.10-4.12) and the observer (eq. 4.13).

The adapter *follows* the run (:mod:`im_common.lockstep`): when the controller and observer use its
estimates they wait for them, so it is on the critical path without needing a watchdog of its own;
when nobody uses them it is off the critical path, and if it falls behind or joins late it takes
what arrives, skips the steps it lost (counted and reported at the end, estimates held across the
gap) and never stops the run. With ``enable`` false it holds its estimates; ``enable`` can be
switched while running (``ros2 param set /adapter enable true``), from the next step on. With the
plant's computational ``delay`` d it takes the command of step k − d, the voltage the motor got
(im_common.delay): with ``overlap`` (the default) straight from its step gate, so it computes step
k beside the controller computing the command of step k; without, through its own delay line,
where a step it skipped leaves its command out.
"""
from __future__ import annotations

import sys

from im_adapt.adaptation import ParameterAdapter
from im_adapt.parameters import declare_law
from im_common import topics as T
from im_common.auth import Signer
from im_common.conversions import JointStateOut, period_ns, shaft_in, xy_in
from im_common.lockstep import LockstepNode, node_main, PARAMETERS, StepGate
from im_common.node_params import (declare_compensation, declare_delay, declare_motor,
                                   declare_run, live_refusal)
from im_common.params import InvalidParameter
from im_common.qos import writer
from rcl_interfaces.msg import SetParametersResult
from sensor_msgs.msg import JointState


class AdapterNode(LockstepNode):
    """Online adaptation of the rotor resistance and of L_sr/L_r."""

    critical = False

    def __init__(self, **kwargs):
        super().__init__('adapter', **kwargs)
        self.T_s, self.duration, timeout, startup = declare_run(self)
        blocks = {}
        params = declare_motor(self, what='adapter model (nominal estimates)', blocks=blocks)
        p = self.param
        R_r0 = p('R_r_initial', float(params.R_r), 'initial estimate of R_r [ohm]', 1e-6, 100.0)
        theta0 = p('theta_initial', float(params.theta), 'initial estimate of L_sr/L_r', 1e-3, 1.0)
        self.enable = p('enable', False, 'adapt (true) or hold the initial estimates (false)',
                        read_only=False)
        self._enable_next = None
        self.law = declare_law(self, params, R_r0, theta0)
        self.compensation = declare_compensation(self)
        self.delay, lag = declare_delay(self)
        self.overlapped = bool(lag)     # the gate gives the acting command: no line to push
        sensorless = p('sensorless', False, "take the observer's speed estimate "
                       f'({T.OBS_SPEED}) in place of the measured shaft and hold R_R '
                       '(docs/sensorless.md)')
        tracking = p('thermal_tracking', False, "the windings' temperatures, heated by the "
                     "drive's losses through the motor file's thermal block, carry R_s and R_R: "
                     'sensorless they are the estimates, sensored they move the least-squares '
                     "estimates between updates (R_s the stator network's alone unless "
                     'estimate_stator_resistance; law improved; docs/adaptation.md §9)')
        if tracking and blocks.get('thermal') is None:
            raise InvalidParameter('thermal_tracking', True, "needs the motor file's thermal "
                                   'block (run-file key thermal: motor)')
        if tracking and not self.law.improved:
            raise InvalidParameter('thermal_tracking', True, "needs law 'improved' (law "
                                   "'thesis' estimates neither R_s nor R_R's temperature)")
        thermal = blocks['thermal'] if tracking else None      # thermal.*: a Thermal
        if sensorless or tracking:  # sensorless: R_R and the speed meet only in the slip
            self.law = ParameterAdapter(params, self.law.gains, R_r0, theta0,
                                        sensorless=sensorless, thermal=thermal)
        if tracking and not sensorless:
            self.get_logger().info("R_s, R_R carried by the windings' temperatures between the "
                                   "least squares' updates (docs/adaptation.md §9)")
        if sensorless:
            held = ('R_R' if self.law.improved else 'R_r')
            est = ('R_s, L_sigma, L_M' if self.law.improved else 'theta')
            if tracking:
                self.get_logger().info("sensorless: R_s, R_R at the windings' temperatures, "
                                       'estimating L_sigma, L_M (docs/adaptation.md §9)')
            else:
                self.get_logger().info(f'sensorless: {held} held at '
                                       f'{getattr(self.law, held):.6g}, estimating {est} '
                                       '(docs/sensorless.md §3)')
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.add_post_set_parameters_callback(self._after_set_parameters)
        self.period = period_ns(self.T_s)
        self.last_step = round(self.duration / self.T_s) if self.duration > 0 else None
        self.pub = self.create_publisher(JointState, T.ADAPT_ESTIMATE, writer(T.ADAPT_ESTIMATE))
        # the law's estimates, in the topic's order (feed 'inverse_gamma' adds L_sigma)
        self.names = tuple(n for n in T.ESTIMATE_NAMES if n in self.law.estimates())
        self.out = JointStateOut(self.names, Signer.frame(''))
        self.shaft = T.OBS_SPEED if sensorless else T.MEAS_SHAFT
        self.gate = StepGate([T.MEAS_CURRENT, self.shaft, T.CMD_VOLTAGE, T.OBS_FLUX],
                             self.period, follow=True, lags={T.CMD_VOLTAGE: lag})
        for topic in (T.MEAS_CURRENT, T.CMD_VOLTAGE, T.OBS_FLUX):
            self.gate_input(topic, xy_in)
        self.gate_input(self.shaft, shaft_in)
        self.k_done = -1
        self.start_protocol(timeout, startup)

    def on_run_running(self) -> None:
        """p̂_0 for the run this node follows (signed for it)."""
        if self.k_done < 0:
            self.publish_estimate(0)

    def step(self, inputs: dict) -> None:
        k = self.gate.expected // self.period
        if self._enable_next is not None:
            self.enable, self._enable_next = self._enable_next, None
            self.status(PARAMETERS, enable=self.enable)
        # every command enters the delay line, enabled or not: the one acting over this step
        # (overlapped, the gate gave that one: stamped t_k−d)
        v_a, v_b = inputs[T.CMD_VOLTAGE]
        if not self.overlapped:
            v_a, v_b = self.delay.push(v_a, v_b)
        if self.enable:
            i_a, i_b = inputs[T.MEAS_CURRENT]
            if self.compensation is not None:   # the voltage the motor got (observer's too)
                v_a, v_b = self.compensation.motor_voltage(v_a, v_b, i_a, i_b)
            f_a, f_b = inputs[T.OBS_FLUX]
            try:
                self.law.update(self.T_s, v_a, v_b, i_a, i_b, inputs[self.shaft][1],
                                f_a, f_b)
            except (ValueError, ArithmeticError) as exc:
                self.fail(f'adapter failed at step {k} (t = {k * self.T_s:.9f} s): {exc}')
                return
        self.k_done = k
        self.publish_estimate(k + 1)
        if self.last_step is not None and k + 1 >= self.last_step:
            self.reached_last_step()

    def end_run(self, reason: str, notify: bool = False) -> None:
        if not self.done and self.gate.gaps:
            self.get_logger().warning(f'{self.gate.gaps} steps skipped (inputs lost): '
                                      f'{self.gate.gap_text()}')
        super().end_run(reason, notify)

    def _on_set_parameters(self, parameters):
        """``enable`` may be switched at run time (validated here, applied at the next step)."""
        refused = live_refusal(self, parameters)    # its type, naming it
        if refused is not None:
            return refused
        for prm in parameters:
            if prm.name == 'enable' and not isinstance(prm.value, bool):
                return SetParametersResult(successful=False,
                                           reason="parameter 'enable' must be true or false")
        return SetParametersResult(successful=True)

    def _after_set_parameters(self, parameters) -> None:
        for prm in parameters:
            if prm.name == 'enable':
                self._enable_next = prm.value

    def publish_estimate(self, k: int) -> None:
        e = self.law.estimates()
        self.pub.publish(self.sign(T.ADAPT_ESTIMATE, self.out.fill(
            k * self.period, [e[n] for n in self.names])))


def main(argv=None) -> None:
    sys.exit(node_main(AdapterNode, argv))


if __name__ == '__main__':
    main()
