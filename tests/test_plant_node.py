"""
The plant node in lock-step.

It advances only on a command stamped t_k, refuses bad input, reports a missing command by topic
and stamp, and never lets its state become NaN.
"""
import math

from geometry_msgs.msg import Vector3Stamped
from im_common import topics as T
from im_common.auth import Signer
from im_common.conversions import stamp_ns, Vector3Out
from im_common.lockstep import lockstep_qos, make_executor
from im_common.params import InvalidParameter
from im_plant.plant_node import PlantNode
import numpy as np
import pytest
import rclpy
from rclpy.node import Node
from rclpy.parameter import Parameter


@pytest.fixture
def ctx(ros_context):
    return ros_context


def make_plant(ctx, **overrides):
    """
    Return a plant alone with a stand-in controller.

    It waits for no other node before step 0.
    """
    params = [Parameter('wait_for', value='')]
    params += [Parameter(k, value=v) for k, v in overrides.items()]
    return PlantNode(context=ctx, parameter_overrides=params)


def _commander(ctx, voltage, plant):
    """
    Return a stand-in controller of the plant's graph (it signs with the plant's key and run).

    Answers each measurement with voltage(ns) stamped like it.
    """
    node = Node('controller', context=ctx)
    pub = node.create_publisher(Vector3Stamped, T.CMD_VOLTAGE, lockstep_qos())
    out = Vector3Out(Signer.frame('alphabeta'))
    seen = []

    def on_meas(m):
        ns = stamp_ns(m.header.stamp)
        seen.append(ns)
        v = voltage(ns)
        if v is None:
            return
        pub.publish(plant.signer.sign(T.CMD_VOLTAGE, out.fill(ns, *v)))
    node.create_subscription(Vector3Stamped, T.MEAS_CURRENT, on_meas, lockstep_qos())
    return node, seen


def _spin(ctx, nodes, until, cap=4000):
    ex = make_executor(ctx)
    for n in nodes:
        ex.add_node(n)
    for _ in range(cap):
        if until():
            break
        ex.spin_once(timeout_sec=0.05)
    ex.shutdown()


def test_lockstep_advances_exactly_to_duration(ctx):
    plant = make_plant(ctx, duration=0.05, load='linear')
    w = 2 * math.pi * 60
    cmd, seen = _commander(ctx, lambda ns: (200 * math.cos(w * ns * 1e-9),
                                            200 * math.sin(w * ns * 1e-9)), plant)
    _spin(ctx, [plant, cmd], lambda: plant.done)
    assert plant.exit_code == 0
    assert plant.sim.k == 500                      # 0.05 s at the default T_s = 100 µs
    # one measurement per step, in order (the last one may still be in flight when spinning stops)
    assert seen[:500] == [k * 100_000 for k in range(500)] and len(seen) <= 501
    assert plant.sim.x[5] > 0.0                    # the rotating field pulled the rotor along
    plant.destroy_node()
    cmd.destroy_node()


def test_missing_command_is_reported_by_topic_and_stamp(ctx, caplog):
    plant = make_plant(ctx, duration=1.0, input_timeout=0.3, startup_timeout=5.0)
    # The stand-in controller stops answering after step 3.
    cmd, _ = _commander(ctx, lambda ns: (1.0, 0.0) if ns < 4 * 100_000 else None, plant)
    _spin(ctx, [plant, cmd], lambda: plant.done)
    assert plant.exit_code == 1
    assert T.CMD_VOLTAGE in plant.failure
    assert '0.000400000 s' in plant.failure and 'step 4' in plant.failure
    assert plant.sim.k == 4
    plant.destroy_node()
    cmd.destroy_node()


def test_non_finite_command_rejected_state_stays_finite(ctx):
    plant = make_plant(ctx, duration=0.002)
    cmd, _ = _commander(ctx, lambda ns: (float('nan'), 1.0) if ns == 500_000 else (10.0, 0.0),
                        plant)
    _spin(ctx, [plant, cmd], lambda: plant.done)
    assert plant.exit_code == 0
    assert plant.rejected == 1
    assert all(math.isfinite(v) for v in plant.sim.x)
    plant.destroy_node()
    cmd.destroy_node()


