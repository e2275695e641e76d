"""
``ros2 run im_observer observer``: full-order rotor-flux observer (seed 000 eq. 3.27 / 4.13).

A thin shell around :class:`im_observer.observer.RotorFluxObserver`. At step k it takes the
measured current and speed and the voltage command stamped t_k (and the adapter's estimates
stamped t_k when ``use_adapter``), integrates the observer over [t_k, t_k+1] and publishes the
estimate x̂_k+1 stamped t_k+1 — in parallel with the plant's own integration. With the plant's
computational ``delay`` d it integrates the command of step k − d, the voltage the motor got
(im_common.delay): with ``overlap`` (the default) its step gate takes that command, stamped
t_k−d, so it predicts x̂_k+1 as soon as the measurement of step k has come, beside the controller
computing the command of step k (docs/architecture.md, "The delayed step overlapped").

In lock-step every step is taken in order. When the plant runs in ``free_run`` the observer
follows: a step whose inputs never came (a command that missed its deadline) is bridged by
predicting open-loop with the previous command — what the plant itself did — and counted.
"""
from __future__ import annotations

import sys

from geometry_msgs.msg import Vector3Stamped
from im_common import topics as T
from im_common.auth import Signer
from im_common.conversions import (estimates_in, JointStateOut, period_ns, shaft_in, Vector3Out,
                                   xy_in)
from im_common.lockstep import LOCKSTEP_DEPTH, LockstepNode, node_main, StepGate
from im_common.node_params import (declare_compensation, declare_delay, declare_motor,
                                   declare_run, declare_saturation_model)
from im_common.qos import writer
from im_observer.observer import RotorFluxObserver
from im_observer.parameters import declare_observer, observer_config
from im_observer.speed_observer import SpeedAdaptiveObserver
from sensor_msgs.msg import JointState


#: free_run: a follow gate this many steps behind the plant's measurements with no step complete
#: is a stalled loop (:meth:`ObserverNode.on_incomplete`) — half the lock-step window, 50 ms at
#: 1 kHz; a loop that runs completes a step every period.
STALL_STEPS = LOCKSTEP_DEPTH // 2


