"""
Durable recording (a hard kill loses seconds, not the run).

The recorder and the in-process writer put a chunk on disk once it holds
:data:`~im_recording.bag.FLUSH_WALL_S` of wall time or :data:`~im_recording.bag.FLUSH_BYTES`,
whichever first; ``recover`` compares what it saved with the run's own record and names the
tail it lost instead of calling the salvage complete. Counts are taken with the ``mcap``
package's reader, which the project did not write.
"""
from collections import Counter
import os
import re
import signal
import time

from im_bringup.testing import random_domain
from im_common import topics as T
from im_common.step_gate import LOCKSTEP_DEPTH
from im_recording import recover as rec
from im_recording.bag import BagWriter, FLUSH_WALL_S, info, partial_path
from im_recording.record_node import FLUSH_CHECK_S
import pytest

PERIOD = 100_000        # T_s = 1e-4 s


@pytest.fixture
def domain():
    return {'ROS_DOMAIN_ID': str(random_domain())}


def mcap_stamps(path, topic, field='log_time'):
    """
    Stamps of ``topic`` in ``path``: log times less the file's offset, mcap's own reader.

    ``field='publish_time'``: the messages' own stamps. A message that reached the recorder
    later than its reorder window is written at the file's latest log time (counted in the
    ``recording`` record's ``written_late``) and keeps its stamp as publish time.
    """
    from mcap.reader import make_reader
    with open(path, 'rb') as f:
        reader = make_reader(f)
        off = next((int(m.metadata['offset_ns']) for m in reader.iter_metadata()
                    if m.name == 'log_time'), 0)
        return [getattr(m, field) - off for _, ch, m in reader.iter_messages(topics=[topic])]


def part_stamps(path, topic):
    """Stamps of ``topic`` in an unclosed ``.part``, record by record (mcap's stream reader)."""
    from mcap.records import Channel, Message, Metadata
    from mcap.stream_reader import StreamReader
    out, cid, off = [], None, 0
    if not os.path.exists(path):          # not created yet
        return out
    with open(path, 'rb') as f:
        try:
            for r in StreamReader(f, skip_magic=False, emit_chunks=False).records:
                if isinstance(r, Channel) and r.topic == topic:
                    cid = r.id
                elif isinstance(r, Metadata) and r.name == 'log_time':
                    off = int(r.metadata['offset_ns'])
                elif isinstance(r, Message) and r.channel_id == cid:
                    out.append(r.log_time - off)
        except Exception:       # noqa: BLE001 - the torn end of a killed file
            pass
    return out


