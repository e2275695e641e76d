"""
``ros2 run im_controller controller``: tracking with minimum magnetic energy (seed 000 ch. 3-4).

A thin shell around :class:`im_controller.control_law.DriveController` (``law``: the thesis's, or
a baseline's in its place with its ``baseline.*`` gains, docs/baselines.md). At step k it waits
for the measured current and shaft stamped t_k, the observer's flux estimate stamped t_k (and the
adapter's estimates stamped t_k when ``use_adapter``), computes V_k and publishes it stamped t_k;
the references every ``reference_decimation`` steps for analysis. Setpoints on ``/im/setpoint``
(profile ``setpoint``) take effect at the first step at or after their stamp — a stamp in the past,
0 included (``ros2 topic pub``'s unset header), means now: the reference moves on from where it is,
continuous in position and speed; the topic takes both
a default ``ros2 topic pub`` (volatile) and a transient-local publisher (a setpoint latched before
the controller started is not lost).

Parameters marked live (``--help``) can be changed while running (``ros2 param set /controller
k1 30.0``): the whole new configuration is validated in the set-parameters callback (a refused
value leaves the old one in force and says why), applied at the next step boundary, and announced
on ``/im/status`` with the step it took effect, so a recording holds it.
"""
from __future__ import annotations

import sys
import time

from geometry_msgs.msg import Vector3Stamped
from im_common import topics as T
from im_common.auth import Signer
from im_common.conversions import (estimates_in, JointStateOut, ns_to_s, period_ns, shaft_in,
                                   stamp_ns, Vector3Out, xy_in)
from im_common.lockstep import LockstepNode, node_main, PARAMETERS, StepGate
from im_common.node_params import (declare_block, declare_compensation, declare_motor,
                                   declare_run, declare_saturation_model, live_refusal)
from im_common.params import describe_defaults
from im_common.qos import reader, writer
from im_controller.baselines.drive import gains_model
from im_controller.control_law import DriveController
from im_controller.parameters import (config_from_parameters, declare_controller, live_changes,
                                      LIVE_PARAMETERS, SENTINEL_DEFAULTS)
from im_observer.speed_observer import POSITION_NEEDS_SENSOR
from rcl_interfaces.msg import SetParametersResult
from rclpy.event_handler import SubscriptionEventCallbacks
from sensor_msgs.msg import JointState