class ObserverNode(LockstepNode):
    """Full-order observer of stator currents and rotor fluxes."""

    def __init__(self, **kwargs):
        super().__init__('observer', **kwargs)
        self.T_s, self.duration, timeout, startup = declare_run(self)
        params = declare_motor(self, what='observer model (nominal estimates)')
        cfg = observer_config(declare_observer(self), self.T_s)
        self.use_adapter = cfg.use_adapter
        self.publish_every = cfg.estimate_decimation
        self.sensorless = cfg.sensorless
        self.obs = (SpeedAdaptiveObserver if self.sensorless else RotorFluxObserver)(
            params, k_e=cfg.k_e_injection, max_substep=cfg.max_substep,
            x0=cfg.initial_state, injection_gain=cfg.injection_gain,
            gain_period=cfg.gain_period or None, inverter_error=declare_compensation(self),
            **({'omega0': cfg.initial_speed} if self.sensorless else {}))
        self.delay, lag = declare_delay(self)
        self.overlapped = bool(lag)     # the gate gives the acting command: no line to push
        # the drive on the magnetizing curve: the next step's model at the flux it now has
        self.saturated = declare_saturation_model(self, params)
        if self.saturated is not None and self.use_adapter:
            raise ValueError("invalid parameter 'saturation_model.enabled': with use_adapter "
                             'the adapter tracks L_M itself; choose one')
        if self.saturated is not None:      # from the start: the model at the initial flux
            x0 = self.obs.state
            self.obs.set_estimates(**self.saturated.estimates(x0[2], x0[3]))
        self.period = period_ns(self.T_s)
        self.last_step = round(self.duration / self.T_s) if self.duration > 0 else None
        self.pub_flux = self.create_publisher(Vector3Stamped, T.OBS_FLUX, writer(T.OBS_FLUX))
        self.pub_current = self.create_publisher(Vector3Stamped, T.OBS_CURRENT,
                                                 writer(T.OBS_CURRENT))
        # the current estimate (a report) is signed as the flux is (T.SIGNED_TOPICS)
        self.out_flux = Vector3Out(Signer.frame('alphabeta'))
        self.out_current = Vector3Out(Signer.frame('alphabeta'))
        if self.sensorless:     # the speed estimate, in the measured shaft's place
            self.pub_speed = self.create_publisher(JointState, T.OBS_SPEED, writer(T.OBS_SPEED))
            self.out_speed = JointStateOut([T.SHAFT_JOINT], Signer.frame(''))
        required = [T.MEAS_CURRENT, T.CMD_VOLTAGE] + ([] if self.sensorless else [T.MEAS_SHAFT])
        if self.use_adapter:
            required.append(T.ADAPT_ESTIMATE)
        self.gate = StepGate(required, self.period, lags={T.CMD_VOLTAGE: lag})
        self.gate_input(T.MEAS_CURRENT, xy_in)
        if not self.sensorless:
            self.gate_input(T.MEAS_SHAFT, shaft_in)
        self.gate_input(T.CMD_VOLTAGE, xy_in)
        if self.use_adapter:
            self.gate_input(T.ADAPT_ESTIMATE, estimates_in)
        self.k_done = -1
        self.held = (0.0, 0.0, 0.0)         # last command and speed (for bridging a gap)
        self.bridged = 0
        self.start_protocol(timeout, startup)

    def on_run_running(self) -> None:
        """x̂_0 for the run this node follows (signed for it): the controller's step 0."""
        if self.k_done < 0:
            self.publish_estimate(0)

    def step(self, inputs: dict) -> None:
        k = self.gate.expected // self.period
        try:
            while self.k_done + 1 < k:          # steps lost in free_run: predict open-loop
                self._bridge(self.k_done + 1)
            if self.use_adapter:
                self.obs.set_estimates(**inputs[T.ADAPT_ESTIMATE])
            v_a, v_b = inputs[T.CMD_VOLTAGE]
            i_a, i_b = inputs[T.MEAS_CURRENT]
            omega = None if self.sensorless else inputs[T.MEAS_SHAFT][1]
            self._step(v_a, v_b, i_a, i_b, omega)
        except (ValueError, ArithmeticError) as exc:
            self.fail(f'observer failed at step {k} (t = {k * self.T_s:.9f} s): {exc}')
            return
        self.held = (v_a, v_b, omega)
        self.k_done = k
        self.publish_estimate(k + 1)
        if self.last_step is not None and k + 1 >= self.last_step:
            self.reached_last_step()

    def on_incomplete(self, topic: str, ns: int) -> None:
        """
        Bridge a stalled free_run loop open-loop up to the plant's present step.

        The plant's measurement stamped ``ns`` came while this node still waits for a step at
        least :data:`STALL_STEPS` earlier, and no later step is complete. The loop has stalled:
        the controller waits for this node's estimate of a step whose command or measurement
        never reached this node (lost from a reader history while the node was starved), and
        this node waits for that command — neither would ever move again. Bridging (what the
        plant did without commands) gives the controller estimates again.
        """
        gate = self.gate
        if topic != T.MEAS_CURRENT or ns - gate.expected < STALL_STEPS * self.period:
            return
        k = ns // self.period
        try:
            while self.k_done + 1 < k:
                self._bridge(self.k_done + 1)
        except (ValueError, ArithmeticError) as exc:
            self.fail(f'observer failed bridging step {self.k_done + 1} '
                      f'(t = {(self.k_done + 1) * self.T_s:.9f} s): {exc}')
            return
        inputs = gate.skip_to(ns)
        if inputs is not None:
            self.ready(inputs)

    def _bridge(self, j: int) -> None:
        v_a, v_b, omega = self.held
        i_a, i_b = self.obs.state[0], self.obs.state[1]      # no measurement: no injection
        self._step(v_a, v_b, i_a, i_b, omega)
        self.bridged += 1
        self.k_done = j
        self.publish_estimate(j + 1)

    def _step(self, v_a, v_b, i_a, i_b, omega) -> None:
        if not self.overlapped:                     # the command that acts over this step
            v_a, v_b = self.delay.push(v_a, v_b)
        if self.sensorless:
            x = self.obs.step(self.T_s, v_a, v_b, i_a, i_b)
        else:
            x = self.obs.step(self.T_s, v_a, v_b, i_a, i_b, omega)
        if self.saturated is not None:
            self.obs.set_estimates(**self.saturated.estimates(x[2], x[3]))

    def end_run(self, reason: str, notify: bool = False) -> None:
        if not self.done and self.bridged:
            self.get_logger().warning(f'{self.bridged} steps bridged open-loop (inputs lost)')
        super().end_run(reason, notify)

    def publish_estimate(self, k: int) -> None:
        """Publish x̂_k: flux (lock-step), current (a report) every publish_every steps."""
        ns = k * self.period
        i_a, i_b, f_a, f_b = self.obs.state
        self.pub_flux.publish(self.sign(T.OBS_FLUX, self.out_flux.fill(ns, f_a, f_b)))
        if self.sensorless:
            self.pub_speed.publish(self.sign(T.OBS_SPEED, self.out_speed.fill(
                ns, (self.obs.theta_hat,), (self.obs.omega_hat,))))
        if k % self.publish_every == 0 or (self.last_step is not None and k >= self.last_step):
            self.pub_current.publish(self.sign(T.OBS_CURRENT,
                                               self.out_current.fill(ns, i_a, i_b)))


def main(argv=None) -> None:
    sys.exit(node_main(ObserverNode, argv))


if __name__ == '__main__':
    main()
