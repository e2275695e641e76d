import importlib
import os

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def source_packages():
    """Return ``{name: directory}`` of every Python package under src/ (src/PKG/PKG)."""
    src = os.path.join(ROOT, 'src')
    return {name: os.path.join(src, name, name) for name in sorted(os.listdir(src))
            if os.path.isfile(os.path.join(src, name, name, '__init__.py'))}


def not_from_source(modules):
    """
    Return one line per module of ``modules`` ({name: module}) not imported from src/.

    A package imported from anywhere else (install/ after ``colcon build``) is a copy of the
    source as it was at the last build: the suite would test that instead of the edit.
    """
    packages = source_packages()
    out = []
    for name, module in modules.items():
        top = name.split('.')[0]
        if top not in packages:
            continue
        where = os.path.realpath(getattr(module, '__file__', None) or '?')
        home = os.path.realpath(packages[top]) + os.sep
        if not where.startswith(home):
            out.append(f'{name} is imported from {where}, not from {home} (pytest.ini pythonpath)')
    return out


# Every package of src/ is imported here, before any test module: from then on each one's
# submodules come from the same directory, and a package that pytest.ini leaves off the path
# fails the session at once instead of testing install/'s stale copy.
_STALE = not_from_source({n: importlib.import_module(n) for n in source_packages()})
if _STALE:
    raise pytest.UsageError('the suite must test the source tree:\n' + '\n'.join(_STALE))

pytest_plugins = ['im_bringup.testing']

# Property-based fuzzing (tests/test_fuzz_*.py): one set of hypothesis profiles for every reader.
# 'ci' (the default, `make test`): a few hundred seeded cases a property, the same ones every run;
# 'fuzz' (`make fuzz`, HYPOTHESIS_PROFILE=fuzz): at least 1,000 fresh cases a property. No
# deadline (a loaded 2-core machine is slow, not wrong); no example database (nothing written
# into the tree: a failure prints its reproduction blob and the shrunk input instead).
from hypothesis import HealthCheck, settings as hypothesis_settings  # noqa: E402, I100

_FUZZ_COMMON = {'deadline': None, 'database': None, 'print_blob': True,
                'suppress_health_check': [HealthCheck.too_slow, HealthCheck.data_too_large,
                                          HealthCheck.filter_too_much]}
hypothesis_settings.register_profile('ci', max_examples=200, derandomize=True, **_FUZZ_COMMON)
hypothesis_settings.register_profile('fuzz', max_examples=1000, **_FUZZ_COMMON)
hypothesis_settings.load_profile(os.environ.get('HYPOTHESIS_PROFILE', 'ci'))


@pytest.fixture(autouse=True)
def ros_domain_id(monkeypatch):
    """
    Run each test on a random ROS domain of its own (``ROS_DOMAIN_ID``), returned as an int.

    Every tool runs on ``ROS_DOMAIN_ID`` as ROS 2 does (the in-process graph, the executables
    a test starts, their processes): here, not in the tools, tests are kept apart from each
    other and from the user's own graph on the shared machine.
    """
    from im_bringup.testing import random_domain
    domain = random_domain()
    monkeypatch.setenv('ROS_DOMAIN_ID', str(domain))
    return domain


@pytest.fixture(scope='session', autouse=True)
def graph_key_file(tmp_path_factory):
    """
    Share one key file among the nodes built without a key of their own.

    Nodes built without a key of their own (``ros2 run`` style) share this session's key file
    instead of the user's ``~/.ros/im_drive/graph.key``.
    """
    import os
    from im_common import auth
    path = str(tmp_path_factory.mktemp('key') / 'graph.key')
    old = os.environ.get(auth.KEY_ENV)
    os.environ[auth.KEY_ENV] = path
    yield path
    if old is None:
        os.environ.pop(auth.KEY_ENV, None)
    else:
        os.environ[auth.KEY_ENV] = old


