"""
Fault injection on the installed tools (issue 11).

Signals and kills mid-run, outputs that would overwrite data, corrupt files, bad YAML. Each test
runs the executables exactly as ``ros2 run`` resolves them (the ament index; build and source the
workspace first) and checks what a user would see: the exit code, one line on stderr without a
traceback, and files that are complete, readable by ``rosbags``, or untouched.
"""
import os
from pathlib import Path
import re
import signal
import subprocess
import sys
import time

from im_recording.bag import BagError, info, iter_raw, partial_path
from im_recording.recorded_run import load_run
import pytest


#: the package of each executable the tests start
PACKAGE_OF = {'scenario': 'im_bringup', 'commission': 'im_bringup', 'record': 'im_recording',
              'replay': 'im_recording', 'report': 'im_recording', 'recover': 'im_recording',
              'campaign': 'im_studies', 'robust_study': 'im_studies'}


def exe(name: str) -> str:
    from ament_index_python.packages import PackageNotFoundError, get_package_prefix
    pkg = PACKAGE_OF[name]
    try:
        prefix = get_package_prefix(pkg)
    except PackageNotFoundError:
        pytest.fail(f'{pkg} is not in the ament index: run `make build` and source '
                    'install/setup.bash')
    return os.path.join(prefix, 'lib', pkg, name)


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


@pytest.mark.processes
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
    assert f'interrupted by {sig.name}' in md and 'steps recorded' in md


@pytest.mark.processes
@pytest.mark.slow
def test_hard_kill_leaves_the_final_name_free_and_recover_finds_the_part(tmp_path):
    p, bag = _start_long(tmp_path, 'killed.mcap')
    p.kill()
    p.wait(timeout=30)
    assert not bag.exists() and partial_path(bag).exists()
    r = run_tool('report', bag, '--no-plots')
    assert r.returncode == 2 and 'recover' in one_line(r.stderr)
    r = run_tool('recover', bag)
    # the kill left whole records (or tore the chunk being written, which is said), but the run
    # went on after the last of them: that tail is lost and named, never "nothing lost"
    assert r.returncode == 1 and 'nothing lost' not in r.stdout, r
    assert re.search(r'lost t = [0-9.]+ \.\. end of run \(20\.0+ s per its run file',
                     r.stderr), r
    fixed = tmp_path / 'killed.recovered.mcap'
    assert rosbags_count(fixed) == info(fixed).message_count > 0
    status = run_tool('report', fixed, '--no-plots', '--out', tmp_path / 'rep')
    assert status.returncode == 0
    assert 'recovered from' in (tmp_path / 'rep' / 'report.md').read_text()


@pytest.mark.processes
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


@pytest.mark.processes
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
@pytest.mark.processes
def test_scenario_bad_params_file_is_one_line(tmp_path, text):
    f = tmp_path / 'p.yaml'
    if text is not None:
        f.write_text(text)
    r = run_tool('scenario', '--duration', '0.01', '--params-file', f, '--no-progress')
    assert r.returncode == 2
    assert str(f) in one_line(r.stderr)


@pytest.mark.processes
def test_corrupt_middle_chunk_recover_keeps_the_rest(short_bag, tmp_path):
    from mcap.reader import make_reader
    from im_recording.bag import BagWriter
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


@pytest.mark.processes
@pytest.mark.slow
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


@pytest.mark.processes
def test_summary_equals_the_report_of_its_recording(short_bag, tmp_path):
    """
    Check that the live summary equals the report of the recorded bag.

    The live summary (streamed while the run went) and the report of the bag it recorded are the
    same numbers.
    """
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


@pytest.mark.processes
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


