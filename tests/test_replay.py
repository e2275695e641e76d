"""Replay: re-estimation reproduces the recorded observer; publishing delivers the recording."""

from geometry_msgs.msg import Vector3Stamped
from im_bringup.testing import random_domain
from im_observer import observer
from im_recording.bag import iter_raw, read_messages
from im_recording.recorded_run import load_run
from im_recording.replay import main as replay_main, Player, reestimate
from im_recording.synth import make_synthetic_bag
import numpy as np
import pytest
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState


@pytest.fixture(scope='module')
def observed_bag(tmp_path_factory):
    d = tmp_path_factory.mktemp('obs')
    path = d / 'obs.mcap'
    obs = observer.RotorFluxObserver(max_substep=1e-4)
    make_synthetic_bag(path, steps=200, T_s=1e-3, observer=obs)
    return path


def test_reestimate_with_the_same_parameters_reproduces_the_recorded_estimates(observed_bag,
                                                                               tmp_path):
    out = tmp_path / 're.mcap'
    r = reestimate(observed_bag, out)
    assert r['steps'] == 200
    run = load_run(out)
    tr = run.trace
    ok = np.isfinite(tr['phi_hat_alpha'])
    assert ok.sum() == 200 and not ok[0]            # x̂_{k+1} stamped t_{k+1}
    for a, b in (('phi_reest_alpha', 'phi_hat_alpha'), ('phi_reest_beta', 'phi_hat_beta'),
                 ('i_reest_alpha', 'i_hat_alpha'), ('i_reest_beta', 'i_hat_beta')):
        np.testing.assert_array_equal(tr[a][ok], tr[b][ok])
    assert np.abs(tr['phi_hat_alpha'][ok]).max() > 0.1      # not trivially zero
    # every original message is kept
    orig = [(tp, t) for tp, _, t, _ in iter_raw(observed_bag)]
    new = [(tp, t) for tp, _, t, _ in iter_raw(out) if not tp.startswith('/im/reestimate')]
    assert orig == new
    assert run.metadata['reestimate']['source'] == str(observed_bag)

    # anti-test: a different rotor resistance gives different estimates
    out2 = tmp_path / 're2.mcap'
    assert replay_main([str(observed_bag), '--reestimate', '--out', str(out2),
                        '--param', 'R_r=1.2']) == 0
    tr2 = load_run(out2).trace
    assert np.abs(tr2['phi_reest_alpha'][ok] - tr2['phi_hat_alpha'][ok]).max() > 1e-3


def test_replay_cli_errors_are_one_line(tmp_path, capsys):
    bad = tmp_path / 'bad.mcap'
    bad.write_bytes(b'nope')
    assert replay_main([str(bad), '--reestimate']) == 2
    assert replay_main([str(bad)]) == 2
    err = capsys.readouterr().err
    assert err.count('\n') == 2 and 'bad.mcap' in err and 'Traceback' not in err


def test_player_lockstep_publishes_the_recording_with_clock_and_remap(observed_bag):
    ctx = Context()
    rclpy.init(context=ctx, domain_id=random_domain())
    got = {'cur': [], 'shaft': [], 'clock': []}
    node = sub = None
    try:
        node = Node('replay', context=ctx)
        topics = ['/im/measured/current', '/im/measured/shaft']
        player = Player(node, observed_bag, topics,
                        remap={'/im/measured/shaft': '/replayed/shaft'}, lockstep=True)
        sub = Node('listener', context=ctx)
        q = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
        sub.create_subscription(Vector3Stamped, '/im/measured/current',
                                lambda m: got['cur'].append(m), q)
        sub.create_subscription(JointState, '/replayed/shaft', lambda m: got['shaft'].append(m), q)
        sub.create_subscription(Clock, '/clock', lambda m: got['clock'].append(m), 100)
        ex = SingleThreadedExecutor(context=ctx)
        ex.add_node(sub)
        ex.add_node(node)
        from im_bringup.testing import wait_until     # events, each with a 60 s hang guard
        assert player.wait_for_subscribers(timeout=60, spin=lambda: ex.spin_once(
            timeout_sec=0.01)), 'hang: the listener never matched the player in 60 s'
        assert wait_until(lambda: ex.spin_once(timeout_sec=0.01)
                          or player.clock_pub.get_subscription_count(), 60, 0.0), \
            'hang: the listener never matched /clock in 60 s'
        n = player.play(spin=lambda: ex.spin_once(timeout_sec=0.0))
        assert wait_until(lambda: ex.spin_once(timeout_sec=0.02)
                          or len(got['cur']) + len(got['shaft']) >= n, 60, 0.0), \
            f"hang: {len(got['cur']) + len(got['shaft'])} of {n} messages arrived in 60 s"
    finally:
        for nd in (node, sub):
            if nd is not None:
                nd.destroy_node()
        rclpy.shutdown(context=ctx)
    rec_cur = [m for tp, _, m in read_messages(observed_bag, ['/im/measured/current'])]
    rec_sh = [m for tp, _, m in read_messages(observed_bag, ['/im/measured/shaft'])]
    assert n == len(rec_cur) + len(rec_sh)
    assert got['cur'] == rec_cur
    assert got['shaft'] == rec_sh
    stamps = [c.clock.sec * 10**9 + c.clock.nanosec for c in got['clock']]
    assert stamps == sorted(stamps) and len(stamps) >= len(rec_cur) // 2
