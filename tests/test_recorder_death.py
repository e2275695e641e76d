"""
The recorder dies during a run of processes: the run goes on to its end, unrecorded, and says so.

docs/guarantees.md ("Off the critical path, never fatal"): the recorder is off the critical path.
A recorder killed outright (SIGKILL) during ``scenario --processes --record`` — the processes the
launch file starts, by the same supervisor policy (:func:`im_bringup.processes.ends_graph`) —
leaves the run going: the plant stops waiting for its acknowledgements after its
``input_timeout``, every drive node ends with exit code 0 at the run's end, one line says that the
run goes on unrecorded, ``scenario`` exits 1 naming the ``.part`` and ``recover`` salvages every
step the recorder had on disk when it was killed.
"""
import json
import os
import shutil
import signal
import subprocess

from im_bringup.processes import ends_graph, exit_text, lost_line
from im_bringup.testing import wait_until
from im_common import topics as T
from im_recording.bag import BagError, iter_raw
from im_recording.recover import recover
import pytest

#: A hang guard, not a speed target: the run and its ends take well under a minute.
HANG_GUARD_S = 600.0
PERIOD_NS = 100_000


def test_only_a_refusal_of_a_process_off_the_critical_path_ends_the_graph():
    assert not ends_graph('recorder', -signal.SIGKILL)
    assert not ends_graph('live', 1)
    assert ends_graph('recorder', 2)            # a refused --out: nothing ran yet
    assert ends_graph('controller', -signal.SIGKILL)
    assert not ends_graph('plant', 0)
    assert exit_text(-9) == 'killed by SIGKILL (exit code -9)'
    line = lost_line('recorder', -9, ['--out', 'bags/a.mcap', '--log-time', 'wall'])
    assert 'UNRECORDED' in line and 'bags/a.mcap.part' in line and '\n' not in line


