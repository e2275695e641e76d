"""Fault injection on the installed tools (issue 11): signals and kills mid-run, outputs that
would overwrite data, corrupt files, bad YAML. Each test runs the executables exactly as
``ros2 run`` resolves them (the ament index; build and source the workspace first) and checks
what a user would see: the exit code, one line on stderr without a traceback, and files that are
complete, readable by ``rosbags``, or untouched.
"""
import os
import signal
import subprocess
import time
from pathlib import Path

import pytest

from im_bringup.bag import BagError, info, iter_raw, partial_path
from im_bringup.run import load_run


def exe(name: str) -> str:
    from ament_index_python.packages import PackageNotFoundError, get_package_prefix
    try:
        prefix = get_package_prefix('im_bringup')
    except PackageNotFoundError:
        pytest.fail('im_bringup is not in the ament index: run `make build` and source '
                    'install/setup.bash')
    return os.path.join(prefix, 'lib', 'im_bringup', name)


def run_tool(*args, timeout=120):
    return subprocess.run([exe(args[0]), *map(str, args[1:])], capture_output=True, text=True,
                          timeout=timeout)


def one_line(err: str) -> str:
    assert 'Traceback' not in err, err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1, err
    return lines[0]


def rosbags_count(path) -> int:
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore
    with AnyReader([Path(path)], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as r:
        return sum(1 for _ in r.messages())


@pytest.fixture(scope='module')
def short_bag(tmp_path_factory):
    d = tmp_path_factory.mktemp('fi')
    bag = d / 'short.mcap'
    r = run_tool('scenario', '--task', 'speed', '--duration', '0.05', '--record', bag,
                 '--no-progress')
    assert r.returncode == 0, r.stderr
    return bag


def _start_long(tmp_path, name='long.mcap'):
    bag = tmp_path / name
    p = subprocess.Popen([exe('scenario'), '--task', 'speed', '--duration', '20', '--record',
                          str(bag), '--no-progress'], stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True)
    part = partial_path(bag)
    t_end = time.monotonic() + 90
    while time.monotonic() < t_end:     # mid-run: at least one chunk on disk
        if part.exists() and part.stat().st_size > 200_000:
            return p, bag
        if p.poll() is not None:
            pytest.fail(f'scenario ended before the signal: {p.stderr.read()}')
        time.sleep(0.1)
    p.kill()
    pytest.fail('scenario wrote no chunk within 90 s')


@pytest.mark.parametrize('sig', [signal.SIGTERM, signal.SIGINT, signal.SIGHUP])
def test_stop_signal_mid_run_leaves_a_complete_recording_and_summary(tmp_path, sig):
    import json
    p, bag = _start_long(tmp_path)
    p.send_signal(sig)
    _out, err = p.communicate(timeout=60)
    assert p.returncode == 128 + sig, err
    assert 'Traceback' not in err and f'interrupted by {sig.name}' in err
    assert bag.exists() and not partial_path(bag).exists()
    n = rosbags_count(bag)
    assert n == info(bag).message_count > 0
    summary = json.loads(bag.with_suffix('.json').read_text())
    assert summary['interrupted'] == sig.name and 0 < summary['steps'] < 200_000
    stamps = [t for _, _, t, _ in iter_raw(bag, ['/im/measured/current'])]
    assert stamps == sorted(stamps) and len(stamps) >= summary['steps']
    # the report says the run is incomplete
    r = run_tool('report', bag, '--no-plots', '--out', tmp_path / 'rep')
    assert r.returncode == 0, r.stderr
    md = (tmp_path / 'rep' / 'report.md').read_text()
    assert f'interrupted by {sig.name}' in md and 'control instants recorded' in md


def test_hard_kill_leaves_the_final_name_free_and_recover_finds_the_part(tmp_path):
    p, bag = _start_long(tmp_path, 'killed.mcap')
    p.kill()
    p.wait(timeout=30)
    assert not bag.exists() and partial_path(bag).exists()
    r = run_tool('report', bag, '--no-plots')
    assert r.returncode == 2 and 'recover' in one_line(r.stderr)
    r = run_tool('recover', bag)
    # 0: the kill left whole records; 1 only if it tore the chunk being written, which is said
    assert r.returncode == 0 and r.stderr == '' or r.returncode == 1 and 'torn' in r.stderr, r
    fixed = tmp_path / 'killed.recovered.mcap'
    assert rosbags_count(fixed) == info(fixed).message_count > 0
    status = run_tool('report', fixed, '--no-plots', '--out', tmp_path / 'rep')
    assert status.returncode == 0
    assert 'recovered from' in (tmp_path / 'rep' / 'report.md').read_text()


def test_reestimate_onto_its_own_input_is_refused_and_the_input_is_byte_identical(short_bag):
    before = short_bag.read_bytes()
    r = run_tool('replay', short_bag, '--reestimate', '--out', short_bag, '--force')
    assert r.returncode == 2
    assert 'also an input' in one_line(r.stderr) and str(short_bag) in r.stderr
    assert short_bag.read_bytes() == before
    link = short_bag.parent / 'alias.mcap'       # the same file under another name
    link.symlink_to(short_bag)
    r = run_tool('replay', short_bag, '--reestimate', '--out', link, '--force')
    assert r.returncode == 2 and 'also an input' in one_line(r.stderr)
    assert short_bag.read_bytes() == before


def test_scenario_outputs_never_overwrite_without_force(short_bag, tmp_path):
    victim = tmp_path / 'precious.mcap'
    victim.write_bytes(short_bag.read_bytes())
    before = victim.read_bytes()
    r = run_tool('scenario', '--duration', '0.01', '--summary', victim, '--no-progress')
    assert r.returncode == 2 and 'exists' in one_line(r.stderr)
    assert victim.read_bytes() == before
    x = tmp_path / 'x.mcap'
    r = run_tool('scenario', '--duration', '0.01', '--record', x, '--summary', x, '--force',
                 '--no-progress')
    assert r.returncode == 2 and 'same file' in one_line(r.stderr)
    assert not x.exists()
    r = run_tool('scenario', '--duration', '0.01', '--record', victim, '--no-progress')
    assert r.returncode == 2 and 'exists' in one_line(r.stderr)
    assert victim.read_bytes() == before


@pytest.mark.parametrize('text', [None, 'plant: {ros__parameters: {T_s: [1,\n', '- a\n- b\n',
                                  'plant: 3\n'])
def test_scenario_bad_params_file_is_one_line(tmp_path, text):
    f = tmp_path / 'p.yaml'
    if text is not None:
        f.write_text(text)
    r = run_tool('scenario', '--duration', '0.01', '--params-file', f, '--no-progress')
    assert r.returncode == 2
    assert str(f) in one_line(r.stderr)


def test_corrupt_middle_chunk_recover_keeps_the_rest(short_bag, tmp_path):
    from mcap.reader import make_reader
    from im_bringup.bag import BagWriter
    src = tmp_path / 'three.mcap'
    with BagWriter(src, chunk_size=128 * 1024) as w:     # the recorded run, in small chunks
        for topic, tname in info(short_bag).topics.items():
            w.add_topic(topic, tname)
        for topic, _tname, t, data in iter_raw(short_bag):
            w.write_serialized(topic, data, t)
    with open(src, 'rb') as f:
        ci = make_reader(f).get_summary().chunk_indexes
    assert len(ci) >= 3
    n_all = info(src).message_count
    data = bytearray(src.read_bytes())
    mid = ci[1].chunk_start_offset + ci[1].chunk_length // 2
    data[mid - 2048:mid + 2048] = os.urandom(4096)
    bad = tmp_path / 'bad.mcap'
    bad.write_bytes(bytes(data))
    r = run_tool('report', bad, '--no-plots')
    assert r.returncode == 2 and 'bad.mcap' in one_line(r.stderr)
    r = run_tool('recover', bad)
    assert r.returncode == 1 and 'skipped bytes' in r.stderr and 'lost t = ' in r.stderr
    fixed = tmp_path / 'bad.recovered.mcap'
    assert rosbags_count(fixed) >= 0.55 * n_all
    with pytest.raises(BagError):
        load_run(bad)


def test_sigterm_during_reestimate_leaves_a_complete_output(tmp_path):
    bag = tmp_path / 'two_s.mcap'
    r = run_tool('scenario', '--task', 'speed', '--duration', '2', '--record', bag,
                 '--no-progress', timeout=300)
    assert r.returncode == 0, r.stderr
    out = tmp_path / 'reest.mcap'
    p = subprocess.Popen([exe('replay'), str(bag), '--reestimate', '--out', str(out)],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    part = partial_path(out)
    t_end = time.monotonic() + 120
    while not (part.exists() and part.stat().st_size > 100_000):   # writing, first chunk out
        assert p.poll() is None and time.monotonic() < t_end, p.stderr.read()
        time.sleep(0.01)
    p.send_signal(signal.SIGTERM)
    _o, err = p.communicate(timeout=120)
    assert p.returncode == 143, err
    assert 'interrupted by SIGTERM' in err and 'Traceback' not in err
    n = rosbags_count(out)
    assert 0 < n == info(out).message_count < info(bag).message_count
    reest = [t for _, _, t, _ in iter_raw(out, ['/im/reestimate/observer/flux'])]
    meas = [t for _, _, t, _ in iter_raw(out, ['/im/measured/current'])]
    assert reest and max(meas) <= max(reest)     # nothing recorded past the last finished step


def test_summary_equals_the_report_of_its_recording(short_bag, tmp_path):
    """The live summary (streamed while the run went) and the report of the bag it recorded are
    the same numbers."""
    import json
    summary = json.loads(short_bag.with_suffix('.json').read_text())
    r = run_tool('report', short_bag, '--no-plots', '--out', tmp_path / 'rep')
    assert r.returncode == 0, r.stderr
    fig = json.loads((tmp_path / 'rep' / 'report.json').read_text())['runs'][0]['figures']
    keys = ('E_in_J', 'E_loss_J', 'balance_residual_J', 'speed_err_max_rad_s',
            'speed_err_rms_rad_s', 'torque_err_max_Nm', 'flux_est_err_rms_Wb', 'V_max_V',
            'i_max_A', 'duration_s')
    assert all(k in summary and k in fig for k in keys)
    for k in keys:
        assert fig[k] == pytest.approx(summary[k], rel=1e-12), k
    status = json.loads((tmp_path / 'rep' / 'report.json').read_text())['runs'][0]['status']
    assert status['notes'] == [] and status['interrupted'] is None     # a whole run


def test_report_refuses_to_replace_a_report_or_write_into_a_bag(short_bag, tmp_path):
    out = tmp_path / 'rep'
    assert run_tool('report', short_bag, '--no-plots', '--out', out).returncode == 0
    before = (out / 'report.md').read_bytes()
    r = run_tool('report', short_bag, '--no-plots', '--out', out)
    assert r.returncode == 2 and 'exists' in one_line(r.stderr)
    assert (out / 'report.md').read_bytes() == before
    assert run_tool('report', short_bag, '--no-plots', '--out', out, '--force').returncode == 0
    bag_bytes = short_bag.read_bytes()
    r = run_tool('report', short_bag, '--no-plots', '--out', short_bag, '--force')
    assert r.returncode == 2 and 'directory' in one_line(r.stderr)
    assert short_bag.read_bytes() == bag_bytes
