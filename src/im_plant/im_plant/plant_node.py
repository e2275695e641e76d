"""``ros2 run im_plant plant``: the simulated motor, load and inverter; the time master.

A thin shell around :class:`im_common.plant_sim.PlantSimulator`: parameters in, voltage commands
in, measurements and ground truth out. In ``lockstep`` mode (default) it advances from t_k to
t_k+1 only when the command stamped t_k has arrived; in ``free_run`` mode it advances on a
wall-clock timer at T_s holding the last command and counts overruns (steps whose command was late).
"""
from __future__ import annotations

import math
import sys
import time

from geometry_msgs.msg import Vector3Stamped
from rclpy.clock import Clock, ClockType
from rosgraph_msgs.msg import Clock as ClockMsg

from im_common import topics as T
from im_common.conversions import JointStateOut, Vector3Out, clock_bytes, period_ns, xy_in
from im_common.lockstep import LockstepNode, StepGate, data_qos, lockstep_qos, node_main
from im_common.node_params import declare_run
from im_plant.parameters import declare_plant, simulator_from_parameters


class PlantNode(LockstepNode):
    """Simulated induction motor, load and inverter; owns simulated time."""

    def __init__(self, **kwargs):
        super().__init__('plant', **kwargs)
        self.T_s, self.duration, timeout, startup = declare_run(self)
        values = declare_plant(self)
        self.mode = values['mode']
        self.clock_every = values['clock_decimation']
        self.truth_every = values['truth_decimation']
        self.sim = simulator_from_parameters(values, self.T_s, self.duration)
        self.period = period_ns(self.T_s)
        self.last_step = (round(self.duration / self.T_s) if self.duration > 0 else None)
        self.rejected = 0
        self.overruns = 0
        self.truth_sink = None      # in-process recorder hook: f(ns, truth_dict)
        self.wall_start = None      # wall time of the first step (for the steps/s report)

        q = lockstep_qos()
        self.pub_current = self.create_publisher(Vector3Stamped, T.MEAS_CURRENT, q)
        self.pub_shaft = self.create_publisher(*_js(), T.MEAS_SHAFT, q)
        self.pub_clock = self.create_publisher(ClockMsg, T.CLOCK, 10)
        dq = data_qos()
        self.pub_truth = {
            'voltage': self.create_publisher(Vector3Stamped, T.TRUTH_VOLTAGE, dq),
            'flux': self.create_publisher(Vector3Stamped, T.TRUTH_FLUX, dq),
            'torque': self.create_publisher(Vector3Stamped, T.TRUTH_TORQUE, dq),
            'params': self.create_publisher(*_js(), T.TRUTH_PARAMS, dq),
            'power': self.create_publisher(*_js(), T.TRUTH_POWER, dq),
            'energy': self.create_publisher(*_js(), T.TRUTH_ENERGY, dq),
        }
        self.out_current = Vector3Out()
        self.out_shaft = JointStateOut([T.SHAFT_JOINT])
        self.out_tv, self.out_tf, self.out_tt = Vector3Out(), Vector3Out(), Vector3Out()
        self.out_par = JointStateOut(T.PARAM_NAMES)
        self.out_pow = JointStateOut(T.POWER_NAMES)
        self.out_en = JointStateOut(T.ENERGY_NAMES)

        self.gate = StepGate([T.CMD_VOLTAGE], self.period)
        self.last_cmd = (0.0, 0.0)
        self.create_subscription(Vector3Stamped, T.CMD_VOLTAGE, self.on_command, q, raw=True)
        if self.mode == 'free_run':
            self.create_timer(self.T_s, self.on_wall_tick, clock=Clock(clock_type=ClockType.STEADY_TIME))
            self.gate = None
        else:
            self.start_watchdog(timeout, startup)
        self.publish_step()

    # Lock-step ---------------------------------------------------------------------------
    def on_command(self, data: bytes) -> None:
        try:
            ns, (vx, vy) = xy_in(data)
        except ValueError as exc:
            self.rejected += 1
            self.get_logger().error(f'rejected malformed {T.CMD_VOLTAGE}: {exc}')
            return
        if not (math.isfinite(vx) and math.isfinite(vy)):
            self.rejected += 1
            self.get_logger().error(
                f'rejected {T.CMD_VOLTAGE} stamped {ns / 1e9:.9f} s: non-finite voltage '
                f'({vx!r}, {vy!r}); holding the previous command')
            vx, vy = self.last_cmd
        if self.gate is None:           # free-running: just hold the latest command
            if ns < self.sim.k * self.period:
                self.overruns += 1
            self.last_cmd = (vx, vy)
            return
        ready = self.gate.put(T.CMD_VOLTAGE, ns, (vx, vy))
        while ready is not None and not self.done:
            if self.wall_start is None:
                self.wall_start = time.perf_counter()
            self.mark_started()
            self.advance(*ready[T.CMD_VOLTAGE])
            ready = self.gate.advance()

    def on_wall_tick(self) -> None:
        if self.done:
            return
        self.advance(*self.last_cmd)

    def advance(self, v_a: float, v_b: float) -> None:
        self.last_cmd = (v_a, v_b)
        try:
            self.sim.step(v_a, v_b)
        except (ValueError, FloatingPointError) as exc:
            self.fail(f'plant step failed: {exc}')
            return
        self.publish_step()

    def publish_step(self) -> None:
        sim = self.sim
        k = sim.k
        ns = k * self.period
        final = self.last_step is not None and k >= self.last_step
        m = sim.measure()
        self.pub_current.publish(self.out_current.fill(ns, m.i_alpha, m.i_beta))
        self.pub_shaft.publish(self.out_shaft.fill(ns, (m.theta_r,), (m.omega_r,)))
        if k % self.clock_every == 0 or final:
            self.pub_clock.publish(clock_bytes(ns))
        if (self.truth_every and k % self.truth_every == 0) or final or self.truth_sink:
            tr = sim.truth()
            if self.truth_sink is not None:
                self.truth_sink(ns, tr)
            if (self.truth_every and k % self.truth_every == 0) or final:
                self.publish_truth(ns, tr)
        if final:
            wall = time.perf_counter() - (self.wall_start or time.perf_counter())
            rate = k / wall if wall > 0 else float('nan')
            self.get_logger().info(
                f'reached duration {self.duration} s at step {k} ({rate:.0f} steps/s); '
                f'rejected commands: {self.rejected}, overruns: {self.overruns}')
            self.finish()

    def publish_truth(self, ns: int, tr: dict) -> None:
        pt = self.pub_truth
        pt['voltage'].publish(self.out_tv.fill(ns, tr['v_alpha'], tr['v_beta']))
        pt['flux'].publish(self.out_tf.fill(ns, tr['phi_r_alpha'], tr['phi_r_beta']))
        pt['torque'].publish(self.out_tt.fill(ns, tr['tau_m'], tr['tau_L'],
                                              self.sim.params.b * tr['omega_r']))
        pt['params'].publish(self.out_par.fill(ns, truth_params(tr)))
        pt['power'].publish(self.out_pow.fill(ns, [tr[n] for n in T.POWER_NAMES]))
        pt['energy'].publish(self.out_en.fill(ns, [tr[n] for n in T.ENERGY_NAMES]))


def truth_params(tr: dict) -> list:
    """True parameter vector in the order of ``topics.PARAM_NAMES``."""
    th = tr['L_sr'] / tr['L_r']
    return [tr['R_s'], tr['R_r'], tr['L_s'], tr['L_r'], tr['L_sr'], th, tr['L_sr'] * th,
            tr['R_r'] * th * th]


def _js():
    from sensor_msgs.msg import JointState
    return (JointState,)


def main(argv=None) -> None:
    sys.exit(node_main(PlantNode, argv))


if __name__ == '__main__':
    main()
