"""
Issue 10 (motor files, profiles, loads) through the lock-step graph.

Issue 10 through the lock-step graph: a motor file, a profile and a load of one's own reach
every node through ``node_parameters`` (the in-process fixture passes them straight on), and the
graph still equals the offline loop with them.
"""
import os

from im_bringup.config import node_parameters
from im_bringup.testing import assert_samples_match, run_graph
from im_common.params import load_motor_file
import numpy as np
import pytest

HERE = os.path.dirname(os.path.abspath(__file__))
MOTOR = os.path.join(HERE, '..', 'src', 'im_common', 'config', 'motors', 'krause_3hp.yaml')


@pytest.fixture
def files(tmp_path):
    prof = tmp_path / 'profile.yaml'
    prof.write_text('setpoints:\n  - {t: 0.0, velocity: 100.0}\n'
                    '  - {t: 0.01, velocity: 120.0, duration: 0.03}\n')
    load = tmp_path / 'load.yaml'
    load.write_text('kind: linear\nc1: 0.5\nc2: 0.002\n')
    return str(prof), str(load)


def test_motor_profile_and_load_reach_every_node(files):
    prof, load = files
    p = node_parameters('speed', 'min_loss', motor=MOTOR, profile=prof, load=load, v_limit=220.0,
                        limits={'current_limit': 20.0}, protection={'current_trip': 60.0})
    m = load_motor_file(MOTOR)
    for node in ('plant', 'controller', 'observer', 'adapter'):
        assert p[node]['L_sr'] == m.L_sr, node
        assert p[node]['rated_current_rms'] == m.rated_current_rms, node
    c = p['controller']
    assert c['profile'] == 'setpoint' and c['setpoints'] == [0.0, 100.0, 0.0, 0.01, 120.0, 0.03]
    assert c['load'] == 'linear' and c['load_c1'] == 0.5 and c['current_limit'] == 20.0
    assert p['plant']['load_c2'] == 0.002 and p['plant']['omega0'] == 100.0
    assert p['plant']['current_trip'] == 60.0
    # an explicit mismatch: the model differs from the plant only where asked
    q = node_parameters('speed', 'min_loss', motor=MOTOR,
                        estimates=m.with_values(R_r=1.2 * m.R_r), profile=prof)
    assert (q['plant']['R_r'] == m.R_r
            and q['controller']['R_r'] == q['observer']['R_r'] == 1.2 * m.R_r)


def test_node_parameters_refuse_bad_options(files, tmp_path):
    prof, _ = files
    with pytest.raises(ValueError, match='is a speed profile; the task is position'):
        node_parameters('position', profile=prof)
    with pytest.raises(ValueError, match="invalid limit 'torque'"):
        node_parameters('speed', limits={'torque': 1.0})
    bad = tmp_path / 'm.yaml'
    bad.write_text('/**:\n  ros__parameters:\n    R_s: 1.0\n')
    with pytest.raises(ValueError, match='m.yaml: R_r'):
        node_parameters('speed', motor=str(bad))


def test_graph_equals_the_offline_loop_with_motor_profile_load_and_limits(files):
    from im_bringup.offline import Scenario, simulate
    from im_common.loads import load_file
    from im_controller.profiles import load_profile
    prof, load = files
    limits = {'current_limit': 25.0, 'torque_limit': 15.0}
    g = run_graph(task='speed', strategy='min_loss', duration=0.05, motor=MOTOR, profile=prof,
                  load=load, v_limit=220.0, limits=limits)
    off = simulate(Scenario(task='speed', strategy='min_loss', duration=0.05,
                            motor=load_motor_file(MOTOR), profile=load_profile(prof),
                            load_model=load_file(load), v_limit=220.0, controller_options=limits))
    assert g.summary['ok'], g.summary['failures']
    for key in ('E_in_J', 'E_copper_J', 'dW_magnetic_J'):
        assert g.summary[key] == pytest.approx(off.summary[key], rel=1e-9, abs=1e-12), key
    assert_samples_match(g.trace, off.trace, ('omega_r', 'theta_r'), 400)
    # the profile was followed: the reference reached 120 rad/s
    assert np.nanmax(g.trace['omega_ref']) == pytest.approx(120.0, abs=1e-6)


