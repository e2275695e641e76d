"""
Micro-benchmark of the recorder's per-message cost: ``python benchmarks/bench_bag.py``.

Writes N steps of the lock-step loop's messages (Vector3Stamped and JointState) through each
write path of :class:`~im_recording.bag.BagWriter` into a temporary file and prints µs per message
(including chunk compression and the final close), plus the reference cost of
``rclpy.serialization.serialize_message``. ``--json FILE`` also writes the table as JSON.

Decode rows: reading 40,000 signed payloads of one topic into arrays with the batch decoder
(:func:`im_common.cdr.vector3_stamped_batch`, :func:`~im_common.cdr.joint_state_batch`, what the
summary tap and ``load_run`` use) against decoding each message.

Recover rows (``--recover-steps 100000,400000``; ``--only-recover`` skips the rest): a synthetic
recording of that many lock-step steps (6 messages each, zstd, 1 MiB chunks) with 4 KiB zeroed in
its middle chunk, salvaged by ``im_recording.recover.recover`` in a fresh subprocess: wall time,
the subprocess's CPU time in ``recover`` (less sensitive to other load), µs per message and
its peak RSS (``ru_maxrss``), next to the same for an intact 1000-step file (the interpreter and
its imports). Linear time is a flat µs/message, bounded memory a flat peak RSS across sizes.
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
    from im_recording.bag import BagWriter
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


def _bench_decode(n: int) -> dict:
    """
    µs per message of reading a topic's payloads into arrays: in one read or one by one.

    The summary tap and ``load_run`` decode each topic's batch with the batch decoder
    (:func:`im_common.cdr.vector3_stamped_batch`, :func:`~im_common.cdr.joint_state_batch`) and
    fall back to decoding each message only for payloads of mixed layouts: these rows show why.
    Payloads signed as the graph signs them (a tag of fixed length in the frame id).
    """
    from im_common import cdr
    v3 = [cdr.pack_vector3_stamped(k // 10000, k % 10000 * 100000, 0.1 * k, 0.2, 0.0,
                                   frame_id=f'plant|{k:032x}') for k in range(n)]
    js = [cdr.pack_joint_state(k // 10000, k % 10000 * 100000, ('rotor',), (0.1 * k,), (1.0,),
                               ()) for k in range(n)]
    ways = {'us_per_msg_decode_v3_batch': lambda: cdr.vector3_stamped_batch(v3),
            'us_per_msg_decode_v3_each': lambda: [cdr.decode_vector3_stamped(p) for p in v3],
            'us_per_msg_decode_js_batch': lambda: cdr.joint_state_batch(js),
            'us_per_msg_decode_js_each': lambda: [cdr.decode_joint_state(p) for p in js]}
    out = {}
    for key, way in ways.items():
        best = float('inf')
        for _ in range(3):
            t0 = time.perf_counter()
            way()
            best = min(best, time.perf_counter() - t0)
        out[key] = best / n * 1e6
    return out


def _messages(n_steps: int):
    """Return the lock-step loop's serialized messages, one list for every writer and reader."""
    from im_common import cdr
    v3 = ('/im/measured/current', '/im/command/voltage', '/im/observer/flux', '/im/truth/flux',
          '/im/truth/torque')
    out = []
    for k in range(n_steps):
        t = k * 100_000
        s, ns = divmod(t, 1_000_000_000)
        for topic in v3:
            out.append((topic, t, cdr.pack_vector3_stamped(s, ns, 0.001 * k, -0.001 * k, 0.0)))
        out.append(('/im/measured/shaft', t,
                    cdr.pack_joint_state(s, ns, ('rotor',), (0.001 * k,), (1.0,), ())))
    return out


