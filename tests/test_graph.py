"""
The four-node graph in lock-step.

Deterministic, identical to the ROS-free loop, and it stops cleanly with a clear report when a node
is missing.
"""
import math

from im_bringup.testing import assert_samples_match, run_graph
import numpy as np
import pytest


def test_same_run_twice_gives_identical_numbers():
    a = run_graph(task='speed', strategy='min_energy', duration=0.05)
    b = run_graph(task='speed', strategy='min_energy', duration=0.05)
    assert a.summary['ok'] and b.summary['ok']
    assert a.summary['steps'] == b.summary['steps'] == 500
    for key in ('E_in_J', 'E_copper_J', 'speed_err_max_rad_s', 'V_max_V'):
        assert a.summary[key] == b.summary[key], key
    for key in ('omega_r', 'v_alpha', 'phi_hat_alpha', 'E_in'):
        np.testing.assert_array_equal(a.trace[key], b.trace[key])


@pytest.mark.parametrize('task,strategy,controller,variation', [
    ('position', 'min_energy', 'nominal', 'none'),
    ('speed', 'min_loss', 'nominal', 'none'),
    ('speed', 'min_energy', 'adaptive_thesis_pair', 'chapter4'),
    ('position', 'min_loss', 'adaptive', 'chapter4'),   # L_sigma on the topic
])
def test_graph_equals_the_ros_free_loop(task, strategy, controller, variation):
    """
    Stamps, not arrival order, decide what each node computes.

    The graph reproduces the offline loop (same classes, same step order, same initial state).
    """
    from im_bringup.offline import Scenario, simulate
    from im_common.params import CHAPTER4_ESTIMATES, THESIS_MOTOR
    g = run_graph(task=task, strategy=strategy, controller=controller, variation=variation,
                  duration=0.05)
    hook = None
    if controller != 'nominal':
        from im_adapt.adaptation import AdaptationGains
        from im_adapt.hook import LockstepAdapter
        from im_bringup.config import ADAPTATION
        est = CHAPTER4_ESTIMATES if variation == 'chapter4' else THESIS_MOTOR
        hook = LockstepAdapter.build(est, AdaptationGains(**ADAPTATION[controller]))
    off = simulate(Scenario(task=task, strategy=strategy, variation=variation, duration=0.05),
                   adapter=hook)
    assert g.summary['ok'], g.summary['failures']
    for key in ('E_in_J', 'E_copper_J', 'dW_magnetic_J'):
        assert g.summary[key] == pytest.approx(off.summary[key], rel=1e-9, abs=1e-12), key
    # the graph's samples at t_k equal the offline per-step trace at the same instants
    assert_samples_match(g.trace, off.trace, ('omega_r', 'theta_r', 'phi_hat_alpha'), 500)


def test_missing_observer_is_reported_and_the_run_stops():
    res = run_graph(task='position', duration=0.1, nodes=('plant', 'controller', 'adapter'),
                    input_timeout=0.3,
                    parameters={n: {'startup_timeout': 0.5}
                                for n in ('plant', 'controller', 'adapter')})
    assert not res.summary['ok']
    msg = res.summary['failures']['plant']        # the time master says who is missing
    assert 'not started' in msg and 'observer (not seen' in msg
    assert 'controller (waiting for a publisher of /im/observer/flux)' in msg


@pytest.mark.slow
@pytest.mark.parametrize('strategy', ['min_energy', 'constant_flux', 'min_loss'])
def test_each_strategy_tracks_through_the_graph(drive_graph, strategy):
    res = drive_graph(task='position', strategy=strategy, duration=0.6)
    s = res.summary
    assert s['ok'], s['failures']
    # the reference starts moving at 0.4 s; the pendulum must be held and then followed
    assert s['pos_err_max_rad'] < 0.01
    assert abs(s['balance_residual_J']) < 1e-6 * s['E_in_J']
    assert math.isfinite(s['E_loss_J']) and s['E_loss_J'] > 0


def test_a_diverging_run_stops_cleanly_and_says_where():
    """
    The thesis's current gain (40 V/A) is unstable at T_s = 1 ms.

    The graph must stop with the plant's report (time of the non-finite state), not hang or
    raise out of the executor.
    """
    res = run_graph(task='position', strategy='min_energy', T_s=1e-3, duration=0.1)
    assert not res.summary['ok']
    assert 'protection trip' in res.summary['failures']['plant']
    assert 'above the inverter rating' in res.summary['failures']['plant']
    assert res.summary['steps'] < 100


