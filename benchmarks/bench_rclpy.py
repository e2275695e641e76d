"""
Yardsticks for the lock-step loop: raw rclpy round trips and a bare four-node protocol loop.

1. Ping-pong: two nodes in one process bounce a Vector3Stamped, SingleThreadedExecutor vs
   ``rclpy.experimental.EventsExecutor`` (round trips/s).
2. Bare protocol loop: four nodes exchanging exactly the messages the drive graph exchanges per
   step (plant: current + shaft; controller: voltage; observer: flux; adapter: estimate), the same
   bytes (frame ids with their tag slot, the adapter's estimate names from ``im_common.topics``,
   decoded by the nodes' own extractors), gated by stamp like the real nodes and spun natively
   like ``DriveGraph``, with no computation (steps/s). With ``tags`` the loop also signs every
   lock-step message and checks every input (``im_common.auth``), as the graph does: the
   difference between the two is what the message tags cost in the loop. The drive graph is
   measured against this loop in the same run (benchmarks/bench_graph.py).
"""
from __future__ import annotations

import os
import random
import time

from geometry_msgs.msg import Vector3Stamped
from im_common import topics as T
from im_common.auth import Signer
from im_common.conversions import (clock_bytes, estimates_in, JointStateOut, shaft_in, Vector3Out,
                                   xy_in)
from im_common.lockstep import lockstep_qos, make_executor, StepGate
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState


def _context():
    ctx = Context()
    rclpy.init(context=ctx, domain_id=random.randint(150, 229))
    return ctx


def _spin(executor, done, limit_s):
    t0 = time.perf_counter()
    while not done() and time.perf_counter() - t0 < limit_s:
        executor.spin_once(timeout_sec=0.05)


def ping_pong(executor_kind: str, n: int = 5000, limit_s: float = 60.0) -> float:
    """Round trips per second between two nodes in one process."""
    ctx = _context()
    try:
        a, b = Node('ping', context=ctx), Node('pong', context=ctx)
        q = lockstep_qos()
        pa = a.create_publisher(Vector3Stamped, '/bench/ping', q)
        pb = b.create_publisher(Vector3Stamped, '/bench/pong', q)
        count = [0]
        msg = Vector3Stamped()

        def on_pong(m):
            count[0] += 1
            if count[0] < n:
                pa.publish(m)
        b.create_subscription(Vector3Stamped, '/bench/ping', lambda m: pb.publish(m), q)
        a.create_subscription(Vector3Stamped, '/bench/pong', on_pong, q)
        if executor_kind == 'events':
            ex = make_executor(ctx)
        else:
            ex = SingleThreadedExecutor(context=ctx)
        ex.add_node(a)
        ex.add_node(b)
        while pa.get_subscription_count() < 1 or pb.get_subscription_count() < 1:
            ex.spin_once(timeout_sec=0.01)
        t0 = time.perf_counter()
        pa.publish(msg)
        _spin(ex, lambda: count[0] >= n, limit_s)
        dt = time.perf_counter() - t0
        ex.shutdown()
        a.destroy_node()
        b.destroy_node()
        return count[0] / dt
    finally:
        rclpy.try_shutdown(context=ctx)


class _Bare(Node):
    """
    A node of the bare loop.

    Gated serialized inputs, serialized outputs, no computation — the same mechanism as the
    drive nodes (im_common.lockstep.LockstepNode.gate_input), with the inputs' tags checked
    when ``signer`` is given.
    """

    def __init__(self, name, ctx, required, outputs, period, on_step, signer=None):
        super().__init__(name, context=ctx)
        q = lockstep_qos()
        self.gate = StepGate(required, period)
        self.pubs = {t: self.create_publisher(typ, t, q) for t, typ in outputs}
        self.on_step = on_step
        self.sign = signer.sign if signer is not None else (lambda _topic, data: data)
        verify = signer.verify if signer is not None else None
        for t in required:
            js = T.TOPIC_TYPES[t] == T.JS
            typ = JointState if js else Vector3Stamped
            extract = {T.MEAS_SHAFT: shaft_in, T.ADAPT_ESTIMATE: estimates_in}.get(t, xy_in)
            if verify is None:
                cb = (lambda d, t=t, x=extract: self._put(t, *x(d)))
            else:
                def cb(d, t=t, x=extract, v=verify):
                    if not v(t, d):
                        raise RuntimeError(f'bare loop: {t} does not verify')
                    self._put(t, *x(d))
            self.create_subscription(typ, t, cb, q, raw=True)

    def _put(self, topic, ns, value):
        ready = self.gate.put(topic, ns, value)
        while ready is not None:
            self.on_step(self, self.gate.expected)
            ready = self.gate.advance()