def _bench_own_vs_library(n_steps: int, tmp: str) -> dict:
    """
    Time the project's MCAP writer and reader against the ``mcap`` library's.

    On the same serialized messages (zstd, 1 MiB chunks): µs per message, writing including the
    close, reading every message back with its payload.
    """
    from mcap.reader import make_reader
    from mcap.writer import CompressionType, Writer
    from im_recording.bag import BagWriter, iter_raw
    from im_recording.msgdefs import full_definition
    msgs = _messages(n_steps)
    own, lib = os.path.join(tmp, 'own.mcap'), os.path.join(tmp, 'lib.mcap')
    t0 = time.perf_counter()
    w = BagWriter(own, force=True)
    ws = w.write_serialized
    for topic, t, data in msgs:
        ws(topic, data, t)
    w.close()
    t_own_w = time.perf_counter() - t0
    types = {'/im/measured/shaft': 'sensor_msgs/msg/JointState'}
    t0 = time.perf_counter()
    with open(lib, 'wb') as f:
        mw = Writer(f, chunk_size=1 << 20, compression=CompressionType.ZSTD)
        mw.start(profile='ros2', library='bench')
        schemas, chans = {}, {}
        for topic in dict.fromkeys(m[0] for m in msgs):
            tn = types.get(topic, 'geometry_msgs/msg/Vector3Stamped')
            if tn not in schemas:
                schemas[tn] = mw.register_schema(tn, 'ros2msg', full_definition(tn).encode())
            chans[topic] = mw.register_channel(topic, 'cdr', schemas[tn])
        add = mw.add_message
        for topic, t, data in msgs:
            add(chans[topic], t, data, t)
        mw.finish()
    t_lib_w = time.perf_counter() - t0
    t0 = time.perf_counter()
    n_own = sum(1 for _ in iter_raw(own))
    t_own_r = time.perf_counter() - t0
    t0 = time.perf_counter()
    with open(own, 'rb') as f:
        n_lib = sum(1 for _ in make_reader(f).iter_messages(log_time_order=True))
    t_lib_r = time.perf_counter() - t0
    if not n_own == n_lib == len(msgs):
        raise RuntimeError(f'readers disagree: {n_own} / {n_lib} / {len(msgs)} messages')
    n = len(msgs)
    return {'us_per_msg_own_writer_zstd': t_own_w / n * 1e6,
            'us_per_msg_mcap_Writer_zstd': t_lib_w / n * 1e6,
            'us_per_msg_own_reader_iter_raw': t_own_r / n * 1e6,
            'us_per_msg_mcap_make_reader_iter_messages': t_lib_r / n * 1e6}


