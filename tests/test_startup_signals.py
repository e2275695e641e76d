"""
A stop signal during any executable's start-up acts: the process ends on its own, cleanly.

Every console script of ``setup.py`` starts through :func:`im_common.startup.entry`, which takes
SIGINT/SIGTERM as a flag before the heavy imports (rclpy, numpy, the middleware) and exits with
one line and the shell's code once they are done — before it starts anything — or, past the
imports, lets the program's own handling act (a node stops cleanly, exit 0). Before, a SIGINT
there was a traceback, or lost in a process that inherited it ignored (a recorder then waited ten
minutes for a plant long finished).

Each executable is signalled as soon as its handlers are in place (``/proc/PID/status`` lists the
signal as caught: the script's first lines, well before its imports end) and once more 0.2 s later,
during its imports; it must then end on its own with no traceback and 0, 130 or 143 (129 for
SIGHUP: docs/guarantees.md). No wall-clock assertion: the wait is a hang guard only.
"""
import os
import signal
import subprocess
import time

from im_bringup.processes import executable_path
from im_bringup.testing import wait_until
import pytest

#: A hang guard, not a speed target: an executable that lost the signal runs on (a recorder
#: waits for a plant forever, a plant for its nodes 30 s, then fails with exit code 1).
HANG_GUARD_S = 180.0

#: Every executable of the stack (setup.py's console scripts) with arguments of a real run.
EXECUTABLES = {
    'plant': ('im_plant', []),
    'observer': ('im_observer', []),
    'controller': ('im_controller', []),
    'adapter': ('im_adapt', []),
    'design_gains': ('im_controller', ['--out', '{tmp}/gains.yaml']),
    'record': ('im_recording', ['--out', '{tmp}/rec.mcap']),
    'replay': ('im_recording', ['{tmp}/none.mcap']),
    'recover': ('im_recording', ['{tmp}/none.mcap.part']),
    'report': ('im_recording', ['{tmp}/none.mcap', '--out', '{tmp}/report']),
    'scenario': ('im_bringup', ['--task', 'speed', '--duration', '1.0', '--record',
                                '{tmp}/sc.mcap']),
    'commission': ('im_bringup', ['--out', '{tmp}/motor.yaml']),
    'live': ('im_bringup', ['--port', '0']),
    'campaign': ('im_studies', ['--help']),
    'efficiency_map': ('im_studies', ['--help']),
    'robust_study': ('im_studies', ['--out', '{tmp}/robust_study']),
    'robust_examples': ('im_robust', ['examples', '--out', '{tmp}/robust']),
}


def test_every_console_script_is_tested_here():
    import re
    root = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), 'src')
    scripts = {}
    for pkg in os.listdir(root):
        setup = os.path.join(root, pkg, 'setup.py')
        if os.path.isfile(setup):
            with open(setup) as f:
                for name, target in re.findall(r"'(\w+) = ([\w.]+:\w+)'", f.read()):
                    scripts[name] = (pkg, target)
    assert set(scripts) == set(EXECUTABLES), sorted(set(scripts) ^ set(EXECUTABLES))
    for name, (pkg, target) in scripts.items():
        assert EXECUTABLES[name][0] == pkg
        assert target == f'{pkg}.entry:{name}', f'{name}: not started by im_common.startup'


def _caught(pid: int, sig: int) -> bool:
    """Tell whether process ``pid`` has a handler for ``sig`` (``SigCgt`` of its status)."""
    try:
        with open(f'/proc/{pid}/status') as f:
            for line in f:
                if line.startswith('SigCgt:'):
                    return bool(int(line.split()[1], 16) >> (sig - 1) & 1)
    except OSError:
        pass
    return False


@pytest.mark.processes
@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM], ids=['SIGINT', 'SIGTERM'])
@pytest.mark.parametrize('name', sorted(EXECUTABLES))
def test_a_signal_during_start_up_ends_the_executable_cleanly(tmp_path, name, sig):
    pkg, args = EXECUTABLES[name]
    cmd = [executable_path(pkg, name)] + [a.format(tmp=tmp_path) for a in args]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            cwd=tmp_path, start_new_session=True)
    try:
        # its handlers are in (SIGHUP is caught by them alone: Python's own catch SIGINT only)
        assert wait_until(lambda: _caught(proc.pid, signal.SIGHUP) or proc.poll() is not None,
                          timeout=HANG_GUARD_S, interval=0.001)
        proc.send_signal(sig)
        time.sleep(0.2)
        if proc.poll() is None:
            proc.send_signal(sig)       # once more, during its start-up
        out, err = proc.communicate(timeout=HANG_GUARD_S)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert 'Traceback' not in out + err, err
    code = proc.returncode
    assert code in (0, 128 + sig), (code, err)
    if code:
        lines = [ln for ln in err.splitlines() if ln.startswith(f'{name}: ')]
        assert lines == [f'{name}: {sig.name} during start-up: exiting'] or any(
            f'stopped by {sig.name}' in ln or 'interrupted' in ln for ln in lines), err