def test_of_two_running_plants_of_one_key_the_later_yields(ctx):
    """
    Discovery is asynchronous.

    A plant can reach step 0 before it sees another plant of the same key already running on
    the domain. When the two see each other, the one that started later fails naming the other
    and the domain; the earlier run goes on.
    """
    from im_common.lockstep import RUNNING
    plant = make_plant(ctx, duration=5.0)
    cmd, _ = _commander(ctx, lambda ns: (10.0, 0.0), plant)
    _spin(ctx, [plant, cmd], lambda: plant.sim.k >= 3)
    assert plant.started_at is not None and not plant.done
    later = {'time_master': 'true', 'run_id': 'later000',
             'started_at': f'{plant.started_at + 0.5:.6f}'}
    plant.on_peer_status('plant', RUNNING, later)
    assert not plant.done                       # the other one started later: it yields
    earlier = {'time_master': 'true', 'run_id': 'earlier0',
               'started_at': f'{plant.started_at - 0.5:.6f}'}
    plant.on_peer_status('plant_first', RUNNING, earlier)
    assert plant.done and plant.exit_code == 1
    assert "another plant ('plant_first', run earlier0)" in plant.failure
    assert 'ROS_DOMAIN_ID' in plant.failure
    plant.destroy_node()
    cmd.destroy_node()


@pytest.mark.parametrize('name,value,needle', [
    ('R_s', -1.0, 'R_s'),
    ('T_s', 0.0, 'T_s'),
    ('L_sr', 0.09, 'L_sr'),          # σ = 1 − L_sr²/(L_s L_r) < 0
    ('load', 'rocket', 'load'),
])
def test_invalid_parameter_is_refused_by_name(ctx, name, value, needle):
    with pytest.raises((InvalidParameter, ValueError,
                        rclpy.exceptions.InvalidParameterValueException)) as err:
        PlantNode(context=ctx, parameter_overrides=[Parameter(name, value=value)])
    assert needle in str(err.value)


def test_custom_variation_drives_the_true_parameter(ctx):
    plant = make_plant(ctx, duration=0.01, variation='custom', variation_parameter='R_r',
                       variation_kind='ramp', variation_offset=0.5, variation_slope=10.0)
    cmd, _ = _commander(ctx, lambda ns: (10.0, 0.0), plant)
    _spin(ctx, [plant, cmd], lambda: plant.done)
    assert plant.sim.truth()['R_r'] == pytest.approx(0.5 + 10.0 * 0.01)
    plant.destroy_node()
    cmd.destroy_node()


def test_custom_variation_that_breaks_sigma_is_refused(ctx):
    with pytest.raises(InvalidParameter) as err:
        PlantNode(context=ctx, parameter_overrides=[
            Parameter('duration', value=1.0), Parameter('variation', value='custom'),
            Parameter('variation_parameter', value='L_sr'),
            Parameter('variation_kind', value='ramp'),
            Parameter('variation_offset', value=0.08136),
            Parameter('variation_slope', value=0.01)])
    assert 'L_sr' in str(err.value) and 't = ' in str(err.value)


def test_shaft_decoder_fast_path_equals_the_general_decoder():
    from im_common.cdr import decode_joint_state, pack_joint_state
    from im_common.conversions import JointStateOut, shaft_in
    for theta, omega in ((0.0, 0.0), (-1.5707963267948966, 135.25), (1e9, -3e-12)):
        data = JointStateOut([T.SHAFT_JOINT]).fill(123_456_789_000, (theta,), (omega,))
        assert shaft_in(data) == (123_456_789_000, (theta, omega))
    # another layout (frame id, extra joint) takes the general path and still decodes right
    other = pack_joint_state(1, 2, ('rotor', 'x'), (0.5, 9.0), (7.0, 8.0), (), 'frame')
    assert shaft_in(other) == (1_000_000_002, (0.5, 7.0))
    assert decode_joint_state(other)[3] == (0.5, 9.0)