def _launch_file(monkeypatch):
    """
    Load ``launch/drive.launch.py`` with stand-ins for ``launch``/``launch_ros``.

    Those are not on PyPI (a full ROS 2 install brings them); each action stand-in keeps its
    keyword arguments.
    """
    import importlib.util
    import sys
    import types

    class Action:

        def __init__(self, *args, **kw):
            self.args, self.kw = args, kw
    names = {'launch': ['LaunchDescription'],
             'launch.actions': ['DeclareLaunchArgument', 'EmitEvent', 'LogInfo',
                                'OpaqueFunction', 'RegisterEventHandler',
                                'SetEnvironmentVariable'],
             'launch.event_handlers': ['OnProcessExit'], 'launch.events': ['Shutdown'],
             'launch.substitutions': ['EnvironmentVariable', 'LaunchConfiguration'],
             'launch_ros': [], 'launch_ros.actions': ['Node']}
    for module, classes in names.items():
        m = types.ModuleType(module)
        for c in classes:
            setattr(m, c, Action)
        monkeypatch.setitem(sys.modules, module, m)
    path = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), 'src',
                        'im_bringup', 'launch', 'drive.launch.py')
    spec = importlib.util.spec_from_file_location('drive_launch', path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_ros2_launch_follows_the_same_policy(monkeypatch):
    """The launch file's exit handler: a dead recorder is one line, a dead controller the end."""
    from types import SimpleNamespace
    launch = _launch_file(monkeypatch)

    def exited(process, code, cmd=()):
        return launch._stop_on_failure(SimpleNamespace(
            returncode=code, process_name=process, cmd=list(cmd), action=None), None)
    said = exited('record-5', -9, ['/lib/record', '--out', 'bags/a.mcap'])
    assert type(said[0]).__name__ == 'Action' and 'msg' in said[0].kw, said
    assert said[0].kw['msg'] == lost_line('recorder', -9, ['--out', 'bags/a.mcap'])
    assert 'event' in exited('record-5', 2)[0].kw           # a refusal ends the launch
    assert 'event' in exited('controller-2', -9)[0].kw
    assert exited('plant-1', 0) is None


def _exe(package, name):
    from im_bringup.processes import executable_path
    return executable_path(package, name)


def _children(pid):
    """Return {pid: command line} of the processes whose parent is ``pid``."""
    out = {}
    for p in os.listdir('/proc'):
        if not p.isdigit():
            continue
        try:
            with open(f'/proc/{p}/stat') as f:
                ppid = int(f.read().rsplit(')', 1)[1].split()[1])
            if ppid == pid:
                with open(f'/proc/{p}/cmdline', 'rb') as f:
                    out[int(p)] = f.read().replace(b'\0', b' ').decode()
        except (OSError, ValueError, IndexError):
            continue
    return out


def _steps(bag):
    """Return the sorted steps of the measured current in ``bag``."""
    return sorted(stamp // PERIOD_NS for _, _, stamp, _ in iter_raw(bag, [T.MEAS_CURRENT]))


def _steps_on_disk(part, snapshot):
    """
    Copy the writing recorder's ``part`` to ``snapshot``; return the steps recover finds in it.

    What the test kills the recorder after: a flushed chunk holding measured currents, not a
    byte count (on a loaded machine the first chunks can hold only the start-up's records).
    """
    shutil.copyfile(part, snapshot)
    out = snapshot.with_suffix('.probe')
    try:
        recover(snapshot, str(out), force=True)
        return _steps(out)
    except BagError:                    # no intact chunk yet, or none with a measured current
        return []


@pytest.mark.processes
@pytest.mark.slow
def test_killed_recorder_the_run_goes_on_unrecorded_and_its_part_is_recoverable(tmp_path):
    bag = tmp_path / 'run.mcap'
    part = tmp_path / 'run.mcap.part'
    logs = tmp_path / 'run_logs'
    proc = subprocess.Popen(
        [_exe('im_bringup', 'scenario'), '--task', 'speed', '--duration', '3.0', '--processes',
         '--record', str(bag), '--no-progress', '--domain-id', os.environ['ROS_DOMAIN_ID']],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tmp_path)
    try:
        # mid-run: the plant started and the recorder put a chunk of its steps on disk (the
        # file's head, written before step 0, holds the run's metadata)
        assert wait_until(lambda: 'starting:' in _read(logs / 'plant.log') and part.exists(),
                          timeout=HANG_GUARD_S), _read(logs / 'plant.log')
        probe = tmp_path / 'probe.mcap.part'
        assert wait_until(lambda: _steps_on_disk(part, probe), timeout=HANG_GUARD_S), \
            _read(logs / 'recorder.log')
        recorder = [pid for pid, cmd in _children(proc.pid).items()
                    if '/lib/im_recording/record ' in cmd]
        assert len(recorder) == 1, _children(proc.pid)
        snapshot = tmp_path / 'at_kill.mcap.part'
        shutil.copyfile(part, snapshot)         # what was on disk before the kill
        os.kill(recorder[0], signal.SIGKILL)
        out, err = proc.communicate(timeout=HANG_GUARD_S)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 1, (out, err)
    assert 'Traceback' not in out + err, err
    # one line during the run, one error line at the end, both naming the recorder's death
    lost = [ln for ln in err.splitlines() if 'the run goes on UNRECORDED' in ln]
    assert len(lost) == 1, err
    assert lost[0].startswith('recorder killed by SIGKILL (exit code -9)'), lost
    assert str(part) in lost[0]
    error = [ln for ln in err.splitlines() if ln.startswith('scenario: error: ')]
    assert len(error) == 1, err
    assert error[0].startswith('scenario: error: the run went on to its end without it: '
                               'recorder: killed by SIGKILL (exit code -9)'), error
    assert f'`ros2 run im_recording recover {part}`' in error[0], error
    summary = json.loads((tmp_path / 'run.json').read_text())
    assert summary['processes'] == {'recorder': -9, 'controller': 0, 'observer': 0,
                                    'plant': 0}, summary
    assert summary['partial'] is True
    plant_log = _read(logs / 'plant.log')
    assert "follower 'recorder' acknowledged nothing" in plant_log, plant_log
    assert 'continuing without it' in plant_log
    assert 'run stopped' not in plant_log, plant_log      # not stopped: it ran to its end
    assert not bag.exists()
    # everything already written is kept: recover salvages at least what was on disk at the kill
    saved, before = tmp_path / 'saved.mcap', tmp_path / 'before.mcap'
    for src, dst in ((part, saved), (snapshot, before)):
        r = subprocess.run([_exe('im_recording', 'recover'), str(src), '-o', str(dst)],
                           capture_output=True, text=True, timeout=HANG_GUARD_S)
        # 1: written, and the run's tail after the kill named as lost (no damaged chunk)
        assert r.returncode == 1 and dst.exists(), r.stderr
        assert 'the writer did not close the file' in r.stderr and 'damaged' not in r.stderr
    steps, steps_before = _steps(saved), _steps(before)
    assert steps_before and steps[:len(steps_before)] == steps_before
    assert steps == list(range(steps[-1] + 1)), 'a gap inside what the recorder wrote'
    assert steps[-1] < 30_000, 'the recorder could not have recorded the whole run'


def _read(path) -> str:
    try:
        return path.read_text()
    except OSError:
        return ''