# ------------------------------------------------------------------------------------------
# Issue 23: I/O and configuration faults — one line, no traceback, no result lost
# ------------------------------------------------------------------------------------------
#: Loaded by every Python process started with ``env=enospc_env(...)`` (the scenario, and with
#: --processes the recorder it starts): the MCAP being recorded (``*.mcap.part``) takes
#: ``IM_TEST_ENOSPC_BYTES`` bytes, then its writes fail with ENOSPC — a disk filling up.
ENOSPC_SITECUSTOMIZE = """
import builtins, errno, io, os
_LIMIT = int(os.environ['IM_TEST_ENOSPC_BYTES'])
_open = builtins.open


class _Full(io.RawIOBase):
    def __init__(self, path):
        self._f = _open(path, 'wb', buffering=0)
        self._n = 0

    def writable(self):
        return True

    def write(self, b):
        room = _LIMIT - self._n
        if room <= 0:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        n = self._f.write(bytes(b)[:room])
        self._n += n
        return n

    def fileno(self):
        return self._f.fileno()

    def close(self):
        self._f.close()
        super().close()


def _open_full(file, mode='r', *a, **k):
    if isinstance(file, (str, os.PathLike)) and str(file).endswith('.mcap.part') and 'w' in mode:
        return io.BufferedWriter(_Full(file))
    return _open(file, mode, *a, **k)


builtins.open = _open_full
"""


def assert_advice_names_existing_files(line: str) -> None:
    """Every file a `recover` advice in ``line`` names as its input exists."""
    advice = re.findall(r'`ros2 run im_recording recover ([^` ]+)', line)
    assert advice, line
    for path in advice:
        assert os.path.exists(path), (path, line)


def enospc_env(tmp_path, limit: int) -> dict:
    site = tmp_path / 'enospc_site'
    site.mkdir(exist_ok=True)
    (site / 'sitecustomize.py').write_text(ENOSPC_SITECUSTOMIZE)
    env = dict(os.environ, IM_TEST_ENOSPC_BYTES=str(limit))
    env['PYTHONPATH'] = os.pathsep.join([str(site), env.get('PYTHONPATH', '')])
    return env


@pytest.mark.processes
@pytest.mark.slow
def test_disk_full_while_recording_is_one_line_the_part_recovers_and_the_summary_is_written(
        tmp_path):
    import json
    bag = tmp_path / 'full.mcap'
    # the disk holds 2.5 MB, the 5 s run's bag about 4.6 MB: chunks reach the disk about every
    # second of wall time (BagWriter.flush_due), each well under 2.5 MB, so the disk fills in the
    # middle of the run with whole chunks before it (at 1 MB the first chunk itself could fill it,
    # and a 1 s run of three nodes ended before the disk was full)
    r = subprocess.run([exe('scenario'), '--task', 'speed', '--duration', '5.0', '--record',
                        str(bag), '--no-progress'], capture_output=True, text=True, timeout=300,
                       env=enospc_env(tmp_path, 2_500_000))
    assert r.returncode == 1, r.stderr
    line = one_line('\n'.join(ln for ln in r.stderr.splitlines() if not ln.startswith('[INFO]')))
    assert str(partial_path(bag)) in line and 'No space left on device' in line, line
    assert not bag.exists() and partial_path(bag).exists()
    summary = json.loads(bag.with_suffix('.json').read_text())
    assert summary['ok'] is False and 'No space left on device' in summary['failures']['recorder']
    assert 0 < summary['steps'] < 50_000
    assert summary['partial'] is True and summary['E_in_J'] > 0      # the figures of what ran
    assert_advice_names_existing_files(line)
    fix = run_tool('recover', bag)
    # the run went on after the last write that reached the disk: that tail is named, exit 1
    assert fix.returncode == 1 and 'end of run (5.000000000 s' in fix.stderr, fix.stderr
    assert rosbags_count(tmp_path / 'full.recovered.mcap') > 0