def test_torque_task_follows_an_effort_profile_in_the_graph_and_offline(tmp_path):
    """
    Check the torque task following an effort profile, in the graph and offline.

    The torque task (an effort profile, beyond the thesis): graph and offline loop agree, the
    torque follows the profile once the machine is magnetized.
    """
    from im_bringup.offline import Scenario, simulate
    from im_controller.profiles import load_profile
    prof = tmp_path / 'effort.yaml'
    prof.write_text('setpoints:\n  - {t: 0.0, effort: 0.0}\n  - {t: 0.03, effort: 2.0, duration: '
                    '0.01}\n')
    g = run_graph(task='torque', strategy='constant_flux', duration=0.06, profile=str(prof))
    off = simulate(Scenario(task='torque', strategy='constant_flux', duration=0.06,
                            profile=load_profile(str(prof))))
    assert g.summary['ok'], g.summary['failures']
    assert g.summary['E_in_J'] == pytest.approx(off.summary['E_in_J'], rel=1e-9)
    assert off.trace['tau_ref'][-1] == pytest.approx(2.0)
    with pytest.raises(ValueError, match='torque task needs a profile'):
        node_parameters('torque')


def _message_from_yaml(msg_type, text: str):
    """
    Build the message ``ros2 topic pub TOPIC TYPE 'TEXT'`` publishes.

    The message ``ros2 topic pub TOPIC TYPE 'TEXT'`` publishes: a default-constructed message
    whose fields named in the YAML are set (rosidl_runtime_py.set_message_fields' rule), every
    other field left at its default — an unset header stamp is 0 s 0 ns, unset arrays empty.
    """
    import yaml
    msg = msg_type()
    for name, value in yaml.safe_load(text).items():
        setattr(msg, name, value)
    return msg


@pytest.mark.slow
def test_a_setpoint_sent_the_readme_way_moves_the_reference_from_where_it_is():
    """
    Check that a setpoint sent the README's way moves the reference from where it is.

    Issue 23: the README's ``ros2 topic pub --once /im/setpoint sensor_msgs/msg/JointState
    '{name: [rotor], velocity: [150.0]}'`` (stamp 0, "now") sent at t = 0.6 s, long after the
    start: θ*, ω* continue from where they are (no rebuilt past), ω* takes the quintic's
    setpoint_duration to 150 with its peak acceleration 1.875·Δω/T, τ* stays within the torque
    that acceleration needs (far under the torque limit) and the shaft does not overshoot.
    """
    import rclpy.node
    from sensor_msgs.msg import JointState

    from im_bringup.graph import DriveGraph
    from im_common import topics as T
    from im_common.conversions import stamp_ns
    from im_common.params import THESIS_MOTOR

    t_send, duration, T_s = 0.6, 0.5, 1e-4
    params = node_parameters('speed', 'min_loss', duration=t_send + duration + 0.2)
    params['controller'].update(profile='setpoint', setpoint_duration=duration,
                                torque_limit=20.0)
    msg = _message_from_yaml(JointState, '{name: [rotor], velocity: [150.0]}')
    assert stamp_ns(msg.header.stamp) == 0 and list(msg.position) == [] and list(msg.effort) == []
    rows, sent = [], []
    graph = DriveGraph(params)
    try:
        user = rclpy.node.Node('user', context=graph.context)
        pub = user.create_publisher(JointState, T.SETPOINT, 10)    # ros2 topic pub's default QoS
        graph.executor.add_node(user)
        node = graph.nodes['controller']
        step = node.step

        def recorded_step(inputs):
            step(inputs)
            r = node.ctl.reference
            rows.append((r['t'], r['theta_ref'], r['omega_ref'], r['tau_ref'],
                         inputs[T.MEAS_SHAFT][1]))
            if not sent and r['t'] >= t_send:
                pub.publish(msg)
                sent.append(r['t'])
        node.step = recorded_step
        stats = graph.run()
        user.destroy_node()
    finally:
        graph.close()
    assert stats['ok'], stats['failures']
    t, theta, omega, tau, omega_r = np.array(rows).T
    assert np.all(np.diff(t) == pytest.approx(T_s, rel=1e-9))
    start = int(np.argmax(omega > 135.0 + 1e-9))      # the first step the setpoint moved ω*
    assert start > 0 and t[start] > sent[0], 'applied from now, not from its stamp 0'
    a_max = 1.875 * (150.0 - 135.0) / duration         # peak acceleration of the quintic
    # continuous: ω* moves at most a_max·T_s a step; θ* advances by ω*·T_s (no jump)
    assert np.max(np.abs(np.diff(omega))) <= a_max * T_s * 1.001
    assert np.max(np.abs(np.diff(theta) - omega[1:] * T_s)) < a_max * T_s * T_s
    # the whole transition takes setpoint_duration (not cut short by a rebuilt past)
    end = int(np.argmax(omega >= 150.0 - 1e-9))
    assert t[end] - t[start] == pytest.approx(duration, abs=2 * T_s)
    # τ*: the torque it held before plus what the acceleration, friction and the speed-dependent
    # load need on the way (the PD's share is small); the torque limit never binds
    m, c2 = THESIS_MOTOR, params['plant']['load_c2']
    assert np.max(np.abs(tau)) < 1.05 * (tau[start - 1] + m.J * a_max + (m.b + c2) * 15.0) < 20.0
    assert np.max(np.abs(np.diff(tau))) < 0.01
    assert np.max(omega_r) < 150.0 + 0.05 and omega_r[-1] == pytest.approx(150.0, abs=0.01)


