import random

import pytest

pytest_plugins = ['im_bringup.testing']

#: DDS domains the in-process tests draw from (shared machine: keep clear of the default 0)
TEST_DOMAINS = (150, 229)


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

    The domain is in 150-229; the context is shut down afterwards.

    Every in-process ROS test takes its context from here instead of calling ``rclpy.init``
    itself, so no test shares the global context or a domain with another run on the machine.
    """
    import rclpy
    from rclpy.context import Context
    ctx = Context()
    rclpy.init(context=ctx, domain_id=random.randint(*TEST_DOMAINS))
    try:
        yield ctx
    finally:
        rclpy.try_shutdown(context=ctx)


@pytest.fixture(scope='session')
def free_run_rate(tmp_path_factory):
    """
    Return the free_run rate [Hz] this machine holds beside a busy process, as the plant says.

    The graph's processes (as the launch file starts them) at 1 kHz with a CPU-bound process
    beside them: the plant's pre-flight probe either starts the run (1 kHz holds; 50 steps) or
    refuses it, naming the rate it holds. None when it holds none of them: a free_run test then
    checks that refusal instead. The free_run tests run at this rate, so a machine slower than
    1 kHz makes them slower, not red (the guard itself: tests/test_free_run_guard.py).
    """
    import re
    import subprocess
    import sys
    from im_bringup.processes import free_run_gains, graph_processes, GraphProcesses, \
        load_params_yaml
    procs = graph_processes('position', 'min_energy', T_s=1e-3, duration=0.05, mode='free_run',
                            extra=load_params_yaml(free_run_gains(1e-3)))
    busy = subprocess.Popen([sys.executable, '-c', 'while True: pass'])
    try:
        env = {'ROS_DOMAIN_ID': str(random.randint(*TEST_DOMAINS))}
        with GraphProcesses(procs, str(tmp_path_factory.mktemp('probe')), env) as g:
            codes = g.start().wait(120)
            log = g.log('plant')
    finally:
        busy.kill()
    if codes['plant'] == 0 and 'holds it' in log:
        return 1000
    m = re.search(r'cannot hold it; this machine holds (none|\d+)', log)
    assert m, log[-3000:]
    return None if m.group(1) == 'none' else int(m.group(1))
