"""
The graph as ROS users run it.

Every node its own process, started the way the launch file starts them
(:mod:`im_bringup.processes`: the executables ``ros2 run`` finds, ``-r __node:=``, one ``/**``
parameters file per node), plus the recorder.

What users rely on: every process exits 0 at the end; the multi-process run computes the same
numbers as the in-process graph (stamps decide, not scheduling); the recording holds every
lock-step message even with a busy process beside the graph; Ctrl-C (on the graph or on one node)
ends every process cleanly with a readable recording; a killed node is reported by the plant and
nothing hangs; a recorder that joins late records without a gap from where it joined; free_run
closes the loop in wall-clock time; live parameters are validated, applied and recorded.
"""
from collections import Counter
import os
import re
import signal
import subprocess
import sys
import time

from conftest import FREE_RUN_RATES
from im_bringup.processes import graph_processes, GraphProcesses
from im_bringup.testing import assert_all_ended, random_domain, wait_for_log, wait_until
from im_common import topics as T
from im_recording.bag import info, iter_raw, partial_path
import pytest

LOCKSTEP = (T.MEAS_CURRENT, T.MEAS_SHAFT, T.CMD_VOLTAGE, T.OBS_FLUX)


@pytest.fixture
def domain():
    return {'ROS_DOMAIN_ID': str(random_domain())}


def counts(bag):
    return Counter(t for t, *_ in iter_raw(bag))


def plant_end(bag):
    """(state, step, values) of the plant's final event in the bag (None if it has none)."""
    end = None
    for _, m in _statuses(bag):
        st = m.status[0]
        values = {kv.key: kv.value for kv in st.values}
        if values.get('time_master') == 'true' and st.message in ('finished', 'stopped', 'failed'):
            end = (st.message, int(values['step']), values)
    return end


def missing_in_bag(bag, period=100_000):
    """
    Count the steps each lock-step topic lacks in the bag.

    How many steps of the run the bag lacks, from step 0 to the plant's final step (the command
    of the final step is never computed; after a stop only the measurements of the final step
    are sure to exist).
    """
    state, step, _ = plant_end(bag)
    stamps = {t: set() for t in LOCKSTEP}
    for topic, _, t, _ in iter_raw(bag, list(LOCKSTEP)):
        stamps[topic].add(t)
    out = {}
    for topic in LOCKSTEP:
        measured = topic in (T.MEAS_CURRENT, T.MEAS_SHAFT)
        last = step if measured or (state == 'finished' and topic != T.CMD_VOLTAGE) else step - 1
        out[topic] = len({k * period for k in range(last + 1)} - stamps[topic])
    return out


#: The signed topics that are not lock-step: the reports of the graph's nodes (those of the real
#: plant's blocks only when the run has them: none of these runs does).
REPORTS = tuple(t for t in T.SIGNED_TOPICS if t not in T.LOCKSTEP_TOPICS
                and t not in (T.TRUTH_TEMPERATURE, T.TRUTH_INVERTER))


class _Defaults:
    """Stand in for a node while declaring its parameters: every parameter keeps its default."""

    def param(self, name, default, *args, **kwargs):
        return default