def bare_loop(steps: int = 5000, adapter_on_path: bool = True, tags: bool = False,
              limit_s: float = 120.0, decimation: int = 10) -> float:
    """
    Measure the steps per second of the drive's message pattern with no computation.

    With the EventsExecutor.

    Four nodes exchange what the graph exchanges per step: plant → current + shaft, controller →
    voltage, observer → flux, adapter → estimates. With ``adapter_on_path`` the controller waits
    for the estimates (adaptive runs); without, the adapter still receives every step but nobody
    waits for it (nominal runs). Clock, ground truth, references and the observer's current
    estimate go out every ``decimation`` steps, as the graph's defaults publish them. ``tags``:
    lock-step messages signed and checked with a graph key, as the drive nodes do. The rate is
    taken from the plant's first step, as the drive graph's (``steps_per_s_running``) and the
    plant's own report: discovery and the run protocol's start-up are not steps.
    """
    from rclpy.task import Future
    ctx = _context()
    try:
        period = 100_000
        signer = Signer(os.urandom(32), 'bench') if tags else None
        sign = signer.sign if tags else (lambda _topic, data: data)
        # the lock-step topics with the frame ids the drive nodes pack them with (tag slot)
        v3_ab, v3 = Vector3Out(Signer.frame('alphabeta')), Vector3Out()
        js_shaft = JointStateOut([T.SHAFT_JOINT], Signer.frame(''))
        js_ref = JointStateOut([T.SHAFT_JOINT])
        js_est = JointStateOut(T.ESTIMATE_NAMES, Signer.frame(''))   # the adaptive controller's
        est = [1.0] * len(T.ESTIMATE_NAMES)                          # feed: every estimate name
        state = {'k': 0, 't_first': None}
        done = Future()

        js_par, js_pow = JointStateOut(T.PARAM_NAMES), JointStateOut(T.POWER_NAMES)
        js_en = JointStateOut(T.ENERGY_NAMES)

        def measure(node, ns):
            node.pubs[T.MEAS_CURRENT].publish(sign(T.MEAS_CURRENT, v3_ab.fill(ns, 1.0, 2.0)))
            node.pubs[T.MEAS_SHAFT].publish(sign(T.MEAS_SHAFT, js_shaft.fill(ns, (0.0,), (0.0,))))

        def plant_step(node, ns):
            if state['t_first'] is None:
                state['t_first'] = time.perf_counter()
            state['k'] += 1
            if state['k'] >= steps:
                done.set_result(True)
                return
            nxt = ns + period
            measure(node, nxt)
            if state['k'] % decimation == 0:       # clock and ground truth, decimated
                p = node.pubs
                p[T.CLOCK].publish(clock_bytes(nxt))
                for topic in (T.TRUTH_VOLTAGE, T.TRUTH_FLUX, T.TRUTH_TORQUE):
                    p[topic].publish(v3.fill(nxt, 1.0, 2.0))
                p[T.TRUTH_PARAMS].publish(js_par.fill(nxt, [1.0] * len(T.PARAM_NAMES)))
                p[T.TRUTH_POWER].publish(js_pow.fill(nxt, [1.0] * len(T.POWER_NAMES)))
                p[T.TRUTH_ENERGY].publish(js_en.fill(nxt, [1.0] * len(T.ENERGY_NAMES)))

        def ctl_step(node, ns):
            node.pubs[T.CMD_VOLTAGE].publish(sign(T.CMD_VOLTAGE, v3_ab.fill(ns, 1.0, 2.0)))
            if (ns // period) % decimation == 0:        # references, decimated
                node.pubs[T.REF_SHAFT].publish(js_ref.fill(ns, (0.0,), (0.0,), (0.0,)))
                node.pubs[T.REF_CURRENT].publish(v3.fill(ns, 1.0, 2.0))
                node.pubs[T.REF_FLUX].publish(v3.fill(ns, 1.0, 2.0, 3.0))

        def obs_publish(node, ns):
            node.pubs[T.OBS_FLUX].publish(sign(T.OBS_FLUX, v3_ab.fill(ns, 1.0, 2.0)))
            if (ns // period) % decimation == 0:
                node.pubs[T.OBS_CURRENT].publish(v3.fill(ns, 1.0, 2.0))

        def ad_publish(node, ns):
            node.pubs[T.ADAPT_ESTIMATE].publish(sign(T.ADAPT_ESTIMATE, js_est.fill(ns, est)))

        ctl_req = [T.MEAS_CURRENT, T.MEAS_SHAFT, T.OBS_FLUX]
        if adapter_on_path:
            ctl_req.append(T.ADAPT_ESTIMATE)
        V3, JS = Vector3Stamped, JointState
        nodes = [
            _Bare('plant', ctx, [T.CMD_VOLTAGE],
                  [(T.MEAS_CURRENT, V3), (T.MEAS_SHAFT, JS), (T.CLOCK, Clock),
                   (T.TRUTH_VOLTAGE, V3), (T.TRUTH_FLUX, V3), (T.TRUTH_TORQUE, V3),
                   (T.TRUTH_PARAMS, JS), (T.TRUTH_POWER, JS), (T.TRUTH_ENERGY, JS)],
                  period, plant_step, signer),
            _Bare('controller', ctx, ctl_req,
                  [(T.CMD_VOLTAGE, V3), (T.REF_SHAFT, JS), (T.REF_CURRENT, V3), (T.REF_FLUX, V3)],
                  period, ctl_step, signer),
            _Bare('observer', ctx, [T.MEAS_CURRENT, T.MEAS_SHAFT, T.CMD_VOLTAGE],
                  [(T.OBS_FLUX, V3), (T.OBS_CURRENT, V3)], period,
                  lambda node, ns: obs_publish(node, ns + period), signer),
            _Bare('adapter', ctx, [T.MEAS_CURRENT, T.MEAS_SHAFT, T.CMD_VOLTAGE, T.OBS_FLUX],
                  [(T.ADAPT_ESTIMATE, JointState)], period,
                  lambda node, ns: ad_publish(node, ns + period), signer),
        ]
        ex = make_executor(ctx)
        for n in nodes:
            ex.add_node(n)
        t0 = time.perf_counter()
        # Step 0: initial estimates and measurement (transient-local QoS delivers them to late
        # joiners).
        obs_publish(nodes[2], 0)
        ad_publish(nodes[3], 0)
        measure(nodes[0], 0)
        while not done.done() and time.perf_counter() - t0 < limit_s:   # natively, as DriveGraph
            ex.spin_until_future_complete(done, timeout_sec=0.5)
        dt = time.perf_counter() - (state['t_first'] or t0)
        ex.shutdown()
        for n in nodes:
            n.destroy_node()
        if not done.done():
            raise RuntimeError(f'bare loop: {state["k"]} of {steps} steps in {limit_s} s')
        return state['k'] / dt
    finally:
        rclpy.try_shutdown(context=ctx)


def run(quick: bool = False) -> dict:
    n = 1000 if quick else 10000
    return {
        'ping_pong_single_threaded_rt_per_s': ping_pong('single', n),
        'ping_pong_events_rt_per_s': ping_pong('events', n),
        'bare_loop_adapter_on_path_steps_per_s': bare_loop(n, adapter_on_path=True),
        'bare_loop_adapter_off_path_steps_per_s': bare_loop(n, adapter_on_path=False),
        'bare_loop_tagged_adapter_off_path_steps_per_s': bare_loop(n, adapter_on_path=False,
                                                                   tags=True),
    }


if __name__ == '__main__':      # the table and JSON come from the driver
    import sys

    from run_all import main
    sys.exit(main(['--only', 'rclpy'] + sys.argv[1:]))