@pytest.fixture
def ros_context():
    """
    Return an initialized rclpy ``Context`` on a random DDS domain.

    The domain is one of im_bringup.testing's; the context is shut down afterwards.

    Every in-process ROS test takes its context from here instead of calling ``rclpy.init``
    itself, so no test shares the global context or a domain with another run on the machine.
    """
    import rclpy
    from rclpy.context import Context
    from im_bringup.testing import random_domain
    ctx = Context()
    rclpy.init(context=ctx, domain_id=random_domain())
    try:
        yield ctx
    finally:
        rclpy.try_shutdown(context=ctx)


@pytest.fixture(scope='session')
def free_run_rate(tmp_path_factory):
    """
    Return the free_run rate [Hz] this machine holds beside a busy process, as the plant says.

    The graph's processes (as the launch file starts them) with a CPU-bound process beside them,
    at 1 kHz, then 500 Hz, then 250 Hz (each with its certified gains): the first rate whose
    pre-flight probe lets the run start (50 steps). The free_run tests run at it, so a machine
    slower than 1 kHz makes them slower, not red (the guard itself:
    tests/test_free_run_guard.py). None when even 250 Hz is refused: the tests then check that
    refusal (:data:`FREE_RUN_REFUSAL`, the plant's line) instead.
    """
    import subprocess
    import sys
    from im_bringup.processes import free_run_gains, graph_processes, GraphProcesses, \
        load_params_yaml
    from im_bringup.testing import random_domain
    log = ''
    for rate in FREE_RUN_RATES:
        gains = load_params_yaml(free_run_gains(1.0 / rate))
        procs = graph_processes('position', 'min_energy', T_s=1.0 / rate, duration=50.0 / rate,
                                mode='free_run', extra=gains)
        busy = subprocess.Popen([sys.executable, '-c', 'while True: pass'])
        try:
            env = {'ROS_DOMAIN_ID': str(random_domain())}
            with GraphProcesses(procs, str(tmp_path_factory.mktemp('probe')), env) as g:
                codes = g.start().wait(120)
                log = g.log('plant')
        finally:
            busy.kill()
        if 'holds it' in log and 'starting:' in log:
            return rate
        assert codes['plant'] == 1 and 'cannot hold it' in log, log[-3000:]
    FREE_RUN_REFUSAL.append(log)
    return None


#: The free_run rates [Hz] the suite tries, fastest first.
FREE_RUN_RATES = (1000, 500, 250)

#: The plant's log of the refused 250 Hz run when :func:`free_run_rate` is None.
FREE_RUN_REFUSAL: list = []


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    """
    Say that a command the suite gave up waiting for hung: its ``timeout=`` is a hang guard.

    Every ``timeout=`` of a ``subprocess`` call in the suite bounds a command that ends on its own
    (a run to its duration, a refusal, a stop after a signal) and is many times what the command
    takes on a loaded 2-core machine: no test asserts how fast it was. One that fires is reported
    as a hang, with the command and its guard, instead of as a bare ``TimeoutExpired``.
    """
    import subprocess
    outcome = yield
    if call.excinfo is not None and call.excinfo.errisinstance(subprocess.TimeoutExpired):
        exc = call.excinfo.value
        cmd = exc.cmd if isinstance(exc.cmd, str) else ' '.join(map(str, exc.cmd))
        outcome.get_result().sections.append((
            'hang guard', f'HANG: {cmd[:300]} did not end within its hang guard of {exc.timeout:g}'
            ' s, many times what it takes on a loaded machine: a hang, not slowness'))


@pytest.fixture(scope='module')
def context():
    """Yield an rclpy context of its own (a random test domain) for a module's nodes."""
    import rclpy
    from rclpy.context import Context
    from im_bringup.testing import random_domain
    ctx = Context()
    rclpy.init(context=ctx, domain_id=random_domain())
    yield ctx
    rclpy.try_shutdown(context=ctx)