def test_adapter_enable_switches_at_run_time():
    """
    `ros2 param set /adapter enable true`.

    Validated in the callback, applied at the next step (not inside the callback), announced on
    /im/status; a non-boolean is refused.
    """
    from im_bringup.testing import random_domain

    import rclpy
    from rclpy.context import Context
    from rclpy.parameter import Parameter

    from im_adapt.adapter_node import AdapterNode
    from im_common import topics as T
    ctx = Context()
    rclpy.init(context=ctx, domain_id=random_domain())
    try:
        node = AdapterNode(context=ctx)
        said = []
        node.status = lambda state, *a, **kw: said.append((state, kw))
        assert node.enable is False
        assert not node.set_parameters([Parameter('enable', value=3)])[0].successful
        assert node.set_parameters([Parameter('enable', value=True)])[0].successful
        assert node.enable is False                       # not applied inside the callback
        for topic, value in ((T.MEAS_CURRENT, (1.0, 0.0)), (T.CMD_VOLTAGE, (10.0, 0.0)),
                             (T.OBS_FLUX, (0.1, 0.0)), (T.MEAS_SHAFT, (0.0, 0.0))):
            node.ready(node.gate.put(topic, 0, value))
        assert node.enable is True and node.gate.expected == node.period
        assert ('parameters', {'enable': True}) in said
        node.destroy_node()
    finally:
        rclpy.shutdown(context=ctx)


def test_speed_setpoint_from_the_topic_is_reached_smoothly():
    """
    Check the 'setpoint' profile.

    A JointState on /im/setpoint (velocity) becomes a smooth reference that the drive follows;
    the plant ends at the new speed.
    """
    import rclpy.node
    from sensor_msgs.msg import JointState

    from im_bringup.config import node_parameters
    from im_bringup.graph import DriveGraph
    from im_common import topics as T
    from im_common.conversions import set_stamp
    params = node_parameters('speed', 'min_loss', duration=0.8)
    params['controller']['profile'] = 'setpoint'
    graph = DriveGraph(params)
    try:
        user = rclpy.node.Node('user', context=graph.context)
        pub = user.create_publisher(JointState, T.SETPOINT, 10)   # what `ros2 topic pub` uses
        sp = JointState()
        set_stamp(sp.header.stamp, 100_000_000)          # from t = 0.1 s
        sp.velocity = [150.0]
        pub.publish(sp)
        graph.executor.add_node(user)
        stats = graph.run()
        omega = graph.plant.sim.x[5]
        user.destroy_node()
    finally:
        graph.close()
    assert stats['ok'], stats['failures']
    assert omega == pytest.approx(150.0, abs=0.05)


def test_scenario_recording_carries_run_metadata_and_matches_its_summary(tmp_path):
    from im_recording.bag import info
    from im_recording.recorded_run import load_run
    from im_bringup.run_file import Scenario
    from im_recording.report import figures_of_merit
    from im_bringup.scenario import run_scenario
    path = str(tmp_path / 'run.mcap')
    s = run_scenario(Scenario(task='speed', strategy='constant_flux', duration=0.05),
                     record=path, progress=False)
    s.pop('_run')
    meta = info(path).metadata
    assert meta['scenario']['strategy'] == 'constant_flux'
    assert meta['parameters/plant']['R_s'] == '0.687'          # a default, not an override
    assert meta['parameters/controller']['strategy'] == "'constant_flux'"
    assert 'revision' in meta['git'] and 'ros-rclpy' in meta['versions']
    fig = figures_of_merit(load_run(path))      # the report of the bag = the live summary
    for key in ('E_in_J', 'E_loss_J', 'speed_err_max_rad_s', 'torque_err_max_Nm'):
        assert fig[key] == pytest.approx(s[key], rel=1e-12), key


def test_a_node_at_another_period_is_refused_by_name():
    """
    Different T_s per node would deadlock at step 1.

    The plant refuses to start and names the node and both periods.
    """
    res = run_graph(task='position', duration=0.05, parameters={'observer': {'T_s': 2e-4}})
    assert not res.summary['ok']
    msg = res.summary['failures']['plant']
    assert "node 'observer' runs at T_s = 0.0002 s" in msg and '0.0001 s' in msg