def report_stamps(topic, procs, bag, period, grid=False):
    """
    Return the stamps one graph alone publishes a report topic at, from its nodes' parameters.

    The truth every truth_decimation steps and at the plant's final step; the references with
    the commands (as recorded: lock-step, signed) every reference_decimation steps; the observer
    current with the flux estimates every estimate_decimation steps and from the observer's last
    step on. ``grid``: every stamp of the run on that decimation instead of only those whose
    lock-step message the bag holds (a free_run recording may lack a command, reported missing,
    and still hold its step's reference).
    """
    from im_observer.parameters import declare_observer
    params = {p.name: p.parameters for p in procs}
    _, step, _ = plant_end(bag)
    if topic.startswith('/im/truth/'):
        every = params['plant']['truth_decimation']
        return {k * period for k in range(step + 1) if k % every == 0} | {step * period}
    if topic.startswith('/im/reference/'):
        every = params['controller']['reference_decimation']
        stamps = ([k * period for k in range(step + 1)] if grid
                  else [t for _, _, t, _ in iter_raw(bag, [T.CMD_VOLTAGE])])
        return {t for t in stamps if (t // period) % every == 0}
    assert topic == T.OBS_CURRENT, topic
    obs = params['observer']
    every = obs.get('estimate_decimation', declare_observer(_Defaults())['estimate_decimation'])
    last = round(obs['duration'] / obs['T_s'])
    stamps = ([k * period for k in range(step + 2)] if grid
              else [t for _, _, t, _ in iter_raw(bag, [T.OBS_FLUX])])
    return {t for t in stamps if (t // period) % every == 0 or t >= last * period}


def no_traceback(g):
    for name in g.popen:
        log = g.log(name)
        assert 'Traceback' not in log and 'FATAL' not in log, f'{name}:\n{log[-3000:]}'


#: A step the run has passed when a test stops it "mid-run" (0.01 s of the 30 s lock-step runs)
MID_RUN_STEP = 100


def recorded_past(bag, step, period=100_000):
    """Return True once the recording's ``.part`` on disk holds a measurement past ``step``."""
    from test_durable_recording import part_stamps
    stamps = part_stamps(partial_path(bag), T.MEAS_CURRENT)
    return bool(stamps) and max(stamps) > step * period


@pytest.mark.processes
@pytest.mark.slow
def test_four_processes_and_recorder_beside_a_busy_process_lose_nothing(tmp_path, domain):
    """
    Three short runs in a row, one CPU-bound process beside them.

    Every process exits 0 and the bag holds every step on every lock-step topic; the numbers
    equal the in-process graph's.
    """
    from im_recording.recorded_run import load_run
    from im_recording.report import figures_of_merit
    from im_bringup.testing import run_graph
    busy = subprocess.Popen([sys.executable, '-c', 'while True: pass'])
    try:
        for i in range(3):
            bag = tmp_path / f'run{i}.mcap'
            with GraphProcesses(graph_processes('position', 'min_energy', duration=0.2,
                                                record=bag), str(tmp_path / f'r{i}'),
                                domain) as g:
                codes = g.start().wait(120)
                no_traceback(g)
                assert_all_ended(g, codes)
            c = counts(bag)
            for topic in LOCKSTEP:
                expected = 2000 if topic == T.CMD_VOLTAGE else 2001      # steps 0..2000
                assert c[topic] == expected, (topic, c[topic])
            meta = info(bag).metadata['recording']
            assert meta['missing_steps'] == '0'
            assert missing_in_bag(bag) == {t: int(meta[f'missing_steps{t}']) for t in LOCKSTEP}
    finally:
        busy.kill()
    live = run_graph(task='position', strategy='min_energy', duration=0.2)
    fig = figures_of_merit(load_run(bag))
    for key in ('E_in_J', 'E_loss_J', 'pos_err_max_rad', 'V_max_V'):
        assert fig[key] == pytest.approx(live.summary[key], rel=1e-12), key


@pytest.mark.processes
@pytest.mark.slow
@pytest.mark.parametrize('target', ['all', 'controller', 'plant', 'recorder'])
def test_sigint_ends_every_process_cleanly(tmp_path, domain, target):
    """
    Ctrl-C on `ros2 launch` (SIGINT to all) or on one node.

    Every process exits 0, no traceback, and the recording is complete up to the stop (rosbags
    reads it).
    """
    bag = tmp_path / 'run.mcap'
    procs = graph_processes('position', 'min_energy', duration=30.0, record=bag)
    with GraphProcesses(procs, str(tmp_path), domain) as g:
        g.start()
        assert wait_for_log(g, 'plant', 'starting:'), g.log('plant')
        # mid-run: the recorder has put steps past MID_RUN_STEP on disk
        assert wait_until(lambda: recorded_past(bag, MID_RUN_STEP), 60, 0.2), g.log('recorder')
        g.send(signal.SIGINT, None if target == 'all' else [target])
        if target == 'recorder':        # off the critical path: the run goes on without it
            assert g.popen['recorder'].wait(30) == 0
            assert wait_for_log(g, 'plant', "follower 'recorder' stopping", 30), g.log('plant')
            assert all(p.poll() is None for n, p in g.popen.items() if n != 'recorder')
            g.send(signal.SIGINT)
        codes = g.wait(30)
        no_traceback(g)
        assert_all_ended(g, codes)
        if target == 'controller':
            assert 'controller stopping (SIGINT)' in g.log('plant')
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore
    with AnyReader([bag], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as ar:
        n = sum(1 for c, _, raw in ar.messages() if ar.deserialize(raw, c.msgtype))
    assert n > 100
    meta = info(bag).metadata['recording']
    assert meta['missing_steps'] == '0'
    if target in ('all', 'recorder'):
        assert meta['interrupted'] == 'SIGINT'
    else:
        assert meta['run_end'].startswith('stopped'), meta
    if target != 'recorder':            # the run's stop is in the bag, and nothing before it lacks
        end = plant_end(bag)
        assert end and end[0] == 'stopped', [(m.status[0].name, m.status[0].message)
                                             for _, m in _statuses(bag)]
        assert missing_in_bag(bag) == dict.fromkeys(LOCKSTEP, 0)


@pytest.mark.processes
@pytest.mark.slow
def test_killed_node_is_reported_and_nothing_hangs(tmp_path, domain):
    procs = graph_processes('position', 'min_energy', duration=30.0, input_timeout=1.0)
    with GraphProcesses(procs, str(tmp_path), domain) as g:
        g.start()
        assert wait_for_log(g, 'plant', 'starting:'), g.log('plant')     # mid-run from here
        g.send(signal.SIGKILL, ['observer'])
        codes = g.wait(30)
        assert None not in codes.values(), codes
        assert codes['observer'] == -signal.SIGKILL
        # the stall is diagnosed in one line by the first watchdog to fire: the plant's (1 s),
        # or, on a crowded machine where the plant's process ran less than the controller's
        # (the wait counts only the time a process ran), the controller's (2.5 s), whose
        # failure then ends the plant's part as its provider's
        plant, controller = g.log('plant'), g.log('controller')
        if codes['plant'] == 1:
            assert 'no /im/command/voltage stamped' in plant, plant
            assert codes['controller'] in (0, 1)
        else:
            assert codes['plant'] == 0 and "input provider 'controller' failed" in plant, plant
            assert codes['controller'] == 1, controller
            assert re.search(r'no [^\n]*/im/observer/flux[^\n]* stamped', controller), controller
        no_traceback(g)


@pytest.mark.processes
@pytest.mark.slow
def test_late_recorder_records_without_a_gap_from_where_it_joined(tmp_path, domain):
    """
    A recorder started while the run goes on.

    From the step the plant took it on as a lossless follower ("joined at step N" in the
    plant's log) every lock-step topic has every step to the end. Before that it has what the
    publishers' history still held when it matched; a step that was gone by then (on a loaded
    machine the plant may run more than the history ahead before it sees the recorder) is
    counted in the metadata exactly as the bag lacks it.
    """
    bag = tmp_path / 'late.mcap'
    procs = graph_processes('position', 'min_energy', duration=1.5)
    key = procs[0].parameters['graph_key_file']          # the recorder of this graph
    rec = graph_processes('position', 'min_energy', duration=1.5, record=bag, key_file=key)[-1]
    g = GraphProcesses(procs + [rec], str(tmp_path), domain)
    with g:
        g.start(only=['plant', 'controller', 'observer'])
        assert wait_for_log(g, 'plant', 'starting:'), g.log('plant')     # mid-run from here
        g.start_one('recorder')
        codes = g.wait(120)
        no_traceback(g)
        assert_all_ended(g, codes)
    joined = re.search(r"lossless follower 'recorder' joined at step (\d+)", g.log('plant'))
    assert joined, g.log('plant')[-2000:]
    n_join = int(joined.group(1))
    meta = info(bag).metadata['recording']
    last = {T.MEAS_CURRENT: 15000, T.MEAS_SHAFT: 15000, T.CMD_VOLTAGE: 14999, T.OBS_FLUX: 15000}
    first = {}
    for topic, k_last in last.items():
        steps = sorted(t // 100_000 for _, _, t, _ in iter_raw(bag, [topic]))
        assert steps[-1] == k_last, topic
        # lossless from the join on: every step to the end
        assert set(range(n_join, k_last + 1)) <= set(steps), (topic, n_join)
        first[topic] = steps[0]
    start = max(first.values())          # the first step every topic has
    joined = min(first.values())         # the step it joined: the earliest it has on any topic
    lacks = 0                            # per topic: from there to the end
    for topic, k_last in last.items():
        have = {t // 100_000 for _, _, t, _ in iter_raw(bag, [topic])}
        lacks += len(set(range(joined, k_last + 1)) - have)
    counts = {k: v for k, v in meta.items() if k.startswith(('missing', 'last', 'joined'))}
    assert int(meta['missing_steps']) == lacks, counts
    assert meta.get('joined_at_step') == str(joined) or joined == 0, counts
    # the reports too, from the first step every lock-step topic has: their writers keep their
    # last samples (lockstep.report_qos) as the lock-step writers do, so the recorder matched late
    # gets those of the steps before it (before: volatile, they began where it matched)
    for topic in REPORTS:
        have = {t for _, _, t, _ in iter_raw(bag, [topic])}
        want = {t for t in report_stamps(topic, procs, bag, 100_000) if t >= start * 100_000}
        assert want <= have, (topic, start, sorted(want - have)[:5])


@pytest.mark.processes
@pytest.mark.slow
def test_free_run_closes_the_loop_in_wall_clock_time(tmp_path, domain, free_run_rate):
    """
    free_run at the rate this machine holds (1 kHz on most) with the gains certified for it.

    The plant starts after discovery, runs on the wall clock (never faster than real time),
    applies the commands that arrive by their deadline and accounts for every step and every
    command's latency — in its final log line whether the run reached its end or the protection
    tripped because this machine could not keep the deadlines (how many it meets is a benchmark
    figure: benchmarks/bench_processes.py).
    """
    if free_run_refused(free_run_rate, tmp_path, domain):
        return
    T_s = 1.0 / free_run_rate
    procs = graph_processes('position', 'min_energy', duration=1.0, **_free_run_kw(free_run_rate))
    with GraphProcesses(procs, str(tmp_path), domain) as g:
        g.start()
        assert wait_for_log(g, 'plant', 'starting:'), g.log('plant')
        t0 = time.monotonic()
        codes = g.wait(120)
        wall = time.monotonic() - t0
        no_traceback(g)
    plant = g.log('plant')
    assert 'arrived before the run started' not in plant
    m = re.search(r'free_run \((.*?) scheduling\): (\d+) of (\d+) steps without a command by '
                  r'their deadline .*?(\d+) late, (\d+) plant overruns; latency mean (\d+) µs.*?'
                  r'\((\d+) samples', plant)
    assert m, plant
    scheduling = m.group(1)      # real-time when this user may (root, CAP_SYS_NICE, rtprio)
    assert scheduling.startswith('fifo:') or scheduling == 'normal (refused)', scheduling
    missed, steps, late, _, _, samples = (int(x) for x in m.groups()[1:])
    if codes['plant'] == 0:
        assert steps == free_run_rate
    else:       # the protection (or the deadline watchdog) stopped a loop that missed
        assert codes['plant'] == 1 and 'protection trip' in plant, plant
    assert samples > 0 and abs(samples - (steps - missed + late)) <= 2  # every command counted
    assert wall >= 0.9 * steps * T_s                                # paced by the wall clock
    assert codes['controller'] == 0 and codes['observer'] == 0


def _statuses(bag):
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.serialization import deserialize_message
    return [(t, deserialize_message(bytes(raw), DiagnosticArray))
            for _, _, t, raw in iter_raw(bag, [T.STATUS])]


@pytest.mark.processes
def _set_live(procs, tmp_path, domain, target: str, name: str, values) -> list:
    """
    Run ``procs`` and set ``target``'s parameter ``name`` to each of ``values`` while it runs.

    As ``ros2 param set`` does (the node's set_parameters service); returns each SetParameters
    result; every process must then finish with exit code 0 and no traceback.
    """
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter
    from rcl_interfaces.srv import SetParameters
    ctx = Context()
    rclpy.init(context=ctx, domain_id=int(domain['ROS_DOMAIN_ID']))
    try:
        node = rclpy.create_node('operator', context=ctx)
        ex = SingleThreadedExecutor(context=ctx)
        ex.add_node(node)
        cli = node.create_client(SetParameters, f'/{target}/set_parameters')
        results = []
        with GraphProcesses(procs, str(tmp_path), domain) as g:
            g.start()
            assert wait_for_log(g, 'plant', 'starting:'), g.log('plant')
            assert cli.wait_for_service(timeout_sec=20)
            for value in values:
                req = SetParameters.Request(
                    parameters=[Parameter(name, value=value).to_parameter_msg()])
                fut = cli.call_async(req)
                ex.spin_until_future_complete(fut, timeout_sec=20)
                results.append(fut.result().results[0])
            codes = g.wait(120)
            assert_all_ended(g, codes)
            no_traceback(g)
        node.destroy_node()
    finally:
        rclpy.shutdown(context=ctx)
    return results


@pytest.mark.slow
def test_live_parameter_is_validated_applied_and_recorded(tmp_path, domain):
    """
    `ros2 param set /controller k1 ...` on a running controller process.

    An invalid value is refused with a reason, a valid one is applied at a step boundary and
    recorded.
    """
    bag = tmp_path / 'live.mcap'
    procs = graph_processes('position', 'min_energy', duration=2.0, record=bag)
    bad, good = _set_live(procs, tmp_path, domain, 'controller', 'k1', (-5.0, 30.0))
    assert not bad.successful and 'k1' in bad.reason
    assert good.successful
    events = [m.status[0] for t, m in _statuses(bag) if m.status[0].message == 'parameters']
    assert events and events[0].name == 'controller'
    assert {kv.key: kv.value for kv in events[0].values}['k1'] == '30.0'


@pytest.mark.processes
@pytest.mark.slow
def test_the_live_load_offset_of_a_plant_process_is_applied_at_a_step_and_recorded(
        tmp_path, domain):
    """
    `ros2 param set /plant load_offset 3.0` on a running plant process (docs/running.md, Loads).

    An out-of-range value is refused naming it; a valid one is announced as a `parameters` event
    with its step, and the recorded true load torque is the load's own before that step and 3 N·m
    more after it.
    """
    from im_bringup.run_file import Scenario
    from im_common.loads import ConstantLoad
    bag = tmp_path / 'load.mcap'
    sc = Scenario(task='speed', duration=2.0, load_model=ConstantLoad(1.0))
    procs = graph_processes(scenario=sc, record=bag)
    bad, good = _set_live(procs, tmp_path, domain, 'plant', 'load_offset', (1e6, 3.0))
    assert not bad.successful and 'load_offset' in bad.reason
    assert good.successful
    events = [(t, m.status[0]) for t, m in _statuses(bag) if m.status[0].message == 'parameters']
    assert len(events) == 1 and events[0][1].name == 'plant'
    values = {kv.key: kv.value for kv in events[0][1].values}
    k = int(values['step'])
    assert values['load_offset'] == '3.0' and 0 < k < 20000
    from im_common.cdr import decode_vector3_stamped, NS_PER_S
    tau = {}
    for _, _, t, raw in iter_raw(bag, [T.TRUTH_TORQUE]):
        sec, nsec, _tau_m, tau_l, _friction = decode_vector3_stamped(bytes(raw))
        tau[(sec * NS_PER_S + nsec) // 100_000] = tau_l
    assert all(v == 1.0 for j, v in tau.items() if j < k)
    assert all(v == 4.0 for j, v in tau.items() if j > k) and any(j > k for j in tau)


@pytest.mark.processes
@pytest.mark.slow
def test_second_graph_on_the_same_domain_is_refused_by_name(tmp_path, domain):
    """
    Two graphs with the same key on one ROS_DOMAIN_ID (nodes started by hand share the user's key).

    Nodes could not tell which run to follow, so the second plant refuses to start and says so;
    the first run is not disturbed.
    """
    first = graph_processes('position', 'min_energy', duration=30.0)
    key = first[0].parameters['graph_key_file']
    second = graph_processes('position', 'min_energy', duration=30.0, key_file=key)[0]
    second.name, second.parameters = 'plant2', dict(second.parameters, wait_for='')
    with GraphProcesses(first + [second], str(tmp_path), domain) as g:
        g.start(only=['plant', 'controller', 'observer'])
        assert wait_for_log(g, 'plant', 'starting:'), g.log('plant')
        g.start_one('plant2')
        assert g.popen['plant2'].wait(60) == 1
        assert 'ROS_DOMAIN_ID' in g.log('plant2') and "another plant ('plant'" in g.log('plant2')
        # not disturbed: an absence has no event to wait on, so the first graph is given a
        # second (its nodes hear plant2's last status within it) to show it goes on
        time.sleep(1.0)
        assert all(g.popen[n].poll() is None for n in ('plant', 'controller', 'observer'))
        codes = g.stop()
        no_traceback(g)
        assert codes == dict.fromkeys(('plant', 'controller', 'observer'), 0) | {'plant2': 1}


@pytest.mark.processes
@pytest.mark.slow
def test_two_graphs_with_their_own_keys_share_a_domain_without_crosstalk(tmp_path, domain):
    """
    Each launch makes its own key.

    Two graphs on one ROS_DOMAIN_ID refuse each other's messages (and say so) and both compute
    exactly what they compute alone.
    """
    from im_recording.recorded_run import load_run
    from im_recording.report import figures_of_merit
    from im_bringup.testing import run_graph
    bags = [tmp_path / 'a.mcap', tmp_path / 'b.mcap']
    a = graph_processes('position', 'min_energy', duration=0.1, record=bags[0])
    b = graph_processes('position', 'min_energy', duration=0.1, record=bags[1])
    for p in b:
        p.name += '_b'
    for p in b:
        if p.name == 'plant_b':
            p.parameters['wait_for'] = ' '.join(n + '_b' for n in p.parameters['wait_for'].split())
    with GraphProcesses(a + b, str(tmp_path), domain) as g:
        codes = g.start().wait(180)
        no_traceback(g)
        assert_all_ended(g, codes)
    assert 'not signed by this graph' in g.log('controller') + g.log('observer')
    live = run_graph(task='position', strategy='min_energy', duration=0.1)
    for bag in bags:
        fig = figures_of_merit(load_run(str(bag)))
        for key in ('E_in_J', 'pos_err_max_rad', 'V_max_V'):
            assert fig[key] == pytest.approx(live.summary[key], rel=1e-12), (bag, key)


def _free_run_kw(rate, force=True):
    """
    Return graph_processes' free_run arguments at ``rate`` [Hz], with its certified gains.

    ``force``: past the plant's own probe — the session's probe (``free_run_rate``) chose the rate
    once, beside a busy process; a second probe near the budget's edge would decide again (seen:
    p99 472 µs beside a busy process, then 513 µs at the test's own start, budget 500 µs). The
    deadline watchdog still stops a loop that misses.
    """
    from im_bringup.processes import free_run_gains, load_params_yaml
    extra = load_params_yaml(free_run_gains(1.0 / rate))
    if force:
        extra['plant'] = {'force_rate': True}
    return {'T_s': 1.0 / rate, 'mode': 'free_run', 'extra': extra}


def free_run_refused(rate, tmp_path, domain):
    """
    On a machine that holds no free_run rate, check the plant's refusal and return True.

    The session's probe (``free_run_rate``) ran the processes at 250 Hz last: the plant refused
    before step 0 with the one line naming the measured latency, the period and the rate held.
    """
    if rate is not None:
        return False
    from conftest import FREE_RUN_REFUSAL
    log = FREE_RUN_REFUSAL[-1]
    assert 'starting:' not in log, log
    assert 'free_run at 250 Hz: measured loop latency' in log and 'cannot hold it' in log, log
    assert 'refusing to start (the plant parameter force_rate: true starts anyway)' in log, log
    return True


#: the lock-step pair's run: 5,000 steps a graph, still many seconds after the second starts (a
#: graph's processes start in 1-3 s; the pair steps at 1-5 ms)
LOCKSTEP_PAIR_S = 0.5


@pytest.mark.processes
@pytest.mark.slow
@pytest.mark.parametrize('mode', ['lockstep', 'free_run'])
def test_two_launches_on_one_domain_both_finish_as_alone(tmp_path, domain, mode, free_run_rate):
    """
    Check two launches on one ROS_DOMAIN_ID, the second started during the first.

    Two launches (each its own key, the same node names) on one ROS_DOMAIN_ID, the second started
    while the first runs: both finish (exit 0), each bag's missing count is what it lacks, and in
    lock-step each records every step and computes exactly what it computes alone (in free_run,
    before, one lost message of a step deadlocked both loops: 100 % of deadlines missed, no
    command recorded). Before, each node asked the graph API
    for every message of the other graph it refused, fell behind the other graph's flood, its
    reader history lost its own graph's step and that plant stopped ("no /im/command/voltage
    stamped 0.468 s ... within 5.0 s").
    """
    from im_recording.recorded_run import load_run
    from im_recording.report import figures_of_merit
    from im_bringup.testing import run_graph
    if mode == 'free_run' and free_run_refused(free_run_rate, tmp_path, domain):
        return
    bags = [tmp_path / 'a.mcap', tmp_path / 'b.mcap']
    # free_run: not forced past the plants' own probes — a second graph on the machine is load the
    # session's probe did not see. A rate the machine does not hold here is refused before step 0
    # or stopped by the deadline watchdog, loudly; the pair then runs again at the next lower rate
    rates = [1000] if mode == 'lockstep' else [r for r in FREE_RUN_RATES if r <= free_run_rate]
    for rate in rates:
        kw = ({'duration': LOCKSTEP_PAIR_S} if mode == 'lockstep' else
              dict(duration=2.0, **_free_run_kw(rate, force=False)))
        a = graph_processes('position', 'min_energy', record=bags[0], **kw)
        b = graph_processes('position', 'min_energy', record=bags[1], **kw)
        ga = GraphProcesses(a, str(tmp_path / f'a{rate}'), domain)
        gb = GraphProcesses(b, str(tmp_path / f'b{rate}'), domain)     # the same names
        with ga, gb:
            ga.start()
            # b starts while a runs: a's plant has started (a free_run lasts 2 s of wall time)
            started = wait_for_log(ga, 'plant', 'starting:')
            assert started or mode == 'free_run', ga.log('plant')
            gb.start()
            codes = [ga.wait(300), gb.wait(300)]
            for g in (ga, gb):
                no_traceback(g)
        held = all(c == dict.fromkeys(c, 0) for c in codes)
        if held or mode == 'lockstep':
            break
        for g, c in zip((ga, gb), codes):       # not held: said so, by the plant, loudly
            if c != dict.fromkeys(c, 0):
                plant = g.log('plant')
                assert c['plant'] == 1 and ('cannot hold it' in plant or
                                            'protection trip' in plant), {
                    n: g.log(n)[-1500:] for n in c}
        for bag in bags:
            bag.unlink(missing_ok=True)
    else:
        return      # no rate held with two graphs on this machine: each refusal checked above
    free_run_rate = rate
    for g, c in zip((ga, gb), codes):
        assert c == dict.fromkeys(c, 0), {n: g.log(n)[-1500:] for n in c}
        assert 'reached duration' in g.log('plant')
    if mode == 'lockstep':      # a free_run may end before b's nodes speak: no overlap to see
        assert 'not signed by this graph' in ''.join(g.log(n) for g in (ga, gb)
                                                     for n in ('controller', 'observer', 'plant'))
    period = 100_000 if mode == 'lockstep' else round(1e9 / free_run_rate)
    for bag in bags:
        meta = info(bag).metadata['recording']
        missing = missing_in_bag(bag, period)
        if mode == 'lockstep':      # the plant waits for its recorder: nothing may be missing
            assert missing[T.MEAS_CURRENT] == missing[T.MEAS_SHAFT] == 0, (bag, missing)
        # free_run: two graphs at 1 kHz, SCHED_FIFO 50, fill a 2-core machine and their recorders
        # run below them (fifo:40) — a recording may lack steps, but never silently: what the
        # bag lacks is exactly what its metadata reports missing
        assert missing == {t: int(meta[f'missing_steps{t}']) for t in LOCKSTEP}, (bag, meta)
    refused_reports = 0
    for bag, procs in zip(bags, (a, b)):
        # every signed report topic holds what its graph alone publishes, each stamp once (before:
        # a free_run bag held both graphs' ground truth, 391 /im/truth/voltage where one gives
        # 201); the other graph's reports are kept apart, counted in the metadata
        meta = info(bag).metadata['recording']
        n = counts(bag)
        for topic in REPORTS:
            stamps = [t for _, _, t, _ in iter_raw(bag, [topic])]
            assert len(stamps) == len(set(stamps)), (bag, topic, len(stamps), len(set(stamps)))
            # the observer's î_0 too: it goes out when the run starts running, when the recorder
            # follows the run (it was missing from a free_run bag)
            expected = report_stamps(topic, procs, bag, period)
            if mode == 'lockstep':
                assert set(stamps) == expected, (bag, topic)
            else:   # a command or flux the bag lacks (reported missing) may have its report
                assert expected <= set(stamps) <= report_stamps(topic, procs, bag, period,
                                                                grid=True), (bag, topic)
            refused = n.get(T.REFUSED_PREFIX + topic, 0)
            assert refused == int(meta.get(f'refused_unsigned{topic}', 0)), (bag, topic, meta)
            refused_reports += refused
    if mode == 'lockstep':      # the runs overlap (b started once a's plant had): reports refused
        assert refused_reports > 0
    if mode == 'lockstep':
        live = run_graph(task='position', strategy='min_energy', duration=LOCKSTEP_PAIR_S)
        for bag in bags:
            fig = figures_of_merit(load_run(str(bag)))
            for key in ('E_in_J', 'pos_err_max_rad', 'V_max_V'):
                assert fig[key] == pytest.approx(live.summary[key], rel=1e-12), (bag, key)


@pytest.mark.processes
@pytest.mark.slow
def test_free_run_recording_beside_a_busy_process_holds_every_step(tmp_path, domain,
                                                                   free_run_rate):
    """
    free_run for 2 s with the recorder and a CPU-bound process beside the graph.

    At the rate the machine holds beside a busy process (1 kHz on most).

    The plant cannot wait for the recorder, yet the bag holds the measurements of every step
    the plant integrated and its final event, and the metadata's missing count is what the bag
    lacks (before: the niced recorder was starved — 10 s runs lost 19-22 % of the steps and the
    plant's `finished`).
    """
    if free_run_refused(free_run_rate, tmp_path, domain):
        return
    bag = tmp_path / 'free.mcap'
    procs = graph_processes('position', 'min_energy', duration=2.0, record=bag,
                            **_free_run_kw(free_run_rate))
    busy = subprocess.Popen([sys.executable, '-c', 'while True: pass'])
    try:
        with GraphProcesses(procs, str(tmp_path), domain) as g:
            codes = g.start().wait(120)
            no_traceback(g)
    finally:
        busy.kill()
    assert codes['recorder'] == 0 and codes['controller'] == 0, codes
    state, step, _ = plant_end(bag)
    assert step == 2 * free_run_rate if state == 'finished' else codes['plant'] == 1
    period = round(1e9 / free_run_rate)
    missing = missing_in_bag(bag, period)
    assert missing[T.MEAS_CURRENT] == missing[T.MEAS_SHAFT] == 0, missing
    meta = info(bag).metadata['recording']
    assert missing == {t: int(meta[f'missing_steps{t}']) for t in LOCKSTEP}, meta
    # the voltage applied over [t_k-1, t_k] (the truth stamped t_k) is the command stamped t_k-1,
    # unless that command missed its deadline (the one before is held): no more samples differ
    # than steps missed (a plant that filed each command one step late passed every check above)
    from im_common.conversions import xy_in
    cmd = {t: xy_in(bytes(raw))[1] for _, _, t, raw in iter_raw(bag, [T.CMD_VOLTAGE])}
    applied = {t: xy_in(bytes(raw))[1] for _, _, t, raw in iter_raw(bag, [T.TRUTH_VOLTAGE])}
    pairs = [(applied[t], cmd[t - period]) for t in applied if t - period in cmd]
    assert len(pairs) >= 0.5 * len(applied), (len(pairs), len(applied))
    differ = sum(v != c for v, c in pairs)
    assert differ <= int(plant_end(bag)[2]['missed']), (differ, len(pairs))


@pytest.mark.processes
@pytest.mark.slow
def test_scenario_runs_as_separate_processes(tmp_path):
    """
    ``scenario --processes``.

    The same numbers as the in-process scenario, from the recorder's bag; every process exits
    0; logs next to the recording.
    """
    import json

    from im_bringup.processes import executable_path
    from im_bringup.testing import run_graph
    bag = tmp_path / 'p.mcap'
    r = subprocess.run([executable_path('im_bringup', 'scenario'), '--processes', '--duration',
                        '0.1', '--record', str(bag), '--no-progress'], capture_output=True,
                       text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    s = json.loads((tmp_path / 'p.json').read_text())
    assert s['ok'] and set(s['processes']) == {'plant', 'controller', 'observer', 'recorder'}
    assert (tmp_path / 'p_logs' / 'plant.log').exists()
    live = run_graph(task='position', strategy='min_energy', duration=0.1)
    for key in ('E_in_J', 'pos_err_max_rad', 'V_max_V'):
        assert s[key] == pytest.approx(live.summary[key], rel=1e-12), key
    # one step count on both paths: the steps the plant integrated, 0.1 s / 100 µs
    assert s['steps'] == live.summary['steps'] == 1000
    r2 = subprocess.run([executable_path('im_bringup', 'scenario'), '--processes', '--duration',
                         '0.1'], capture_output=True, text=True, timeout=60)
    assert r2.returncode == 2 and r2.stderr.strip() == \
        'scenario: error: --processes needs --record (the figures come from the recording)'


@pytest.mark.processes
@pytest.mark.slow
@pytest.mark.parametrize('target', ['observer', 'scenario'])
def test_scenario_processes_stopped_by_one_node_is_partial_and_ctrl_c_is_an_interrupt(
        tmp_path, target):
    """
    ``scenario --processes`` stopped mid-run: by a Ctrl-C to one node, or to itself.

    A node that stopped the run (every process still exits 0) makes it partial: one
    ``scenario: error: the run stopped early: …`` line naming the node, exit 1, the summary
    partial. A Ctrl-C to ``scenario`` is the user's stop, as in one process: the shell's code
    (130) and the summary ``interrupted``. Either way the recording holds the run up to there.
    """
    import json

    from im_bringup.processes import executable_path
    bag = tmp_path / 's.mcap'
    proc = subprocess.Popen([executable_path('im_bringup', 'scenario'), '--processes',
                             '--task', 'speed', '--duration', '30', '--record', str(bag),
                             '--no-progress'], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    try:
        assert wait_until(lambda: recorded_past(bag, MID_RUN_STEP) or proc.poll() is not None,
                          120, 0.2) and proc.poll() is None
        if target == 'scenario':
            proc.send_signal(signal.SIGINT)
        else:
            logs = tmp_path / 's_logs'
            pid = [line.split()[0] for line in subprocess.run(
                ['pgrep', '-af', '__node:=observer'], capture_output=True, text=True
            ).stdout.splitlines() if f'--params-file {logs}' in line]
            assert len(pid) == 1, pid
            os.kill(int(pid[0]), signal.SIGINT)
        out, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    s = json.loads((tmp_path / 's.json').read_text())
    assert set(s['processes'].values()) == {0} and s['partial'] is True
    assert 0 < s['steps'] < 300_000
    assert 'Traceback' not in err
    if target == 'scenario':
        assert proc.returncode == 128 + signal.SIGINT, err[-2000:]
        assert s['interrupted'] == 'SIGINT'
    else:
        assert proc.returncode == 1, err[-2000:]
        line, = [x for x in err.splitlines() if x.startswith('scenario: error:')]
        assert line.startswith('scenario: error: the run stopped early: ')
        assert 'plant stopped at t = ' in line and 'observer stopping (SIGINT)' in line
        assert s['ok'] is False
    assert info(bag).metadata['recording']['missing_steps'] == '0'


@pytest.mark.processes
@pytest.mark.slow
def test_a_loaded_machine_makes_runs_slow_not_wrong(tmp_path, domain):
    """
    Two CPU-bound processes beside the graph: five runs in one process, five as processes.

    Every run finishes with the numbers of the same run on a quiet machine (lock-step: stamps
    decide, not scheduling). The input watchdogs count only the time their process ran
    (``im_common.lockstep_protocol.WaitClock``): before, a run in one process on a machine at load
    13-33 stopped with "no /im/command/voltage stamped 0.114 s (step 1140) within 5.0 s of wall
    time" — the command was not lost, its delivery had not been scheduled yet.
    """
    from im_recording.report import figures_of_merit
    from im_recording.recorded_run import load_run
    from im_bringup.testing import run_graph
    quiet = run_graph(task='position', strategy='min_energy', duration=0.1).summary
    busy = [subprocess.Popen([sys.executable, '-c', 'while True: pass']) for _ in range(2)]
    try:
        for i in range(5):
            s = run_graph(task='position', strategy='min_energy', duration=0.1).summary
            assert s['ok'], (i, s['failures'])
            assert s['E_in_J'] == quiet['E_in_J'], i
        for i in range(5):
            bag = tmp_path / f'p{i}.mcap'
            procs = graph_processes('position', 'min_energy', duration=0.1, record=bag)
            with GraphProcesses(procs, str(tmp_path / f'p{i}'), domain) as g:
                codes = g.start().wait(180)
                no_traceback(g)
            assert_all_ended(g, codes)
            assert figures_of_merit(load_run(str(bag)))['E_in_J'] == pytest.approx(
                quiet['E_in_J'], rel=1e-12), i
    finally:
        for b in busy:
            b.kill()
