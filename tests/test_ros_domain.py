"""
The ROS domain, as every ROS 2 tool chooses it: ``--domain-id`` wins, else ``ROS_DOMAIN_ID``.

A user who runs ``scenario`` in a shell with ``ROS_DOMAIN_ID=N`` sees its topics with ``ros2
topic list`` on N (here: a node of the test's own on N lists them). Each test runs on a random
domain (``ros_domain_id``, tests/conftest.py): keeping tests apart is the fixture's job.
"""
import os
import random
import signal
import subprocess
import time

from im_bringup.processes import executable_path
from im_common import topics as T
import pytest


def _topics_seen_on(domain: int, proc: subprocess.Popen, *want: str, limit_s: float = 120.0):
    """
    Return the topics a node on ``domain`` lists once all of ``want`` are among them.

    Or once ``proc`` ended, or after ``limit_s``. Discovery is incremental: one topic of the
    graph may be listed a moment before another (a run failed once asserting the command
    topic right after the current had appeared).
    """
    import rclpy
    from rclpy.context import Context
    ctx = Context()
    rclpy.init(context=ctx, domain_id=domain)
    try:
        node = rclpy.create_node('domain_probe', context=ctx)
        t0 = time.monotonic()
        names = set()
        while time.monotonic() - t0 < limit_s and proc.poll() is None:
            names = {n for n, _ in node.get_topic_names_and_types()}
            if names.issuperset(want):
                break
            time.sleep(0.2)
        node.destroy_node()
        return names
    finally:
        rclpy.try_shutdown(context=ctx)


@pytest.mark.processes
@pytest.mark.slow
@pytest.mark.parametrize('processes', [False, True], ids=['in_process', 'processes'])
def test_scenario_runs_on_ros_domain_id_and_an_explicit_domain_id_wins(tmp_path, ros_domain_id,
                                                                       processes):
    """
    ``ROS_DOMAIN_ID=N scenario``: its topics are on N.

    With ``--domain-id M`` (the ``--processes`` case): on M, not on N.
    """
    bag = str(tmp_path / 'run.mcap')
    argv = [executable_path('im_bringup', 'scenario'), '--task', 'speed', '--duration', '20',
            '--record', bag, '--no-progress']
    domain = ros_domain_id
    if processes:
        domain = random.choice([d for d in range(150, 230) if d != ros_domain_id])
        argv += ['--processes', '--domain-id', str(domain)]
    assert os.environ['ROS_DOMAIN_ID'] == str(ros_domain_id)
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        seen = _topics_seen_on(domain, proc, T.MEAS_CURRENT, T.CMD_VOLTAGE)
        assert T.MEAS_CURRENT in seen and T.CMD_VOLTAGE in seen, (seen, proc.poll())
        if processes:       # nothing of the run on the environment's domain
            elsewhere = _topics_seen_on(ros_domain_id, proc, T.MEAS_CURRENT, limit_s=3.0)
            assert T.MEAS_CURRENT not in elsewhere
    finally:
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=120)
    assert proc.returncode == 128 + signal.SIGINT or proc.returncode == 0, err[-2000:]


def test_the_in_process_graph_takes_ros_domain_id_unless_told(ros_domain_id):
    from im_bringup.config import node_parameters
    from im_bringup.graph import DriveGraph
    params = node_parameters('position', 'min_energy', 'nominal', 'none', 1e-4, 0.01)
    with DriveGraph(params, nodes=('plant',)) as g:
        assert g.domain_id == g.context.get_domain_id() == ros_domain_id
    other = 150 + (ros_domain_id - 150 + 1) % 80
    with DriveGraph(params, nodes=('plant',), domain_id=other) as g:
        assert g.domain_id == g.context.get_domain_id() == other


@pytest.mark.parametrize('env, option, line', [
    ('abc', [], "scenario: error: ROS_DOMAIN_ID='abc': not a ROS domain (an integer 0-232)"),
    ('7', ['--domain-id', '300'],
     'scenario: error: --domain-id 300: not a ROS domain (an integer 0-232)'),
])
def test_a_domain_the_middleware_cannot_open_is_one_line(tmp_path, monkeypatch, capsys, env,
                                                         option, line):
    from im_bringup.scenario import main
    monkeypatch.setenv('ROS_DOMAIN_ID', env)
    out = tmp_path / 's.json'
    assert main(['--duration', '0.01', '--summary', str(out), '--no-progress'] + option) == 2
    assert capsys.readouterr().err.strip() == line and not out.exists()