@pytest.mark.processes
@pytest.mark.slow
def test_sigkill_of_the_recorder_loses_at_most_the_last_flush_interval(tmp_path, domain, capsys):
    from im_bringup.processes import graph_processes, GraphProcesses
    from im_bringup.testing import wait_for_log, wait_until
    from im_bringup.run_file import Scenario
    from im_bringup.scenario import run_metadata
    sc = Scenario.from_mapping({'task': 'position', 'duration': 30.0}, source='test')
    bag = tmp_path / 'killed.mcap'
    procs = graph_processes(scenario=sc, record=bag, record_metadata=run_metadata(
        sc.task, sc.strategy, sc.controller, sc.variation_label, scenario=sc))
    with GraphProcesses(procs, str(tmp_path), domain) as g:
        g.start()
        assert wait_for_log(g, 'plant', 'starting:'), g.log('plant')
        t_start = time.monotonic()
        # killed in the recorder's steady state: once two chunks of the run are on disk
        flushed = set()

        def two_chunks_on_disk():
            on_disk = part_stamps(partial_path(bag), T.MEAS_CURRENT)
            flushed.add(max(on_disk, default=None))
            return len(flushed - {None}) >= 2
        assert wait_until(two_chunks_on_disk, 60, 0.2), g.log('recorder')[-2000:]
        g.send(signal.SIGKILL, ['recorder'])
        t_kill = time.monotonic()
        # the plant stays within follower_window steps of the recorder's last acknowledgement
        # (every step up to it was received), then goes on without it and names that step
        assert wait_for_log(g, 'plant', "follower 'recorder' acknowledged nothing after", 30), \
            g.log('plant')[-2000:]
        g.send(signal.SIGINT, [p.name for p in procs if p.name != 'recorder'])
        g.wait(30)
    acked = re.search(r"follower 'recorder' acknowledged nothing after ([0-9.]+) s",
                      g.log('plant'))
    k_ack = round(float(acked.group(1)) * 1e9) // PERIOD
    rate = k_ack / (t_kill - t_start)                   # steps per second of wall time
    # at most the last flush interval (and the timer's period, and a little scheduling), and
    # the reorder window's steps the writer holds back for the next chunk (log-time order)
    allowed = rate * (FLUSH_WALL_S + 2 * FLUSH_CHECK_S + 0.2) + LOCKSTEP_DEPTH
    assert not bag.exists() and partial_path(bag).exists()
    on_disk = part_stamps(partial_path(bag), T.MEAS_CURRENT)
    assert on_disk, 'nothing of the run reached the disk'
    assert max(on_disk) // PERIOD >= k_ack - allowed, (max(on_disk) // PERIOD, k_ack, rate)

    out = tmp_path / 'saved.mcap'
    code = rec.main([str(bag), '-o', str(out)])
    cap = capsys.readouterr()
    assert code == 1, cap
    for topic in (T.MEAS_CURRENT, T.MEAS_SHAFT, T.CMD_VOLTAGE, T.OBS_FLUX):
        steps = sorted(t // PERIOD for t in mcap_stamps(out, topic))
        assert steps == list(range(steps[-1] + 1)), topic            # a prefix, no hole
        assert steps[-1] >= k_ack - allowed - 1, (topic, steps[-1], k_ack, allowed)
    saved = max(mcap_stamps(out, T.MEAS_CURRENT))
    assert 'nothing lost' not in cap.out
    # the missing tail named: from the last saved stamp to the run file's end (30 s)
    last = max(t for topic in T.RECORDED_TOPICS for t in mcap_stamps(out, topic))
    assert f'lost t = {last * 1e-9:.9f} .. end of run (30.000000000 s' in cap.err, cap.err
    assert saved <= last
    # the output's run record says what was saved, the original duration is kept beside it
    md = info(out).metadata
    assert rec._run_file(md['run'])['duration'] == pytest.approx(last * 1e-9)
    assert md['recovered_from']['run_duration_s'] == '30.0'


def _write_timed(path, n, sleep_every, **kw):
    with BagWriter(path, **kw) as w:
        for k in range(n):
            w.write_vector3(T.MEAS_CURRENT, k * PERIOD, float(k), 0.0)
            if k % sleep_every == sleep_every - 1:
                time.sleep(0.05)
        return dict(w.flushes)


def test_a_chunk_is_flushed_after_a_second_of_wall_time_or_4_mib(tmp_path):
    from mcap.reader import make_reader
    # slow and small: 1 s of wall time closes a chunk long before 4 MiB
    flushes = _write_timed(tmp_path / 'slow.mcap', 2000, 40, flush_wall_s=0.2)
    assert flushes['time'] >= 8 and flushes['size'] == 0, flushes
    # fast: 4 MiB closes it first
    path = tmp_path / 'fast.mcap'
    with BagWriter(path, compression='none') as w:
        w.add_topic('/x', 'std_msgs/msg/Header')
        data = os.urandom(4000)
        for k in range(3000):
            w.write_serialized('/x', data, k)
        flushes = dict(w.flushes)
    with open(path, 'rb') as f:
        sizes = [c.uncompressed_size for c in make_reader(f).get_summary().chunk_indexes]
    assert flushes['size'] == 2 and max(sizes) < (4 << 20) + 4023 + 23, (flushes, sizes)


def test_a_quiet_writer_is_on_disk_after_flush_due(tmp_path):
    path = tmp_path / 'quiet.mcap'
    w = BagWriter(path, flush_wall_s=0.1)
    w.write_vector3(T.MEAS_CURRENT, 0, 1.0, 2.0)
    assert not w.flush_due()                    # not yet due
    assert part_stamps(partial_path(path), T.MEAS_CURRENT) == []
    time.sleep(0.15)
    assert w.flush_due()
    assert part_stamps(partial_path(path), T.MEAS_CURRENT) == [0]
    w.close()


def log_times_in_file_order(path):
    """Every message's (log time, publish time) in the order the file holds them (mcap stream)."""
    from mcap.records import Message
    from mcap.stream_reader import StreamReader
    with open(path, 'rb') as f:
        return [(r.log_time, r.publish_time) for r in
                StreamReader(f, skip_magic=False, emit_chunks=False).records
                if isinstance(r, Message)]


def assert_log_time_order(path):
    """``mcap doctor --strict-message-order``'s rule: log times never decrease in file order."""
    times = [t for t, _ in log_times_in_file_order(path)]
    assert times, path
    back = [(i, a, b) for i, (a, b) in enumerate(zip(times, times[1:])) if b < a]
    assert not back, f'{path}: {len(back)} log times go back, first {back[:3]}'


@pytest.mark.processes
@pytest.mark.slow
def test_every_recording_path_writes_log_times_in_order(tmp_path, domain):
    """
    The recorder of separate processes, the in-process graph, and recover's copy of either.

    In one process the observer publishes x̂_{k+1} before the plant's step k+1; across processes
    messages arrive in any order within the protocol's window. Both bags are in log-time order,
    and every message keeps its own stamp as publish time.
    """
    from im_bringup.processes import graph_processes, GraphProcesses
    from im_bringup.testing import assert_all_ended, run_graph
    from im_common.cdr import header_stamp_ns
    from im_recording.bag import iter_raw
    inproc = tmp_path / 'inproc.mcap'
    run_graph(task='position', strategy='min_energy', duration=0.05, record=str(inproc))
    assert_log_time_order(inproc)
    procs_bag = tmp_path / 'procs.mcap'
    procs = graph_processes('position', 'min_energy', duration=0.3, record=procs_bag)
    with GraphProcesses(procs, str(tmp_path / 'logs'), domain) as g:
        assert_all_ended(g, g.start().wait(120))
    assert_log_time_order(procs_bag)
    late = int(info(procs_bag).metadata['recording']['written_late'])
    for bag in (inproc, procs_bag):
        pairs = log_times_in_file_order(bag)
        moved = sum(1 for t, pub in pairs if t != pub)
        assert moved == (late if bag == procs_bag else 0), (bag, moved)
        # nothing lost or duplicated by the reordering: every header stamp is a publish time
        # (publish times are offset to the wall-clock start like the log times: docs/recording.md)
        stamps = Counter(header_stamp_ns(d) for _, _, _, d in iter_raw(bag))
        off = info(bag).log_time_offset
        assert off > 0 and stamps == Counter(pub - off for _, pub in pairs), bag
        out = tmp_path / f'{bag.stem}.recovered.mcap'
        rec.recover(bag, str(out))
        assert_log_time_order(out)


def test_the_writer_orders_each_chunk_within_its_window_and_clamps_what_comes_later(tmp_path):
    path = tmp_path / 'order.mcap'
    w = BagWriter(path, chunk_size=1024, flush_wall_s=None)
    w.set_reorder_window(10 * PERIOD)
    sent = []
    for k in range(300):                  # each step's estimate of k+1 comes before step k+1
        for t in ((k + 1) * PERIOD, k * PERIOD):
            w.write_vector3(T.MEAS_CURRENT, t, float(k), 0.0)
            sent.append(t)
    w.write_vector3(T.MEAS_CURRENT, 5 * PERIOD, -1.0, 0.0)     # far later than the window
    w.close()
    assert w.late_messages == 1
    assert_log_time_order(path)
    pairs = log_times_in_file_order(path)
    assert sorted(pub for _, pub in pairs) == sorted(sent + [5 * PERIOD])
    moved = [i for i, (t, pub) in enumerate(pairs) if t != pub]
    assert len(moved) == 1 and pairs[moved[0]][1] == 5 * PERIOD
    # written at the latest log time the file held when it came, not at its stamp
    assert pairs[moved[0]][0] == pairs[moved[0] - 1][0] > 5 * PERIOD + 10 * PERIOD


@pytest.mark.processes
@pytest.mark.slow
def test_a_late_recorder_stopped_mid_run_counts_exactly_what_its_bag_lacks(tmp_path, domain):
    """
    The issue's recorder, by hand: started after the run, stopped (SIGINT) while it goes on.

    Its metadata says where it joined and to which step it counted, and per lock-step topic the
    missing figure equals what the bag lacks over that span, read with the mcap reader.
    """
    from im_bringup.processes import graph_processes, GraphProcesses
    from im_bringup.testing import wait_for_log, wait_until
    procs = graph_processes('position', 'min_energy', duration=30.0)
    key = procs[0].parameters['graph_key_file']
    bag = tmp_path / 'late.mcap'
    recorder = graph_processes('position', 'min_energy', duration=30.0, record=bag,
                               key_file=key)[-1]
    with GraphProcesses(procs + [recorder], str(tmp_path), domain) as g:
        g.start(only=['plant', 'controller', 'observer'])
        assert wait_for_log(g, 'plant', 'starting:'), g.log('plant')     # mid-run from here
        g.start_one('recorder')
        assert wait_for_log(g, 'plant', "lossless follower 'recorder' joined at step"), \
            g.log('plant')[-2000:]
        # stopped once it has put part of the run on disk
        assert wait_until(lambda: part_stamps(partial_path(bag), T.MEAS_CURRENT), 60, 0.2), \
            g.log('recorder')[-2000:]
        g.send(signal.SIGINT, ['recorder'])
        assert g.popen['recorder'].wait(30) == 0, g.log('recorder')[-2000:]
        g.send(signal.SIGINT)
        g.wait(30)
    meta = info(bag).metadata['recording']
    first, last = int(meta['counted_from_step']), int(meta['counted_to_step'])
    assert meta['joined_at_step'] == str(first) and first > 0, meta
    assert 'joined at step' in meta['missing_counted'] and meta['run_end'] == 'not seen'
    total = 0
    for topic in (T.MEAS_CURRENT, T.MEAS_SHAFT, T.CMD_VOLTAGE, T.OBS_FLUX):
        # the steps the bag holds, by the messages' own stamps: under load a message can
        # reach the recorder later than its reorder window and be written at a later log time
        have = {t // PERIOD for t in mcap_stamps(bag, topic, 'publish_time')}
        end = last if topic in (T.MEAS_CURRENT, T.MEAS_SHAFT) else last - 1
        lacks = len(set(range(first, end + 1)) - have)
        assert int(meta[f'missing_steps{topic}']) == lacks, (topic, meta)
        total += lacks
    assert int(meta['missing_steps']) == total
    assert 'joined at step' in g.log('recorder')


@pytest.mark.processes
@pytest.mark.slow
def test_sigkill_of_the_in_process_scenario_loses_at_most_the_last_flush_interval(tmp_path):
    """
    The in-process writer: ``scenario --record`` SIGKILLed mid-run.

    Its own progress line (every 0.5 s: the plant's step and the rate) says how far the run was
    when killed; the ``.part`` holds every step up to at most the last flush interval before.
    """
    import subprocess
    import threading
    from im_bringup.processes import executable_path
    bag = tmp_path / 'killed.mcap'
    p = subprocess.Popen([executable_path('im_bringup', 'scenario'), '--task', 'speed',
                          '--duration', '60', '--record', str(bag)],
                         stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    seen = []

    def read():
        buf = b''
        while True:
            c = p.stderr.read(1)
            if not c:
                return
            buf += c
            if c == b'\r' and len(buf) > 1:
                last = buf[:-1].rsplit(b'\r', 1)[-1]
                m = re.search(rb'step (\d+)\s+\S+ %\s+(\d+) steps/s', last)
                if m:
                    seen.append((int(m.group(1)), int(m.group(2))))
    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and (len(seen) < 6 or seen[-1][0] < 3000):
        time.sleep(0.05)
    assert seen, f'hang: no progress line from the scenario in 120 s (exit code {p.poll()})'
    k_seen, rate = seen[-1]
    p.kill()
    p.wait(timeout=30)
    reader.join(timeout=5)
    on_disk = part_stamps(partial_path(bag), T.MEAS_CURRENT)
    steps = sorted(t // PERIOD for t in on_disk)
    assert steps == list(range(steps[-1] + 1))                       # a prefix, no hole
    # the step printed last was reached before the kill; at most the flush interval (and the
    # timer's period, the reorder window, the progress line's own 0.5 s) is not on disk
    allowed = rate * (FLUSH_WALL_S + 2 * FLUSH_CHECK_S + 0.2) + LOCKSTEP_DEPTH
    assert steps[-1] >= k_seen - allowed, (steps[-1], k_seen, rate)