def test_a_peers_warning_does_not_undo_its_ready(ctx):
    """
    Check that a follower that warns after 'ready' is still ready.

    A follower that is ready and then warns (a foreign graph's messages refused, real-time
    scheduling refused, new parameters) is still ready: the warning and parameters events are not
    states. Two graphs on one domain made the controller warn after 'ready' and the plant waited
    for it until its startup timeout.
    """
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
    from im_common.auth import status_payload
    from im_common.lockstep import PARAMETERS, READY, WARNING
    plant = make_plant(ctx, wait_for='controller', duration=0.01)

    def event(state, **values):
        msg = DiagnosticArray()
        values = dict(values, run_id=plant.run_id, T_s_ns=plant.period)
        msg.status = [DiagnosticStatus(level=bytes([0]), name='controller', message=state,
                                       hardware_id='im_drive',
                                       values=[KeyValue(key=k, value=str(v))
                                               for k, v in values.items()])]
        msg.header.frame_id = plant.status_signer.tag_bytes(T.STATUS, status_payload(msg))
        plant.events.receive(msg)

    assert not plant.master.start_condition(plant.peers)[0]
    event(READY)
    assert plant.master.start_condition(plant.peers)[0]
    event(WARNING, reason="ignoring /im/status event 'waiting' from 'controller_b'")
    event(PARAMETERS, k1='2.0')
    assert plant.peers['controller'][0] == READY
    assert plant.master.start_condition(plant.peers)[0]
    plant.destroy_node()


def _graph_summary(task, duration, plant=None, controller_hook=None, **config):
    """
    Run one in-process graph and return its summary.

    One in-process graph run's summary (the figures ``scenario`` prints and writes), with optional
    plant parameters and a hook given the controller node before the run.
    """
    from im_bringup.config import node_parameters
    from im_bringup.graph import DriveGraph
    from im_bringup.scenario import summarize
    from im_recording.traces import Tap
    params = node_parameters(task, 'min_loss', duration=duration, **config)
    params['plant'].update(plant or {})
    sink = Tap(None, keep=True)
    graph = DriveGraph(params, recorder=sink)
    try:
        if controller_hook is not None:
            controller_hook(graph.nodes['controller'])
        stats = graph.run()
    finally:
        graph.close()
    s = summarize(params, stats, sink, task=task, strategy='min_loss', controller='nominal',
                  variation='none')
    return s, s.pop('_run').trace


def test_a_one_step_voltage_spike_is_in_the_summary():
    """
    Issue 23: V_max_V came from the decimated /im/truth/voltage and missed a 314 V spike.

    A command of 314 V at one step between two truth samples (step 1234; truth every 10 steps)
    is applied by the plant for that period, and the summary's peak is exactly it; the true
    current peak is the every-step one too.
    """
    spike_ns = 1234 * 100_000

    def hook(node):
        compute = node.ctl.compute

        def spiking(t, *args, **kw):
            v = compute(t, *args, **kw)
            return (314.0, 0.0) if round(t * 1e9) == spike_ns else v
        node.ctl.compute = spiking
    s, tr = _graph_summary('position', 0.2, controller_hook=hook)
    assert s['ok'], s['failures']
    assert s['V_max_V'] == pytest.approx(314.0, rel=1e-12)
    # the sampled applied voltage alone never saw it
    assert np.nanmax(np.hypot(tr['v_alpha'], tr['v_beta'])) < 100.0
    assert s['i_max_A'] == pytest.approx(np.nanmax(np.hypot(tr['i_alpha'], tr['i_beta'])),
                                         rel=1e-12)      # noise-free: measured = true, every step


def test_tracking_errors_come_from_the_true_shaft_not_the_noisy_measurement():
    """
    Check that the summary's speed error is the true one under measurement noise.

    Issue 23: with speed measurement noise the summary's speed error was the noise's (0.20 rad/s
    where the true error was 0.009). The plant publishes the true shaft on /im/truth/shaft and
    every tracking figure uses it: with σ = 0.05 rad/s of noise the summary's speed error is
    |ω_true − ω*| over the reference instants, exactly, not the measured one (≈ 3σ). (It is not the
    noise-free run's: the controller's PD acts on the noisy speed, so the shaft really does move
    more — 0.016 against 0.0009 rad/s here.)
    """
    s, tr = _graph_summary('speed', 0.3, plant={'speed_noise_std': 0.05, 'noise_seed': 3})
    assert s['ok'], s['failures']
    true_err = np.nanmax(np.abs(tr['omega_true'] - tr['omega_ref']))
    measured_err = np.nanmax(np.abs(tr['omega_r'] - tr['omega_ref']))
    assert s['speed_err_max_rad_s'] == pytest.approx(true_err, rel=1e-12)
    assert s['speed_err_rms_rad_s'] == pytest.approx(
        np.sqrt(np.nanmean((tr['omega_true'] - tr['omega_ref']) ** 2)), rel=1e-9)
    assert measured_err > 0.1 and measured_err > 5 * s['speed_err_max_rad_s']
    # the true shaft is sampled at every reference instant (both every 10 steps)
    ref = np.isfinite(tr['omega_ref'])
    assert ref.sum() > 0 and np.isfinite(tr['omega_true'][ref]).all()