def _synthetic(path: str, n_steps: int, damage: bool = True) -> int:
    """
    Write a recording of ``n_steps`` lock-step steps; return its message count.

    Written as it goes (no list in memory), with 4 KiB zeroed in the middle of its middle chunk if
    ``damage``.
    """
    from im_common import cdr
    from im_recording.bag import BagWriter
    v3 = ('/im/measured/current', '/im/command/voltage', '/im/observer/flux', '/im/truth/flux',
          '/im/truth/torque')
    w = BagWriter(path, force=True)
    ws = w.write_serialized
    for k in range(n_steps):
        t = k * 100_000
        s, ns = divmod(t, 1_000_000_000)
        for topic in v3:
            ws(topic, cdr.pack_vector3_stamped(s, ns, 0.001 * k, -0.001 * k, 0.0), t)
        ws('/im/measured/shaft', cdr.pack_joint_state(s, ns, ('rotor',), (0.001 * k,), (1.0,), ()),
           t)
    w.close()
    if not damage:
        return 6 * n_steps
    from mcap.reader import make_reader
    with open(path, 'rb') as f:
        ci = sorted(make_reader(f).get_summary().chunk_indexes, key=lambda c: c.chunk_start_offset)
    c = ci[len(ci) // 2]
    mid = c.chunk_start_offset + c.chunk_length // 2
    with open(path, 'r+b') as f:
        f.seek(mid - 2048)
        f.write(bytes(4096))
    return 6 * n_steps


_RECOVER_CHILD = """
import json, resource, sys, time
from im_recording.recover import recover
def cpu():
    ru = resource.getrusage(resource.RUSAGE_SELF)
    return ru.ru_utime + ru.ru_stime
t0, c0 = time.perf_counter(), cpu()
r = recover(sys.argv[1], sys.argv[2], force=True)
dt, dc = time.perf_counter() - t0, cpu() - c0
print(json.dumps({'seconds': dt, 'cpu_seconds': dc, 'saved': r['messages'],
                  'lost': r['messages_lost'], 'ranges': len(r['lost_ranges']),
                  'peak_rss_mb': resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""


def _bench_recover(steps_list, tmp: str) -> list:
    """One row per size: file size, messages, recover wall time, µs/message, peak RSS."""
    import subprocess
    rows = []
    for steps in [1000] + list(steps_list):
        src, out = os.path.join(tmp, f'rec_{steps}.mcap'), os.path.join(tmp, f'rec_{steps}.out')
        n = _synthetic(src, steps, damage=steps != 1000)
        r = subprocess.run([sys.executable, '-c', _RECOVER_CHILD, src, out], capture_output=True,
                           text=True, check=True)
        res = json.loads(r.stdout.strip().splitlines()[-1])
        rows.append({'steps': steps, 'messages': n, 'file_mb': os.path.getsize(src) / 1e6,
                     'seconds': res['seconds'], 'us_per_msg': res['seconds'] / n * 1e6,
                     'cpu_seconds': res['cpu_seconds'],
                     'cpu_us_per_msg': res['cpu_seconds'] / n * 1e6,
                     'peak_rss_mb': res['peak_rss_mb'], 'saved': res['saved'],
                     'lost': res['lost'], 'ranges': res['ranges']})
        if res['ranges'] != (steps != 1000) or res['saved'] + res['lost'] != n:
            raise RuntimeError(f'recover of {src}: {res}')
        os.remove(src)
        os.remove(out)
    return rows


def _print_recover(rows) -> None:
    print('\nrecover: 4 KiB zeroed in the middle chunk, fresh subprocess '
          '(first row: intact, baseline)')
    print(f'{"steps":>8s} {"messages":>9s} {"file MB":>8s} {"lost":>6s} {"wall s":>7s} '
          f'{"µs/msg":>7s} {"CPU s":>7s} {"CPU µs/msg":>10s} {"peak RSS MB":>11s}')
    for r in rows:
        print(f'{r["steps"]:8d} {r["messages"]:9d} {r["file_mb"]:8.1f} {r["lost"]:6d} '
              f'{r["seconds"]:7.2f} {r["us_per_msg"]:7.2f} {r["cpu_seconds"]:7.2f} '
              f'{r["cpu_us_per_msg"]:10.2f} {r["peak_rss_mb"]:11.1f}')


def run(quick: bool = False) -> dict:
    """µs per written message for each write path (zstd), for benchmarks/run_all.py."""
    steps = 500 if quick else 20000
    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        out['us_per_msg_write_msg_zstd'] = _bench(steps, 'write(msg)', 'zstd', tmp)
        out['us_per_msg_write_serialized_zstd'] = _bench(steps, 'write_vector3/joint_state',
                                                         'zstd', tmp)
        out.update(_bench_own_vs_library(steps, tmp))
        rec = _bench_recover((4000, 16000) if quick else (100000, 400000), tmp)
    for r in rec[1:]:
        out[f'recover_us_per_msg_{r["steps"]}_steps'] = r['us_per_msg']
        out[f'recover_cpu_us_per_msg_{r["steps"]}_steps'] = r['cpu_us_per_msg']
        out[f'recover_peak_rss_mb_{r["steps"]}_steps'] = r['peak_rss_mb']
    out['recover_peak_rss_mb_baseline'] = rec[0]['peak_rss_mb']
    out['us_rclpy_serialize_message_v3'] = _bench_serialize(1000 if quick else 50000)
    out.update(_bench_decode(2000 if quick else 40000))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--steps', type=int, default=20000)
    ap.add_argument('--json', default=None)
    ap.add_argument('--recover-steps', default='100000,400000',
                    help='comma-separated recording sizes (steps) for the recover rows')
    ap.add_argument('--only-recover', action='store_true', help='only the recover rows')
    a = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        rec = _bench_recover([int(x) for x in a.recover_steps.split(',') if x], tmp)
    _print_recover(rec)
    if a.only_recover:
        if a.json:
            with open(a.json, 'w') as f:
                json.dump({'recover': rec, 'python': sys.version}, f, indent=1)
        return 0
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for mode in ('write(msg)', 'write_vector3/joint_state'):
            for comp in ('zstd', 'none'):
                rows.append({'path': mode, 'compression': comp,
                             'us_per_msg': _bench(a.steps, mode, comp, tmp)})
        lib = _bench_own_vs_library(a.steps, tmp)
    fill = _bench_fill(a.steps)
    ser = _bench_serialize(50000)
    print(f'{"write path":30s} {"compression":12s} µs/message')
    for r in rows:
        print(f'{r["path"]:30s} {r["compression"]:12s} {r["us_per_msg"]:8.2f}')
    print(f'{"(filling the message objects)":30s} {"":12s} {fill:8.2f}')
    print(f'{"(rclpy serialize_message V3)":30s} {"":12s} {ser:8.2f}')
    print('\nsame serialized messages, zstd, 1 MiB chunks: own code vs the mcap library')
    for k, v in lib.items():
        print(f'{k[11:]:42s} {v:8.2f} µs/message')
    dec = _bench_decode(40000)
    print('\nreading payloads into arrays (signed, one layout): batch decoder vs one by one')
    for k, v in dec.items():
        print(f'{k[11:]:42s} {v:8.3f} µs/message')
    if a.json:
        with open(a.json, 'w') as f:
            json.dump({'rows': rows, 'fill_us': fill, 'serialize_message_us': ser, **lib, **dec,
                       'recover': rec,
                       'steps': a.steps, 'python': sys.version}, f, indent=1)
    return 0


if __name__ == '__main__':
    sys.exit(main())
