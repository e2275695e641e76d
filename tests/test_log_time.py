"""
Log times at the wall-clock date the run was recorded, stamps in simulated time (issue 35).

A recording of a run offsets its log times to the wall-clock time it started (``log_time:
wall``, the default of ``scenario --record``, ``launch record:=`` and the recorder), so viewers
place it at its date; ``simulated`` keeps log time = stamp. Every reader of the project gives
simulated stamps either way, and replay and recover keep what the file holds.
"""
import datetime
import time

from im_common import cdr
from im_recording import recover as rec
from im_recording.bag import (BagWriter, info, iter_raw, log_time_offset, log_time_offset_for,
                              LOG_TIME_RECORD)
from mcap.reader import make_reader
import pytest
import yaml

V3 = '/im/measured/current'
DAY = 86_400 * 10 ** 9


def _raw_log_times(path):
    with open(path, 'rb') as f:
        return [(m.log_time, m.publish_time) for _s, _c, m in make_reader(f).iter_messages(
            log_time_order=False)]


def _write(path, offset, steps=50, **kw):
    with BagWriter(path, log_time_offset_ns=offset, **kw) as w:
        w.set_reorder_window(5_000_000)
        for k in range(steps):      # one message out of order: the writer sorts it
            t = (k + 1 if k % 10 == 3 else k - 1 if k % 10 == 4 else k) * 1_000_000
            w.write_vector3(V3, t, float(k), 0.0)
    return path


def test_wall_log_times_place_the_run_at_its_date_and_readers_give_the_stamps(tmp_path):
    before = time.time_ns()
    off = log_time_offset_for('wall')
    assert before <= off <= time.time_ns()
    path = _write(tmp_path / 'wall.mcap', off)
    raw = _raw_log_times(path)
    # in the file: offset + stamp, log and publish time alike, never decreasing in file order
    assert [t for t, _ in raw] == sorted(t for t, _ in raw)
    assert {t - off for t, _ in raw} == {k * 1_000_000 for k in range(50)}
    assert all(p == t for t, p in raw)
    # every reader: the stamps in simulated time, whatever the file holds
    stamps = [t for _, _, t, _ in iter_raw(path)]
    assert stamps == [k * 1_000_000 for k in range(50)]
    assert [t for _, _, t, _ in iter_raw(path, log_time=True)] == [t for t, _ in raw]
    bi = info(path)
    assert bi.log_time_offset == off and bi.start_ns == off
    rec_ = bi.metadata[LOG_TIME_RECORD]
    started = datetime.datetime.fromisoformat(rec_['started_utc'])
    assert abs(started.timestamp() * 1e9 - off) < 1e3 and rec_['clock'] == 'wall'
    # rosbag2's own record (ros2 bag info) starts at the date too
    rb = yaml.safe_load(bi.metadata['rosbag2']['serialized_metadata'])
    assert rb['starting_time']['nanoseconds_since_epoch'] == off


def test_simulated_log_times_are_the_stamps_and_carry_no_record(tmp_path):
    assert log_time_offset_for('simulated') == 0
    path = _write(tmp_path / 'sim.mcap', 0)
    assert [t for t, _ in _raw_log_times(path)] == [k * 1_000_000 for k in range(50)]
    assert LOG_TIME_RECORD not in info(path).metadata and info(path).log_time_offset == 0


def test_a_bad_log_time_choice_or_record_is_refused_with_one_line(tmp_path):
    with pytest.raises(ValueError, match="invalid log_time 'utc'"):
        log_time_offset_for('utc')
    with pytest.raises(ValueError, match='log_time_offset_ns must be >= 0'):
        BagWriter(tmp_path / 'x.mcap', log_time_offset_ns=-1)
    from im_recording.bag import BagError
    with pytest.raises(BagError, match="record 'log_time': offset_ns 'soon'"):
        log_time_offset({LOG_TIME_RECORD: {'offset_ns': 'soon'}}, 'f.mcap')