def test_the_live_load_offset_acts_from_the_step_it_is_announced_at(ctx):
    """
    `ros2 param set /plant load_offset 3.0` during a run.

    A bad value is refused with one line naming it; a good one is staged and acts from the next
    step boundary, announced on /im/status with its step. The run equals the ROS-free plant with
    the offset set before that step (lock-step determinism).
    """
    from im_common.loads import ConstantLoad
    from im_plant.plant_sim import PlantSimulator
    plant = make_plant(ctx, duration=0.03, load='constant', load_tau=1.0, omega0=50.0)
    said = []
    status = plant.status
    plant.status = lambda state, *a, **kw: (said.append((state, kw)), status(state, *a, **kw))
    refused = []

    def voltage(ns):
        if ns == 100 * plant.period:        # while step 100 waits for its command
            for bad in (float('nan'), 'three'):
                refused.append(plant.set_parameters([Parameter('load_offset', value=bad)])[0])
            assert plant.set_parameters([Parameter('load_offset', value=3.0)])[0].successful
            assert plant.sim.load_offset == 0.0         # staged, not yet in force
        return (5.0, 0.0)
    cmd, _ = _commander(ctx, voltage, plant)
    _spin(ctx, [plant, cmd], lambda: plant.done)
    assert plant.exit_code == 0 and plant.sim.k == 300
    assert [r.successful for r in refused] == [False, False]
    assert 'load_offset' in refused[0].reason and '\n' not in refused[0].reason
    events = [kw for state, kw in said if state == 'parameters']
    assert events == [{'stamp_ns': 100 * plant.period, 'load_offset': '3.0', 'step': 100}]
    sim = PlantSimulator(load=ConstantLoad(1.0), T_s=plant.T_s, omega0=50.0)
    for k in range(300):
        if k == 100:
            sim.set_load_offset(3.0)
        sim.step(5.0, 0.0)
    assert sim.x == plant.sim.x
    plant.destroy_node()
    cmd.destroy_node()


def test_a_motor_given_without_ratings_or_core_loss_is_warned_of_once_per_default(
        ctx, capfd, monkeypatch):
    """A motor parameters file without k_e, k_h and ratings: one warning line per default."""
    from im_common import params
    from im_common.params import ELECTRICAL_NAMES, THESIS_MOTOR
    monkeypatch.setattr(params, '_WARNED', set())       # what earlier tests warned of
    motor = {n: getattr(THESIS_MOTOR, n) for n in ELECTRICAL_NAMES}
    plant = make_plant(ctx, duration=0.01, **motor)
    warned = [ln for ln in capfd.readouterr().err.splitlines() if "node 'plant' motor" in ln]
    assert len(warned) == 6 and all('WARN' in ln for ln in warned)
    assert [ln.split('motor: ')[1].split(':')[0] for ln in warned] == [
        'no k_e', 'no k_h', 'no rated_voltage_rms_line', 'no rated_current_rms',
        'no rated_speed_rpm', 'no rated_flux (nor rated_voltage_rms_line, rated_frequency, '
        'rated_speed_rpm to derive it)']
    plant.destroy_node()
    plant = make_plant(ctx, duration=0.01, **motor)         # once per process
    assert "node 'plant' motor" not in capfd.readouterr().err
    plant.destroy_node()
    # the thesis's runs give no motor: nothing to warn of
    plant = make_plant(ctx, duration=0.01)
    assert "node 'plant' motor" not in capfd.readouterr().err
    plant.destroy_node()