class ControllerNode(LockstepNode):
    """Position / speed / torque tracking controller with selectable flux strategy."""

    def __init__(self, **kwargs):
        super().__init__('controller', **kwargs)
        self.T_s, self.duration, timeout, startup = declare_run(self)
        params = declare_motor(self, what='controller model (nominal estimates)',
                               warn_defaults=True)
        self._model = params
        self._values = values = declare_controller(self)
        gains = gains_model(values['law'])
        if gains is not None:       # a baseline law: its gains, the run file's baseline: block
            values['baseline'] = declare_block(
                self, gains, 'baseline', f"take the baseline.* gains of the {values['law']} law "
                '(false: its defaults from the bandwidths, docs/baselines.md)')
        self.use_adapter = self.param('use_adapter', False,
                                      'wait for and use the adapter estimates (eq. 4.10-4.12)')
        self.ref_every = self.param('reference_decimation', 10,
                                    'publish the references every N steps', 1, 1000000)
        self.sensorless = self.param('sensorless', False, "take the observer's speed estimate "
                                     f'({T.OBS_SPEED}) in place of the measured shaft, which is '
                                     'not subscribed (docs/sensorless.md)')
        if self.sensorless and values['mode'] == 'position':
            raise ValueError(f"invalid parameter 'sensorless' = True: {POSITION_NEEDS_SENSOR}")
        self.shaft = T.OBS_SPEED if self.sensorless else T.MEAS_SHAFT
        cfg = config_from_parameters(params, values, self.T_s)
        if cfg.from_ratings:
            self.get_logger().info(describe_defaults(cfg.from_ratings))
        # the run's end is the optimal strategy's planning horizon (0: open-ended)
        horizon = self.duration if self.duration > 0 else None
        # the drive on the magnetizing curve: the model at the observer's flux of the step
        self.saturated = declare_saturation_model(self, params)
        self.ctl = DriveController(cfg.replace(
            horizon=horizon, sensorless=self.sensorless,
            compensation=declare_compensation(self),
            magnetizing=None if self.saturated is None else self.saturated.curve))
        self._plan_note = ''
        if self.saturated is not None and self.use_adapter:
            raise ValueError("invalid parameter 'saturation_model.enabled': with use_adapter "
                             'the adapter tracks L_M itself; choose one')
        self.period = period_ns(self.T_s)
        self.last_step = round(self.duration / self.T_s) if self.duration > 0 else None
        self.pub_cmd = self.create_publisher(Vector3Stamped, T.CMD_VOLTAGE, writer(T.CMD_VOLTAGE))
        self.pub_ref_shaft = self.create_publisher(JointState, T.REF_SHAFT, writer(T.REF_SHAFT))
        self.pub_ref_current = self.create_publisher(Vector3Stamped, T.REF_CURRENT,
                                                     writer(T.REF_CURRENT))
        self.pub_ref_flux = self.create_publisher(Vector3Stamped, T.REF_FLUX, writer(T.REF_FLUX))
        self.out_cmd = Vector3Out(Signer.frame('alphabeta'))
        # the references are signed too (T.SIGNED_TOPICS): frames with the tag's placeholder
        self.out_ri = Vector3Out(Signer.frame('alphabeta'))
        self.out_rf = Vector3Out(Signer.frame('alphabeta'))
        self.out_rs = JointStateOut([T.SHAFT_JOINT], Signer.frame(''))
        required = [T.MEAS_CURRENT, self.shaft, T.OBS_FLUX]
        if self.use_adapter:
            required.append(T.ADAPT_ESTIMATE)
        self.gate = StepGate(required, self.period)
        self.gate_input(T.MEAS_CURRENT, xy_in)
        self.gate_input(self.shaft, shaft_in)
        self.gate_input(T.OBS_FLUX, xy_in)
        if self.use_adapter:
            self.gate_input(T.ADAPT_ESTIMATE, estimates_in)
        # volatile: matches every publisher, `ros2 topic pub` included; transient-local: also
        # gets a setpoint latched before the controller came up. A message that arrives on
        # both is applied once.
        # a message that arrives on both is applied once; the same command sent again later
        # (`ros2 topic pub` twice: same stamp 0, same value) is a new command
        self._seen_setpoints = []
        self.create_subscription(JointState, T.SETPOINT,
                                 lambda msg: self.on_setpoint(msg, 'volatile'), reader(T.SETPOINT))
        self.create_subscription(  # a volatile publisher does not match it: that is expected
            JointState, T.SETPOINT, lambda msg: self.on_setpoint(msg, 'transient_local'),
            reader(T.SETPOINT, latched=True),
            event_callbacks=SubscriptionEventCallbacks(incompatible_qos=lambda _event: None))
        self._pending_changes = None
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.add_post_set_parameters_callback(self._after_set_parameters)
        self.start_protocol(timeout, startup)

    # Live parameters -------------------------------------------------------------------
    def _on_set_parameters(self, parameters):
        """Validate a set of changes as a whole new configuration; applied at the next step."""
        changes = {p.name: p.value for p in parameters if p.name in LIVE_PARAMETERS}
        if not changes:
            return SetParametersResult(successful=True)
        refused = live_refusal(self, parameters)    # types and ranges, naming the parameter
        if refused is not None:
            return refused
        try:
            live_changes(self._model, self._values, dict(self._pending_changes or {}, **changes),
                         self.T_s)
        except (ValueError, TypeError) as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    def _after_set_parameters(self, parameters) -> None:
        """Stage accepted changes for the next step boundary."""
        changes = {p.name: p.value for p in parameters if p.name in LIVE_PARAMETERS}
        if changes:
            self._pending_changes = dict(self._pending_changes or {}, **changes)

    def _apply_changes(self, k: int) -> None:
        changes, self._pending_changes = self._pending_changes, None
        try:
            applied = live_changes(self._model, self._values, changes, self.T_s)
            self.ctl.reconfigure(applied)
        except ValueError as exc:       # validated already; a refusal here is a defect: say so
            self.get_logger().error(f'parameters {changes} not applied at step {k}: {exc}')
            return
        self._values.update(changes)
        # what is in force: a sentinel (-1) is shown with the value it stands for
        said = {n: repr(v) if n not in SENTINEL_DEFAULTS or v != -1.0
                else f'{v!r} ({SENTINEL_DEFAULTS[n]}: {applied[n]!r})'
                for n, v in changes.items()}
        self.get_logger().info(f'parameters applied at step {k}: '
                               + ', '.join(f'{n} = {v}' for n, v in said.items()))
        self.status(PARAMETERS, **said)

    def on_setpoint(self, msg: JointState, via: str = 'volatile') -> None:
        """
        Take a setpoint: it takes effect at the first step at or after its stamp.

        A stamp in the past (0 included: ``ros2 topic pub`` leaves it unset) means now
        (:meth:`DriveController.set_setpoint`).
        """
        ns = stamp_ns(msg.header.stamp)
        key = (ns, tuple(msg.position), tuple(msg.velocity), tuple(msg.effort))
        now = time.monotonic()
        seen = [s for s in self._seen_setpoints if now - s[2] < 1.0]
        twin = next((s for s in seen if s[0] == key and s[1] != via), None)
        if twin is not None:            # the same message through the other subscription
            seen.remove(twin)
            self._seen_setpoints = seen
            return
        self._seen_setpoints = (seen + [(key, via, now)])[-20:]
        for kind, field in (('position', msg.position), ('speed', msg.velocity),
                            ('torque', msg.effort)):
            if len(field):
                try:
                    self.ctl.set_setpoint(kind, float(field[0]), ns_to_s(ns))
                except ValueError as exc:
                    self.get_logger().error(
                        f'rejected {T.SETPOINT} stamped {ns_to_s(ns):.9f} s: {exc}')
                    return
                start = max(ns, self.gate.expected)
                self.get_logger().info(
                    f'{T.SETPOINT}: {kind} {float(field[0])!r} stamped {ns_to_s(ns):.9f} s, '
                    f'from the step at {ns_to_s(start):.9f} s'
                    + (' (now)' if ns < self.gate.expected else ''))
                return
        self.get_logger().error(f'rejected {T.SETPOINT}: no position, velocity or effort value')

    def step(self, inputs: dict) -> None:
        ns = self.gate.expected
        k = ns // self.period
        if self._pending_changes is not None:
            self._apply_changes(k)
        i_a, i_b = inputs[T.MEAS_CURRENT]
        theta, omega = inputs[self.shaft]
        f_a, f_b = inputs[T.OBS_FLUX]
        est = inputs[T.ADAPT_ESTIMATE] if self.use_adapter else None
        if self.saturated is not None:
            est = self.saturated.estimates(f_a, f_b)
        try:
            v_a, v_b = self.ctl.compute(ns_to_s(ns), i_a, i_b, theta, omega, f_a, f_b, est)
        except (ValueError, ArithmeticError) as exc:
            self.fail(f'controller failed at step {k} (t = {ns_to_s(ns):.9f} s): {exc}')
            return
        self.pub_cmd.publish(self.sign(T.CMD_VOLTAGE, self.out_cmd.fill(ns, v_a, v_b)))
        if self.ctl.plan_note != self._plan_note:     # optimal: what the flux follows, and why
            self._plan_note = self.ctl.plan_note
            log = self.get_logger()
            (log.info if 'planned' in self._plan_note else log.warning)(self._plan_note)
        if k % self.ref_every == 0:
            r = self.ctl.reference
            sign = self.sign
            self.pub_ref_shaft.publish(sign(T.REF_SHAFT, self.out_rs.fill(
                ns, (r['theta_ref'],), (r['omega_ref'],), (r['tau_ref'],))))
            self.pub_ref_current.publish(sign(T.REF_CURRENT, self.out_ri.fill(
                ns, r['i_alpha_ref'], r['i_beta_ref'])))
            self.pub_ref_flux.publish(sign(T.REF_FLUX, self.out_rf.fill(
                ns, r['phi_alpha_ref'], r['phi_beta_ref'], r['phi_d_ref'])))
        if self.last_step is not None and k + 1 >= self.last_step:
            self.reached_last_step()


def main(argv=None) -> None:
    sys.exit(node_main(ControllerNode, argv))


if __name__ == '__main__':
    main()