def test_recover_of_a_wall_clock_bag_states_what_was_lost_in_simulated_time(tmp_path, capsys):
    off = 1_795_000_000 * 10 ** 9                        # 2026-11-18
    src = tmp_path / 'three.mcap'
    run = {'yaml': yaml.safe_dump({'task': 'speed', 'T_s': 0.001, 'duration': 3.0})}
    with BagWriter(src, chunk_size=4096, metadata={'run': run}, log_time_offset_ns=off) as w:
        for k in range(3001):
            w.write_vector3(V3, k * 1_000_000, float(k), 0.0)
    with open(src, 'rb') as f:
        ci = sorted(make_reader(f).get_summary().chunk_indexes,
                    key=lambda c: c.chunk_start_offset)
    cut = ci[int(len(ci) * 0.6)]
    bad = tmp_path / 'cut.mcap'
    bad.write_bytes(src.read_bytes()[:cut.chunk_start_offset + cut.chunk_length // 2])
    out = tmp_path / 'saved.mcap'
    assert rec.main([str(bad), '-o', str(out)]) == 1
    cap = capsys.readouterr()
    t0, t1 = cut.message_start_time - off, cut.message_end_time - off
    assert 0 < t0 < t1 < 3 * 10 ** 9
    assert f'lost t = {t0 * 1e-9:.9f} .. {t1 * 1e-9:.9f} s' in cap.err, cap.err
    assert f'lost t = {t1 * 1e-9:.9f} .. end of run (3.000000000 s' in cap.err, cap.err
    assert '(t = 0.000000000 .. ' in cap.out, cap.out
    # the output keeps the file's log times and its record; its run record the saved duration
    bi = info(out)
    assert bi.log_time_offset == off and bi.start_ns == off
    saved_last = max(t for _, _, t, _ in iter_raw(out))
    assert saved_last < t0
    assert yaml.safe_load(bi.metadata['run']['yaml'])['duration'] == saved_last * 1e-9


def test_the_recorder_of_the_processes_is_told_the_choice():
    from im_bringup.processes import graph_processes
    for choice in ('wall', 'simulated'):
        procs = graph_processes('speed', 'min_energy', record='x.mcap', log_time=choice)
        args = next(p for p in procs if p.name == 'recorder').arguments
        assert args[args.index('--log-time') + 1] == choice
    with pytest.raises(ValueError, match="invalid log_time 'utc'"):
        graph_processes('speed', 'min_energy', record='x.mcap', log_time='utc')


def test_a_recorded_run_is_at_its_date_and_replay_keeps_it(tmp_path):
    from im_bringup.testing import run_graph
    from im_recording.replay import reestimate
    start = time.time_ns()
    wall = tmp_path / 'wall.mcap'
    run_graph('speed', duration=0.02, record=str(wall))
    bi = info(wall)
    assert start <= bi.log_time_offset <= time.time_ns() and bi.start_ns >= bi.log_time_offset
    assert bi.end_ns - bi.start_ns < DAY
    stamps = [t for _, _, t, _ in iter_raw(wall, [V3])]
    assert stamps[0] == 0 and stamps[-1] < 0.03e9
    # replay --reestimate: the output at the same date, its new topics on the same stamps
    out = tmp_path / 'reest.mcap'
    reestimate(wall, out)
    bo = info(out)
    assert bo.log_time_offset == bi.log_time_offset
    flux = [t for _, _, t, _ in iter_raw(out, ['/im/reestimate/observer/flux'])]
    assert flux and set(flux) <= set(stamps) | {stamps[-1] + 100_000}
    assert min(t for t, _ in _raw_log_times(out)) == bi.log_time_offset
    # the same run with simulated log times: the same stamps and contents
    sim = tmp_path / 'sim.mcap'
    run_graph('speed', duration=0.02, record=str(sim), log_time='simulated')
    assert info(sim).log_time_offset == 0

    def physics(path):          # the frame ids carry each run's own signature: the values
        return [(tp, t, cdr.decode_vector3_stamped(d)[2:])
                for tp, _, t, d in iter_raw(path, [V3, '/im/command/voltage'])]
    assert physics(sim) == physics(wall)


def test_recover_says_so_when_the_log_time_record_cannot_be_read(tmp_path):
    src = tmp_path / 'odd.mcap'
    with BagWriter(src, chunk_size=4096) as w:
        w.add_metadata(LOG_TIME_RECORD, {'clock': 'wall', 'offset_ns': 'soon'})
        for k in range(500):
            w.write_vector3(V3, k * 1_000_000, float(k), 0.0)
    r = rec.recover(src, str(tmp_path / 'out.mcap'))
    assert any("offset_ns 'soon'" in n and 'log times, not stamps' in n for n in r['notes']), r