@pytest.mark.processes
@pytest.mark.slow
def test_disk_full_in_the_recorder_process_is_one_error_line_and_a_partial_summary(tmp_path):
    """A full disk ends the recorder, not the run: its ENOSPC line, the summary marked partial."""
    import json
    bag = tmp_path / 'pfull.mcap'
    r = subprocess.run([exe('scenario'), '--task', 'speed', '--duration', '2.0', '--record',
                        str(bag), '--processes', '--no-progress'], capture_output=True,
                       text=True, timeout=300, env=enospc_env(tmp_path, 1_500_000))
    assert r.returncode == 1, r.stderr
    assert 'Traceback' not in r.stderr and 'Traceback' not in (
        tmp_path / 'pfull_logs' / 'recorder.log').read_text()
    errors = [ln for ln in r.stderr.splitlines() if 'error' in ln]
    assert len(errors) == 1 and 'recorder' in errors[0], r.stderr
    assert str(partial_path(bag)) in errors[0] and 'No space left on device' in errors[0]
    assert partial_path(bag).exists()
    assert_advice_names_existing_files(errors[0])
    # the summary holds the figures of every step that reached the disk, marked partial
    summary = json.loads(bag.with_suffix('.json').read_text())
    assert summary['ok'] is False and summary['partial'] is True, summary
    assert summary['steps'] > 0 and summary['E_in_J'] > 0, summary
    fix = run_tool('recover', bag)          # what reached the disk, and the tail it lacks
    assert fix.returncode == 1 and 'end of run (' in fix.stderr, fix.stderr
    assert bag.with_suffix('.json').exists()


def _read_only(directory: Path, argv: list) -> list:
    """
    ``argv`` run with ``directory`` read-only.

    A read-only bind mount in a mount namespace of its own as root (root writes through
    permission bits), mode 0555 otherwise.
    """
    if os.geteuid() != 0:
        directory.chmod(0o555)
        return argv
    d = str(directory)
    return ['unshare', '-m', 'sh', '-c', f'mount --bind "{d}" "{d}" && mount -o remount,bind,ro '
            f'"{d}" "{d}" && exec "$@"', '_'] + argv


@pytest.mark.processes
@pytest.mark.parametrize('option', ['--record', '--summary', '--report', '--write-params'])
def test_read_only_output_is_refused_before_the_run(tmp_path, option):
    ro = tmp_path / 'ro'
    ro.mkdir()
    target = {'--record': ro / 'a.mcap', '--summary': ro / 'a.json', '--report': ro / 'rep',
              '--write-params': ro / 'p.yaml'}[option]
    argv = [exe('scenario'), '--task', 'speed', '--duration', '0.02', '--no-progress', option,
            str(target)]
    if option == '--report':
        argv += ['--record', str(tmp_path / 'r.mcap')]
    r = subprocess.run(_read_only(ro, argv), capture_output=True, text=True, timeout=120)
    try:
        assert r.returncode == 2, r.stderr
        line = one_line(r.stderr)
        assert str(ro) in line and ('Read-only' in line or 'Permission denied' in line), line
        assert 'starting:' not in r.stderr      # refused before any simulation (the plant's line)
        assert not (tmp_path / 'r.mcap').exists() and not list(ro.iterdir())
    finally:
        ro.chmod(0o755)


PARAMS_FAULTS = {
    'unknown': ('k_1: 30.0', ["unknown parameter 'k_1'", "did you mean 'k1'"]),
    'integer': ('k1: 30', ["'k1' = 30", 'integer', '30.0']),
    'string': ('k1: "abc"', ["'k1' = 'abc'", 'real number']),
    'range': ('k1: -5.0', ["'k1' = -5.0", 'range']),
}


@pytest.mark.processes
@pytest.mark.parametrize('fault', sorted(PARAMS_FAULTS))
@pytest.mark.parametrize('processes', [False, True], ids=['in_process', 'processes'])
def test_params_file_faults_are_the_node_line_on_every_path(tmp_path, fault, processes):
    text, wanted = PARAMS_FAULTS[fault]
    f = tmp_path / 'p.yaml'
    f.write_text(f'controller:\n  ros__parameters:\n    {text}\n')
    argv = ['scenario', '--task', 'speed', '--duration', '0.02', '--no-progress',
            '--params-file', f, '--record', tmp_path / 'x.mcap']
    r = run_tool(*argv, *(['--processes'] if processes else []))
    assert r.returncode == 2, r.stderr
    line = one_line(r.stderr)
    assert "node 'controller'" in line and all(w in line for w in wanted), line
    # no run (the plant's 'starting:' line), no process started to wait out its startup timeout
    assert 'starting:' not in r.stderr and not (tmp_path / 'x_logs').exists()
    assert not (tmp_path / 'x.mcap').exists() and not partial_path(tmp_path / 'x.mcap').exists()
    # the node executable itself says the same thing about the same file
    from ament_index_python.packages import get_package_prefix
    ctl = os.path.join(get_package_prefix('im_controller'), 'lib', 'im_controller', 'controller')
    node = subprocess.run([ctl, '--ros-args', '--params-file', str(f)], capture_output=True,
                          text=True, timeout=60)
    assert node.returncode == 2
    assert one_line(node.stderr).split('error: ', 1)[1] == line.split('error: ', 1)[1]