def test_non_finite_command_is_refused_and_held_by_the_observer(ros_context):
    """
    Check that a NaN command does not kill the observer.

    A NaN on /im/command/voltage (the plant rejects and holds it) must not kill the observer
    either: refused, logged with its stamp, counted, the previous command held.
    """
    from im_common import topics as T
    from im_common.auth import Signer
    from im_common.conversions import JointStateOut, Vector3Out
    from im_observer.observer_node import ObserverNode
    node = ObserverNode(context=ros_context, graph_key=bytes(32))
    node.adopt_run('run1')                 # as if the plant of run1 had announced itself
    sign = Signer(bytes(32), 'run1').sign  # ... and the graph's nodes signed their messages
    subs = {s.topic_name: s for s in node.subscriptions}
    vec, shaft = Vector3Out(Signer.frame('ab')), JointStateOut([T.SHAFT_JOINT], Signer.frame(''))
    for k in range(3):
        ns = k * node.period
        subs[T.MEAS_CURRENT].callback(sign(T.MEAS_CURRENT, vec.fill(ns, 1.0, 0.0)))
        subs[T.MEAS_SHAFT].callback(sign(T.MEAS_SHAFT, shaft.fill(ns, (0.0,), (0.0,))))
        subs[T.CMD_VOLTAGE].callback(sign(T.CMD_VOLTAGE, vec.fill(
            ns, 10.0 if k == 0 else float('nan'), 0.0)))
    assert not node.done and node.exit_code == 0
    assert node.refused == 2 and node.k_done == 2           # steps 1, 2 ran on the held 10 V
    assert all(math.isfinite(v) for v in node.obs.state)
    node.destroy_node()


def test_a_free_run_observer_bridges_a_stalled_loop_up_to_the_plant(ros_context):
    """
    Check that one lost command does not stop a free_run loop for the rest of the run.

    The controller's command of step 0 never reaches the observer (lost from its reader history
    while it was starved: two free_run graphs on one domain). The controller waits for the
    observer's estimate of step 1, the observer for that command: before, neither moved again
    (2000 of 2000 steps without a command). Now the observer, 50 steps behind the plant's
    measurements with no step complete, bridges open-loop up to the plant's present step, and the
    next command it gets is computed on.
    """
    from im_common import topics as T
    from im_common.auth import Signer
    from im_common.conversions import JointStateOut, Vector3Out
    from im_common.lockstep_protocol import RUNNING
    from im_observer.observer_node import STALL_STEPS, ObserverNode
    node = ObserverNode(context=ros_context, graph_key=bytes(32))
    node.on_peer_status('plant', RUNNING, {'time_master': 'true', 'run_id': 'run1',
                                           'mode': 'free_run'})
    assert node.run_id == 'run1' and node.gate.follow
    sign = Signer(bytes(32), 'run1').sign
    subs = {s.topic_name: s for s in node.subscriptions}
    vec, shaft = Vector3Out(Signer.frame('ab')), JointStateOut([T.SHAFT_JOINT], Signer.frame(''))

    def measure(k):
        ns = k * node.period
        subs[T.MEAS_CURRENT].callback(sign(T.MEAS_CURRENT, vec.fill(ns, 1.0, 0.0)))
        subs[T.MEAS_SHAFT].callback(sign(T.MEAS_SHAFT, shaft.fill(ns, (0.0,), (0.0,))))

    for k in range(STALL_STEPS):            # no command: the loop has stalled at step 0
        measure(k)
    assert node.k_done == -1 and node.bridged == 0      # 49 steps behind: still waiting
    measure(STALL_STEPS)
    assert node.k_done == STALL_STEPS - 1 and node.bridged == STALL_STEPS
    assert node.gate.expected == STALL_STEPS * node.period
    subs[T.CMD_VOLTAGE].callback(sign(T.CMD_VOLTAGE, vec.fill(STALL_STEPS * node.period,
                                                              10.0, 0.0)))
    assert node.k_done == STALL_STEPS and node.bridged == STALL_STEPS    # computed on again
    assert not node.done and node.exit_code == 0
    assert all(math.isfinite(v) for v in node.obs.state)
    node.destroy_node()


def test_a_free_run_plant_that_cannot_keep_real_time_stops_and_says_so():
    """
    free_run at 100 kHz: no Python plant integrates and publishes a step in 10 µs.

    Behind the wall clock, the plant catches up tick after tick without sleeping (at real-time
    priority it held a core for minutes when a machine could not keep up); more than
    ``max_lag`` behind it stops the run, naming how far behind and why.
    """
    res = run_graph(task='position', T_s=1e-5, duration=1.0,      # forced past the probe
                    parameters={'plant': {'mode': 'free_run', 'max_lag': 0.05,
                                          'force_rate': True, 'deadline_miss_limit': 0.0}})
    assert not res.summary['ok']
    reasons = str(res.summary['failures'])
    assert 'behind the wall clock' in reasons and 'max_lag = 0.05 s' in reasons, reasons
    assert 'cannot integrate T_s = 1e-05 s in real time' in reasons
    assert res.summary['steps'] < 50_000          # stopped early, not after catching up