def test_the_same_setpoint_sent_twice_is_two_commands_and_one_message_on_both_subscriptions_one(
        ros_context):
    """
    Check that a setpoint sent twice counts twice, and one message on both subscriptions once.

    `ros2 topic pub` 150, then 100, then 150 again: three commands (same stamp 0, same
    value as the first is no reason to drop the third); a transient-local publisher's message,
    delivered on both of the controller's subscriptions, is one command.
    """
    from rclpy.parameter import Parameter
    from sensor_msgs.msg import JointState

    from im_common import topics as T
    from im_controller.controller_node import ControllerNode
    node = ControllerNode(context=ros_context, graph_key=bytes(32), parameter_overrides=[
        Parameter('mode', value='speed'), Parameter('profile', value='setpoint')])
    try:
        volatile, latched = [s for s in node.subscriptions if s.topic_name == T.SETPOINT]
        for value in (150.0, 100.0, 150.0):
            volatile.callback(_message_from_yaml(JointState, f'{{velocity: [{value}]}}'))
        assert [v for _, v, _ in node.ctl._schedule] == [150.0, 100.0, 150.0]
        msg = _message_from_yaml(JointState, '{velocity: [120.0]}')
        latched.callback(msg)
        volatile.callback(msg)
        assert [v for _, v, _ in node.ctl._schedule] == [150.0, 100.0, 150.0, 120.0]
    finally:
        node.destroy_node()


def test_a_negative_gain_is_refused_by_name_and_the_default_sentinel_says_what_it_uses(
        ros_context):
    """
    Check that a negative gain is refused by name and the -1 sentinel says what it uses.

    Issue 23: `ros2 param set /controller k_p -0.5` was accepted and logged as -0.5 while the
    per-mode default ran. Now -0.5 is refused with one line naming k_p (the old value stays in
    force); -1, the documented sentinel, is accepted and announced with the gain it stands for.
    """
    from rclpy.parameter import Parameter

    from im_common import topics as T
    from im_controller.controller_node import ControllerNode
    node = ControllerNode(context=ros_context, graph_key=bytes(32),
                          parameter_overrides=[Parameter('k_p', value=4.0)])
    said = []
    node.status = lambda state, *a, **kw: said.append((state, kw))
    try:
        for name in ('k_p', 'k_v', 'flux_preview'):
            res = node.set_parameters([Parameter(name, value=-0.5)])[0]
            assert not res.successful and res.reason.startswith(f"invalid parameter '{name}' = "
                                                                '-0.5')
            assert '\n' not in res.reason
        assert node.get_parameter('k_p').value == 4.0 and node._pending_changes is None
        assert node.set_parameters([Parameter('k_p', value=-1.0)])[0].successful
        assert node.ctl.config.k_p == 4.0                 # applied at the next step, not before
        for topic, value in ((T.MEAS_CURRENT, (0.0, 0.0)), (T.MEAS_SHAFT, (0.0, 0.0)),
                             (T.OBS_FLUX, (0.0, 0.0))):
            node.ready(node.gate.put(topic, 0, value))
        assert node.ctl.config.k_p == 10.0                # the position task's default
        assert ('parameters', {'k_p': '-1.0 (per-mode default: 10.0)'}) in said
    finally:
        node.destroy_node()