@pytest.mark.processes
@pytest.mark.slow
def test_a_node_refusing_its_configuration_at_run_time_stops_the_graph_at_once(
        tmp_path, monkeypatch):
    """
    Check that a node's own configuration error ends every process.

    A configuration only the node's own process sees (here a parameter given to the controller on
    its command line) still ends every process at once, with the node's line.

    "At once" is counted in the runner's polls of the exit codes, not in seconds: the graph is
    stopped in the poll that first sees the refusal — not :data:`FAILURE_GRACE` later, not when the
    others give up waiting for the controller, not at the hang guard.
    """
    from im_bringup.processes import (failure_line, FAILURE_GRACE, graph_processes,
                                      GraphProcesses, REFUSED, run_processes)
    procs = graph_processes('speed', duration=0.02)
    for p in procs:
        if p.name == 'controller':
            p.parameters['k_1'] = 30.0
    polls, stopped_after = [], []       # the codes each poll saw; the polls before the stop
    returncodes, stop = GraphProcesses.returncodes, GraphProcesses.stop

    def poll(self):
        codes = returncodes(self)
        if not stopped_after:
            polls.append(codes)
        return codes

    def stopping(self, *args, **kwargs):
        stopped_after.append(len(polls))
        return stop(self, *args, **kwargs)
    monkeypatch.setattr(GraphProcesses, 'returncodes', poll)
    monkeypatch.setattr(GraphProcesses, 'stop', stopping)
    codes = run_processes(procs, str(tmp_path / 'logs'), timeout=120,   # a hang guard
                          env={'ROS_DOMAIN_ID': '177'})
    assert codes['controller'] == REFUSED, codes
    seen = next(i for i, c in enumerate(polls) if c['controller'] == REFUSED)
    assert stopped_after == [seen + 1], (
        f'the refusal was seen in poll {seen + 1} of {len(polls)}, the graph stopped '
        + (f'after poll {stopped_after[0]}' if stopped_after else 'never (each ended on its own)')
        + f": not at once (a {FAILURE_GRACE} s grace, the others' startup timeout, a hang)")
    assert all(c is not None for c in codes.values())
    failure = failure_line(str(tmp_path / 'logs'), codes)
    assert failure.startswith("controller: unknown parameter 'k_1'") and "'k1'" in failure


HUNG_TEARDOWN = """
import sys, time
from im_common import host, lockstep
from im_observer.observer_node import ObserverNode
host.EXIT_GRACE_S = 1.0


class Hung(ObserverNode):
    def destroy_node(self):
        print('tearing down', file=sys.stderr, flush=True)
        time.sleep(60)              # a middleware teardown that does not return


sys.exit(lockstep.node_main(Hung, ['observer']))
"""


@pytest.mark.processes
@pytest.mark.slow
def test_a_node_whose_teardown_hangs_exits_with_its_stacks_instead_of_hanging(tmp_path):
    """
    After its run a node's flush and teardown are bounded (``host.EXIT_GRACE_S``).

    A teardown that does not return (seen once: an observer whose run had finished did not exit
    in 120 s) ends the process with exit code 1 and every thread's stack on stderr, naming where
    it hung, instead of holding its launch (or a test) until something kills it.
    """
    from im_bringup.testing import wait_until
    script = tmp_path / 'hung.py'
    script.write_text(HUNG_TEARDOWN)
    log = tmp_path / 'hung.log'
    with open(log, 'w') as f:
        p = subprocess.Popen([sys.executable, str(script)], stderr=f, text=True)
    # up and waiting for a plant: its "waiting (2 s): no publisher yet of ..." line
    assert wait_until(lambda: 'waiting (' in log.read_text() or p.poll() is not None, 60) \
        and p.poll() is None, log.read_text()[-2000:]
    p.send_signal(signal.SIGINT)    # its run ends: flush, then the teardown that hangs
    # longer than the hung teardown's 60 s: without the exit guard the teardown returns and the
    # process exits 0 without stacks; with it, code 1 and the stacks, EXIT_GRACE_S after the run
    p.wait(timeout=120)
    err = log.read_text()
    assert p.returncode == 1, err[-2000:]
    assert 'tearing down' in err and 'destroy_node' in err and 'Timeout' in err, err[-2000:]


