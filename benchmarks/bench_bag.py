"""Micro-benchmark of the recorder's per-message cost: ``python benchmarks/bench_bag.py``.

Writes N steps of the lock-step loop's messages (Vector3Stamped and JointState) through each
write path of :class:`~im_bringup.bag.BagWriter` into a temporary file and prints µs per message
(including chunk compression and the final close), plus the reference cost of
``rclpy.serialization.serialize_message``. ``--json FILE`` also writes the table as JSON.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time


def _bench(n_steps: int, mode: str, compression: str, tmp: str) -> float:
    from geometry_msgs.msg import Vector3Stamped
    from sensor_msgs.msg import JointState
    from im_bringup.bag import BagWriter
    path = os.path.join(tmp, f'{mode}_{compression}.mcap')
    v3 = Vector3Stamped()
    v3.header.frame_id = 'alphabeta'       # as im_common.conversions.Vector3Out
    js = JointState()
    js.name = ['rotor']
    js.position = [0.0]
    js.velocity = [0.0]
    topics_v3 = ('/im/measured/current', '/im/command/voltage', '/im/observer/flux',
                 '/im/truth/flux', '/im/truth/torque')
    w = BagWriter(path, force=True, compression=compression)
    from rclpy.serialization import serialize_message  # noqa: F401 (import cost outside timing)
    n_msg = 0
    t0 = time.perf_counter()
    for k in range(n_steps):
        t = k * 100_000
        s, ns = divmod(t, 1_000_000_000)
        if mode == 'write(msg)':
            v3.header.stamp.sec = s
            v3.header.stamp.nanosec = ns
            v3.vector.x = 0.001 * k
            v3.vector.y = -0.001 * k
            for topic in topics_v3:
                w.write(topic, v3, t)
            js.header.stamp = v3.header.stamp
            js.position = [0.001 * k]
            js.velocity = [1.0]
            w.write('/im/measured/shaft', js, t)
        else:
            for topic in topics_v3:
                w.write_vector3(topic, t, 0.001 * k, -0.001 * k, 0.0)
            w.write_joint_state('/im/measured/shaft', t, ('rotor',), (0.001 * k,), (1.0,))
        n_msg += 6
    w.close()
    dt = time.perf_counter() - t0
    os.remove(path)
    return dt / n_msg * 1e6


def _bench_fill(n_steps: int) -> float:
    """Cost of only filling the message objects (subtract it: the graph fills them anyway)."""
    from geometry_msgs.msg import Vector3Stamped
    from sensor_msgs.msg import JointState
    v3 = Vector3Stamped()
    js = JointState()
    js.name = ['rotor']
    t0 = time.perf_counter()
    for k in range(n_steps):
        t = k * 100_000
        s, ns = divmod(t, 1_000_000_000)
        v3.header.stamp.sec = s
        v3.header.stamp.nanosec = ns
        v3.vector.x = 0.001 * k
        v3.vector.y = -0.001 * k
        js.header.stamp = v3.header.stamp
        js.position = [0.001 * k]
        js.velocity = [1.0]
    return (time.perf_counter() - t0) / (6 * n_steps) * 1e6


def _bench_serialize(n: int) -> float:
    from geometry_msgs.msg import Vector3Stamped
    from rclpy.serialization import serialize_message
    m = Vector3Stamped()
    t0 = time.perf_counter()
    for _ in range(n):
        serialize_message(m)
    return (time.perf_counter() - t0) / n * 1e6


def run(quick: bool = False) -> dict:
    """µs per written message for each write path (zstd), for benchmarks/run_all.py."""
    steps = 4000 if quick else 20000
    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        out['us_per_msg_write_msg_zstd'] = _bench(steps, 'write(msg)', 'zstd', tmp)
        out['us_per_msg_write_serialized_zstd'] = _bench(steps, 'write_vector3/joint_state',
                                                         'zstd', tmp)
    out['us_rclpy_serialize_message_v3'] = _bench_serialize(10000 if quick else 50000)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--steps', type=int, default=20000)
    ap.add_argument('--json', default=None)
    a = ap.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for mode in ('write(msg)', 'write_vector3/joint_state'):
            for comp in ('zstd', 'none'):
                rows.append({'path': mode, 'compression': comp,
                             'us_per_msg': _bench(a.steps, mode, comp, tmp)})
    fill = _bench_fill(a.steps)
    ser = _bench_serialize(50000)
    print(f'{"write path":30s} {"compression":12s} µs/message')
    for r in rows:
        print(f'{r["path"]:30s} {r["compression"]:12s} {r["us_per_msg"]:8.2f}')
    print(f'{"(filling the message objects)":30s} {"":12s} {fill:8.2f}')
    print(f'{"(rclpy serialize_message V3)":30s} {"":12s} {ser:8.2f}')
    if a.json:
        with open(a.json, 'w') as f:
            json.dump({'rows': rows, 'fill_us': fill, 'serialize_message_us': ser,
                       'steps': a.steps, 'python': sys.version}, f, indent=1)
    return 0


if __name__ == '__main__':
    sys.exit(main())