@pytest.mark.processes
@pytest.mark.slow
def test_a_process_that_did_not_end_is_asked_for_its_stacks_and_goes_on(tmp_path):
    """
    ``kill -USR1`` on a node process writes every thread's stack to its log; the node goes on.

    The harness's report of a graph that did not end (``assert_all_ended``) asks the processes
    still running for their stacks first, so a hang says where it is; the process is not harmed
    by being asked, and still stops cleanly on SIGINT.
    """
    from im_bringup.testing import random_domain
    from im_bringup.processes import GraphProcesses, graph_processes
    from im_bringup.testing import assert_all_ended, wait_for_log
    procs = [p for p in graph_processes('position', duration=0.02) if p.name == 'observer']
    with GraphProcesses(procs, str(tmp_path), {'ROS_DOMAIN_ID': str(random_domain())}
                        ) as g:
        g.start()
        assert wait_for_log(g, 'observer', 'waiting ('), g.log('observer')    # no plant: waits
        with pytest.raises(AssertionError) as err:
            assert_all_ended(g, g.returncodes())
        text = str(err.value)
        assert "{'observer': None}" in text and '--- observer: still running ---' in text
        assert 'most recent call first' in text and 'spin_until_done' in text, text[-2000:]
        assert g.popen['observer'].poll() is None           # asked, not ended
        assert g.stop() == {'observer': 0}, g.log('observer')[-2000:]


def test_the_teardown_yields_to_the_middleware_and_restores_the_scheduling():
    """
    Inside ``yielding_to_middleware`` every thread runs on one CPU and the caller at nice 19.

    That is what lets Fast DDS's starved discovery thread finish while the participant's teardown
    spins (docs/guarantees.md, "Ending is bounded"); on leaving, the caller's policy, nice value
    and every thread's CPUs are what they were.
    """
    import threading
    from im_common.host import YIELD_NICE, yielding_to_middleware
    me = threading.get_native_id()
    before = (os.sched_getaffinity(0), os.sched_getscheduler(0),
              os.getpriority(os.PRIO_PROCESS, me))
    stop = threading.Event()
    other = threading.Thread(target=stop.wait, daemon=True)
    other.start()
    try:
        with yielding_to_middleware() as refused:
            assert os.sched_getscheduler(0) == os.SCHED_OTHER
            assert os.getpriority(os.PRIO_PROCESS, me) == YIELD_NICE
            assert os.getpriority(os.PRIO_PROCESS, other.native_id) == before[2]
            assert len(os.sched_getaffinity(0)) == 1
            assert os.sched_getaffinity(other.native_id) == os.sched_getaffinity(0)
        assert (os.sched_getaffinity(0), os.sched_getscheduler(0),
                os.getpriority(os.PRIO_PROCESS, me)) == before
        assert os.sched_getaffinity(other.native_id) == before[0]
        assert refused == []
    finally:
        stop.set()
        other.join()


def test_a_refused_yield_is_reported_not_raised(monkeypatch):
    """
    Where the scheduler refuses (no policy change for this process), the teardown goes on.

    The refusal is in the context's list, one line naming the call and the error, which
    ``end_process`` logs; the threads' CPUs are still restored.
    """
    from im_common.host import yielding_to_middleware
    before = os.sched_getaffinity(0)

    def refuse(pid, policy, param):
        raise PermissionError(1, 'Operation not permitted')
    monkeypatch.setattr(os, 'sched_setscheduler', refuse)
    with yielding_to_middleware() as refused:
        assert len(os.sched_getaffinity(0)) == 1
    assert os.sched_getaffinity(0) == before
    assert refused == ['yielding to the middleware: [Errno 1] Operation not permitted',
                       'restoring the scheduling policy: [Errno 1] Operation not permitted']
