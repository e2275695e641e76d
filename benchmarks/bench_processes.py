"""
The graph as separate processes (how users run it), next to its yardstick in the same run.

1. Two-process rclpy ping-pong (EventsExecutor on both sides, lock-step QoS, serialized
   Vector3Stamped): round trips/s — the fastest a two-hop-per-step loop across processes can go.
2. Four processes in lock-step (plant, controller, observer, + the recorder as a lossless
   follower, started by :class:`im_bringup.processes.GraphProcesses` the way the launch file
   starts them): steps/s reported by the plant, and the ratio to the ping-pong (target >= 0.8).
   Next to it, the CPU both loops burn: the lock-step processes' CPU time per step (all of them
   together, start-up excluded: a short and a full run, differenced) and the ping-pong's per round
   trip, the step's CPU in ping-pong deliveries (one publish and its take: half a round trip) —
   the protocol delivers seven lock-step messages a step (plant 1, controller 3, observer 3) — and
   the rate the processes could reach if that CPU were spread perfectly over this machine's cores
   (``lockstep_processes_cpu_ceiling_vs_ping_pong``): a ratio above it needs less CPU per step,
   not better scheduling. Each process's CPU per step (``..._cpu_us_per_step_plant`` ...) and the
   rate if the plant's and the controller's CPU of a step came one after the other
   (:func:`serial_chain`); the cores other jobs kept busy during the run beside them.
3. free_run at 1 kHz (T_s = 1 ms, the certified gains of ``config/gains_1ms.yaml``), position
   task, 2 s: fraction of steps whose command missed its deadline, latency quantiles, position
   error, against the lock-step run at the same period and gains (in-process); beside a CPU-bound
   process, five runs of 10 s, the worst one reported (issue 25: <= 1 % missed in every one).
4. free_run recording completeness (``python benchmarks/bench_processes.py --free-run-record 10
   [--busy] [--runs N]``; in ``make bench`` the 2 s runs of 3.): the fraction of the steps the
   plant integrated whose measurements are in the recorder's bag, and of the commands the plant
   received, next to the missed-deadline fraction of the same run.
5. ``four_processes_over_cpu_ceiling`` alone (``python benchmarks/bench_processes.py --key
   [--runs N]``, about 20 s a run): the ping-pong and the lock-step pair of 2., one line a run
   with the key, steps/s and each process's CPU per step (docs/benchmarks.md, 2026-12-04).
"""
from __future__ import annotations

import functools
import math
import os
import random
import re
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from typing import Optional

HERE = os.path.dirname(os.path.abspath(__file__))


def _pong_main() -> None:
    """Child process: answer every /bench/ping with the same bytes on /bench/pong."""
    import rclpy
    from geometry_msgs.msg import Vector3Stamped
    from rclpy.node import Node

    from im_common.lockstep import lockstep_qos, make_executor
    rclpy.init()
    node = Node('bench_pong')
    pub = node.create_publisher(Vector3Stamped, '/bench/pong', lockstep_qos())
    node.create_subscription(Vector3Stamped, '/bench/ping', pub.publish, lockstep_qos(), raw=True)
    ex = make_executor()
    ex.add_node(node)
    t_end = time.monotonic() + 120
    while time.monotonic() < t_end and rclpy.ok():
        ex.spin_once(timeout_sec=0.1)


def _children_cpu_s() -> float:
    """Return the CPU time [s] (user + system) of this process's children that have ended."""
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def _process_cpu_s(pid: int) -> float:
    """Return the CPU time [s] (user + system) a running process has used so far."""
    with open(f'/proc/{pid}/stat') as f:
        fields = f.read().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def ping_pong_processes(n: int = 5000, cpu: Optional[list] = None) -> float:
    """
    Round trips per second between two processes.

    ``cpu``: the CPU time of both processes over the round trips [s] is appended to it.
    """
    import rclpy
    from geometry_msgs.msg import Vector3Stamped
    from rclpy.context import Context
    from rclpy.node import Node

    from im_common.conversions import Vector3Out
    from im_common.lockstep import lockstep_qos, make_executor
    domain = random.randint(150, 229)
    child = subprocess.Popen([sys.executable, os.path.abspath(__file__), '--pong'],
                             env=dict(os.environ, ROS_DOMAIN_ID=str(domain)))
    ctx = Context()
    rclpy.init(context=ctx, domain_id=domain)
    try:
        node = Node('bench_ping', context=ctx)
        pub = node.create_publisher(Vector3Stamped, '/bench/ping', lockstep_qos())
        count = [0]
        data = Vector3Out().fill(0, 1.0, 2.0)

        def on_pong(_msg):
            count[0] += 1
            if count[0] < n:
                pub.publish(data)
        node.create_subscription(Vector3Stamped, '/bench/pong', on_pong, lockstep_qos(), raw=True)
        ex = make_executor(ctx)
        ex.add_node(node)
        t_wait = time.monotonic() + 30
        while (pub.get_subscription_count() < 1 or node.count_publishers('/bench/pong') < 1) \
                and time.monotonic() < t_wait:
            ex.spin_once(timeout_sec=0.01)
        time.sleep(0.5)
        c0 = time.process_time() + _process_cpu_s(child.pid)
        t0 = time.perf_counter()
        pub.publish(data)
        while count[0] < n and time.perf_counter() - t0 < 60:
            ex.spin_once(timeout_sec=0.05)
        dt = time.perf_counter() - t0
        if cpu is not None:
            cpu.append(time.process_time() + _process_cpu_s(child.pid) - c0)
        ex.shutdown()
        node.destroy_node()
        return count[0] / dt
    finally:
        rclpy.try_shutdown(context=ctx)
        child.kill()
        child.wait()


def _machine_busy_s() -> float:
    """Return the CPU time [s] every process of this machine has used so far (/proc/stat)."""
    with open('/proc/stat') as f:
        ticks = [int(v) for v in f.readline().split()[1:]]
    idle = ticks[3] + ticks[4]                  # idle, iowait
    return (sum(ticks[:8]) - idle) / os.sysconf('SC_CLK_TCK')


def _wait_each(g, timeout: float, cpu_by_name: dict) -> dict:
    """
    Wait for the graph's processes like ``GraphProcesses.wait``; each one's CPU time [s] too.

    Each is reaped with ``os.wait4``, which returns its own resource usage (user + system).
    """
    deadline = time.monotonic() + timeout
    left = dict(g.popen)
    while left and time.monotonic() < deadline:
        for name, proc in list(left.items()):
            pid, status, usage = os.wait4(proc.pid, os.WNOHANG)
            if pid:
                proc.returncode = os.waitstatus_to_exitcode(status)
                cpu_by_name[name] = usage.ru_utime + usage.ru_stime
                del left[name]
        time.sleep(0.01)
    return g.returncodes()


def _run_graph_processes(procs, tag: str, plant_may_fail: bool = False,
                         cpu_by_name: Optional[dict] = None) -> str:
    """
    Run the processes (logs in a temporary folder, removed after); the plant's log.

    ``cpu_by_name``: each process's CPU time [s], start-up included, goes into it.
    """
    from im_bringup.processes import GraphProcesses
    tmp = tempfile.mkdtemp(prefix=f'bench_{tag}_')
    env = {'ROS_DOMAIN_ID': str(random.randint(150, 229))}
    try:
        with GraphProcesses(procs, tmp, env) as g:
            g.start()
            codes = g.wait(600) if cpu_by_name is None else _wait_each(g, 600, cpu_by_name)
            bad = {n: c for n, c in codes.items()
                   if c != 0 and not (plant_may_fail and n == 'plant')}
            if bad:
                raise RuntimeError(f'{tag}: exit codes {codes}\n' + g.log('plant')[-2000:])
            return g.log('plant')
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def lockstep_processes(duration: float, record: bool, cpu: Optional[list] = None,
                       cpu_by_name: Optional[dict] = None,
                       others: Optional[list] = None, delay: Optional[int] = None,
                       overlap: bool = True) -> float:
    """
    Steps/s of the position task in lock-step as the plant reports it.

    ``cpu``: the CPU time all the processes used [s], start-up included, is appended to it;
    ``cpu_by_name``: each one's (plant, controller, observer ...); ``others``: the cores the
    rest of the machine kept busy meanwhile (its CPU time over the wall time) is appended.
    ``delay``: the run file's ``inverter: {delay: d}`` (the ideal plant, d periods late; None:
    no inverter block), ``overlap``: the nodes' parameter (the delayed step overlapped).
    """
    from im_bringup.processes import graph_processes
    from im_bringup.run_file import Scenario
    tmp = tempfile.mkdtemp(prefix='bench_bag_')
    c0, busy0, t0 = _children_cpu_s(), _machine_busy_s(), time.monotonic()
    try:
        bag = os.path.join(tmp, 'run.mcap') if record else None
        if delay is None:
            procs = graph_processes('position', 'min_energy', duration=duration, record=bag)
        else:
            sc = Scenario(task='position', strategy='min_energy', duration=duration,
                          inverter={'delay': delay})
            procs = graph_processes(scenario=sc, record=bag, extra={
                n: {'overlap': overlap} for n in ('plant', 'observer', 'adapter')})
        log = _run_graph_processes(procs, 'lockstep', cpu_by_name=cpu_by_name)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    ours = _children_cpu_s() - c0
    if cpu is not None:
        cpu.append(ours)
    if others is not None:
        others.append(max(_machine_busy_s() - busy0 - ours, 0.0) / (time.monotonic() - t0))
    m = re.search(r'\((\d+) steps/s\)', log)
    if m is None:
        raise RuntimeError(f"lockstep: no steps/s in the plant's log: {log[-500:]}")
    return float(m.group(1))


def serial_chain(by_short: dict, by_full: dict, extra_steps: int, res: dict) -> dict:
    """
    Each lock-step process's CPU per step, and the rate if the plant and controller took turns.

    A step is a chain across processes: the plant takes V_k, integrates and publishes the
    measurement; the controller takes it (and the observer's x̂_k, computed meanwhile) and
    publishes V_k+1; the observer runs beside the chain. If the plant's and the controller's CPU
    of a step came one after the other whole, a step would last their sum
    (``lockstep_processes_serial_us_per_step``); ``..._serial_rate_vs_ping_pong`` is that rate
    (or the CPU ceiling's, if lower) over the ping-pong's. Not a bound: part of the controller's
    CPU (taking the observer's estimate, its references) overlaps the plant's, so a run can come
    out above it (docs/benchmarks.md times the chain inside the processes).
    """
    per = {name: 1e6 * (by_full[name] - by_short.get(name, 0.0)) / extra_steps
           for name in sorted(by_full)}
    out = {f'lockstep_processes_cpu_us_per_step_{name}': v for name, v in per.items()}
    serial = per['plant'] + per['controller']
    out['lockstep_processes_serial_us_per_step'] = serial
    rate = min(res['cores'] * 1e6 / res['lockstep_processes_cpu_us_per_step'],
               1e6 / serial if serial > 0 else math.inf)
    out['lockstep_processes_serial_rate_vs_ping_pong'] = (
        rate / res['ping_pong_two_processes_round_trips_per_s'])
    return out


def per_step_cpu(d: float, **run) -> tuple:
    """
    Run ``d`` / 4 and ``d`` [s] of :func:`lockstep_processes` (``run``): steps/s, CPU per step.

    The CPU per step [µs] of each process and of all of them, the start-up differenced out (the
    full run's steps beyond the short run's, T_s 100 µs).
    """
    by_short, by_full, cpu_short, cpu_full = {}, {}, [], []
    lockstep_processes(d / 4, record=False, cpu=cpu_short, cpu_by_name=by_short, **run)
    rate = lockstep_processes(d, record=False, cpu=cpu_full, cpu_by_name=by_full, **run)
    extra_steps = round(d / 1e-4) - round(d / 4 / 1e-4)
    per = {name: 1e6 * (by_full[name] - by_short.get(name, 0.0)) / extra_steps
           for name in sorted(by_full)}
    per['all'] = 1e6 * (cpu_full[0] - cpu_short[0]) / extra_steps
    return rate, per


def delay_overlap(d: float) -> dict:
    """
    Measure the delayed step overlapped: steps/s with ``delay: 1`` over ``delay: 0``, ceiling.

    With a computational delay of one period the plant integrates step k, and the observer
    predicts step k + 1, while the controller computes the command of step k (docs/architecture.md,
    "The delayed step overlapped"); without it a step is the plant's and the controller's CPU one
    after the other. Three runs of the position task through :func:`lockstep_processes`, each a
    short and a full one for the CPU per step: no delay (``inverter: {delay: 0}``), one period
    overlapped, one period in the serial order (``overlap: false``, the nodes' parameter).

    ``four_processes_delay1_over_delay0``: steps/s overlapped over steps/s without the delay.
    ``..._ceiling``: the best that ratio can be with the overlapped run's CPU per step: a step
    lasts at least the busiest process's CPU, and the three processes' CPU spread over the cores
    (``max(P, C, O, (P + C + O) / cores)``), against the delay-0 run's measured step.
    """
    cores = len(os.sched_getaffinity(0))
    out = {}
    runs = (('delay0', {'delay': 0}), ('delay1', {'delay': 1}),
            ('delay1_serial', {'delay': 1, 'overlap': False}))
    for tag, run in runs:
        rate, per = per_step_cpu(d, **run)
        out[f'four_processes_{tag}_steps_per_s'] = rate
        for name, us in per.items():
            out[f'four_processes_{tag}_cpu_us_per_step_{name}'] = us
    per1 = {k.rsplit('_', 1)[1]: v for k, v in out.items()
            if k.startswith('four_processes_delay1_cpu_us_per_step_')}
    bound_us = max(max(v for k, v in per1.items() if k != 'all'), per1['all'] / cores)
    r0 = out['four_processes_delay0_steps_per_s']
    out['four_processes_delay1_over_delay0'] = out['four_processes_delay1_steps_per_s'] / r0
    out['four_processes_delay1_serial_over_delay0'] = (
        out['four_processes_delay1_serial_steps_per_s'] / r0)
    out['four_processes_delay1_over_delay0_ceiling'] = 1e6 / bound_us / r0
    out['four_processes_delay1_over_ceiling'] = (
        out['four_processes_delay1_over_delay0']
        / out['four_processes_delay1_over_delay0_ceiling'])
    return out


def _gains(rate: int = 1000):
    from im_bringup.processes import free_run_gains, load_params_yaml
    return load_params_yaml(free_run_gains(1.0 / rate))


def rate_label(rate: int) -> str:
    """Return '1kHz', '250Hz' ...: the rate as it stands in the keys."""
    return f'{rate // 1000}kHz' if rate % 1000 == 0 else f'{rate}Hz'


def free_run(duration: float, realtime: bool = True, busy: bool = False,
             rate: int = 1000) -> dict:
    """
    free_run at ``rate`` [Hz] (1 kHz by default); ``realtime``.

    The nodes' default SCHED_FIFO (rt_priority 50) — the scheduling each node got is in the
    plant's final status — else ordinary scheduling; ``busy``: a CPU-bound process beside the
    graph. The rate is forced past the plant's pre-flight probe (``force_rate``): this measures
    what the loop does at that rate; the probe's own verdict is reported beside it.
    """
    if busy:
        hog = subprocess.Popen([sys.executable, '-c', 'while True: pass'])
        try:
            return free_run(duration, realtime, rate=rate)
        finally:
            hog.kill()
    tmp = tempfile.mkdtemp(prefix='bench_free_')
    try:
        res = _free_run(duration, realtime, os.path.join(tmp, 'free.mcap'), rate)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return {k.replace('free_run_1kHz', f'free_run_{rate_label(rate)}'): v for k, v in res.items()}


def _free_run(duration: float, realtime: bool, bag: str, rate: int = 1000) -> dict:
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.serialization import deserialize_message

    from im_recording.bag import iter_raw
    from im_recording.recorded_run import load_run
    from im_bringup.processes import graph_processes
    from im_recording.report import figures_of_merit
    from im_common import topics as T
    from im_common.timing import LatencyHistogram
    extra = _gains(rate)
    extra.setdefault('plant', {})['force_rate'] = True
    if not realtime:
        for node in ('plant', 'controller', 'observer', 'adapter'):
            extra.setdefault(node, {})['rt_priority'] = 0
    _run_graph_processes(graph_processes('position', 'min_energy', T_s=1.0 / rate,
                                         duration=duration,
                                         mode='free_run', record=bag, extra=extra), 'free',
                         # a trip is a result: the loop lost its deadlines
                         plant_may_fail=True)
    end, tripped, probe = None, 0, {}
    for _, _, _, raw in iter_raw(bag, [T.STATUS]):
        st = deserialize_message(bytes(raw), DiagnosticArray).status[0]
        values = {kv.key: kv.value for kv in st.values}
        if values.get('time_master') == 'true' and st.message in ('finished', 'failed'):
            end, tripped = values, int(st.message == 'failed')
        if values.get('time_master') == 'true' and st.message == 'running':
            probe = values
    fig = figures_of_merit(load_run(bag))
    hist = LatencyHistogram.from_values(end)
    steps = int(end['steps'])
    rec = recorded_fraction(bag, end, round(1e9 / rate))
    ref = _lockstep_reference(duration, rate)
    return {'free_run_1kHz_realtime': int(end.get('scheduling', '').startswith('fifo')),
            # the pre-flight probe's verdict on this machine (the run itself was forced)
            'free_run_1kHz_probe_p99_le_us':
                float(probe.get('probe_latency_p99_s', 'nan')) * 1e6,
            'free_run_1kHz_probe_rate_held_hz': int(probe.get('rate_held_hz', 0)),
            'free_run_1kHz_steps': steps, 'free_run_1kHz_tripped': tripped,
            'free_run_1kHz_missed_fraction': int(end['missed']) / steps,
            'free_run_1kHz_recorded_steps_fraction': rec['steps'],
            'free_run_1kHz_recorded_commands_fraction': rec['commands'],
            'free_run_1kHz_late_commands': int(end['late']),
            'free_run_1kHz_plant_overruns': int(end['overruns']),
            'free_run_1kHz_latency_mean_us': hist.mean * 1e6,
            'free_run_1kHz_latency_p50_le_us': hist.quantile(0.5) * 1e6,
            'free_run_1kHz_latency_p99_le_us': hist.quantile(0.99) * 1e6,
            'free_run_1kHz_latency_max_us': hist.max * 1e6,
            # a run that tripped before a reference was recorded has no tracking figures: 'nan'
            'free_run_1kHz_pos_err_max_rad': fig.get('pos_err_max_rad', math.nan),
            'free_run_1kHz_pos_err_rms_rad': fig.get('pos_err_rms_rad', math.nan),
            'lockstep_1kHz_pos_err_rms_rad': ref.summary['pos_err_rms_rad'],
            'free_run_1kHz_vs_lockstep_pos_err_rms': fig.get('pos_err_rms_rad', math.nan)
            / ref.summary['pos_err_rms_rad']}


@functools.lru_cache(maxsize=8)
def _lockstep_reference(duration: float, rate: int = 1000):
    """Return the in-process lock-step run free_run is compared with (one per duration)."""
    from im_bringup.testing import run_graph
    return run_graph(task='position', strategy='min_energy', T_s=1.0 / rate, duration=duration,
                     parameters=_gains(rate))


def recorded_fraction(bag: str, end: dict, period: int = 1_000_000) -> dict:
    """
    Return what a free_run bag holds of its run.

    ``steps`` = the fraction of the steps 0..N the plant integrated (its final event's
    ``steps``) whose measured current *and* shaft are in the bag; ``commands`` = recorded
    commands / commands the plant received (its latency samples, on time or late);
    ``missing_meta`` = the recorder's own count of missing lock-step steps.
    """
    from im_recording.bag import info, iter_raw
    from im_common import topics as T
    from im_common.timing import LatencyHistogram
    steps = int(end['steps'])
    got = {T.MEAS_CURRENT: set(), T.MEAS_SHAFT: set(), T.CMD_VOLTAGE: set()}
    for topic, _, t, _ in iter_raw(bag, list(got)):
        got[topic].add(t // period)
    both = got[T.MEAS_CURRENT] & got[T.MEAS_SHAFT]
    received = LatencyHistogram.from_values(end).n
    return {'steps': len(both & set(range(steps + 1))) / (steps + 1),
            'commands': len(got[T.CMD_VOLTAGE]) / max(received, 1),
            'missing_meta': int(info(bag).metadata['recording']['missing_steps'])}


def free_run_record(duration: float, busy: bool) -> dict:
    """One free_run run at 1 kHz with the recorder: recorded fractions and deadlines."""
    r = free_run(duration, busy=busy)
    keys = ('steps', 'tripped', 'missed_fraction', 'recorded_steps_fraction',
            'recorded_commands_fraction', 'realtime', 'pos_err_max_rad', 'latency_p99_le_us',
            'latency_max_us')
    return {k: r[f'free_run_1kHz_{k}'] for k in keys}


#: The busy-neighbour free_run figure of issue 25: this many runs of this length, the worst one.
BUSY_RUNS, BUSY_DURATION_S = 5, 10.0
#: The rate the machine holds: one run of this length at each rate beside a busy process.
RATE_HELD_DURATION_S = 5.0
#: ... holds = at most this fraction of the deadlines missed, and no trip.
RATE_HELD_MISSED = 0.01


def rate_held_busy(duration: float = RATE_HELD_DURATION_S) -> dict:
    """
    Return the highest free_run rate this machine holds beside a CPU-bound process.

    One run at each of ``CANDIDATE_RATES_HZ`` (forced past the probe), position task with the
    gains certified at that rate; held = no trip and at most :data:`RATE_HELD_MISSED` of the
    deadlines missed. ``free_run_rate_held_hz_busy`` is 0 when none is held; each rate's missed
    fraction and the probe's own verdict stand beside it.
    """
    from im_common.timing import CANDIDATE_RATES_HZ
    res, held = {}, 0
    for rate in CANDIDATE_RATES_HZ:
        r = free_run(duration, busy=True, rate=rate)
        key = f'free_run_{rate_label(rate)}'
        missed, tripped = r[f'{key}_missed_fraction'], r[f'{key}_tripped']
        res[f'free_run_rate_{rate}Hz_busy_missed_fraction'] = missed
        res[f'free_run_rate_{rate}Hz_busy_tripped'] = tripped
        res[f'free_run_rate_{rate}Hz_busy_probe_rate_held_hz'] = r[f'{key}_probe_rate_held_hz']
        if not tripped and missed <= RATE_HELD_MISSED:
            held = max(held, rate)
    res['free_run_rate_held_hz_busy'] = held
    return res


def free_run_busy_runs(runs: int, duration: float) -> dict:
    """
    Run free_run at 1 kHz beside a CPU-bound process ``runs`` times; the worst run's figures.

    ``free_run_1kHz_busy_*`` = the run with the most missed deadlines (its latency quantiles,
    position error ...); ``..._missed_fraction_per_run`` and ``..._pos_err_max_rad_worst`` cover
    every run.
    """
    each = [free_run(duration, busy=True) for _ in range(runs)]
    worst = max(each, key=lambda r: (r['free_run_1kHz_tripped'],
                                     r['free_run_1kHz_missed_fraction']))
    res = {k.replace('free_run_1kHz', 'free_run_1kHz_busy'): v for k, v in worst.items()}
    res['free_run_1kHz_busy_runs'] = runs
    res['free_run_1kHz_busy_duration_s'] = duration
    res['free_run_1kHz_busy_missed_fraction_per_run'] = [
        r['free_run_1kHz_missed_fraction'] for r in each]
    errs = [r['free_run_1kHz_pos_err_max_rad'] for r in each]
    # a run that tripped before a reference was recorded ('nan') is the worst
    res['free_run_1kHz_busy_pos_err_max_rad_worst'] = (
        math.nan if any(math.isnan(e) for e in errs) else max(errs))
    return res


def run(quick: bool = False) -> dict:
    """
    Full: every row.

    ``quick`` (a smoke test of every path, seconds): 2,000 round trips, one 0.4 s lock-step run
    without and one with the recorder (and a 0.1 s one, whose CPU time is subtracted: the
    start-up's, ≈ 0.8 s a process, must not drown the steps'), one 0.5 s free_run (real-time if
    allowed; the position error it is compared by is still zero before 0.2 s).
    """
    d = 0.4 if quick else 2.0
    res = cpu_ceiling(d, 2000 if quick else 10000)
    res.update(delay_overlap(d))
    res['lockstep_processes_recorded_steps_per_s'] = lockstep_processes(d, record=True)
    res.update(free_run(0.5 if quick else d))
    if quick:
        return res
    res.update(free_run_busy_runs(BUSY_RUNS, BUSY_DURATION_S))
    res.update(rate_held_busy())
    res.update({k.replace('free_run_1kHz', 'free_run_1kHz_normal_sched'): v
                for k, v in free_run(d, realtime=False).items()})
    return res


def cpu_ceiling(d: float, n_rt: int) -> dict:
    """
    Run the ping-pong, a lock-step run of ``d`` / 4 and one of ``d`` [s]: rates, CPU, ceilings.

    Everything ``four_processes_over_cpu_ceiling`` is made of (``run_all.CEILING_SHARES``): the
    ping-pong's round trips and CPU, the lock-step processes' steps/s, CPU per step (the two runs
    differenced), each process's, the ceilings, and the cores other jobs kept busy meanwhile.
    """
    cpu_rt, cpu_short, cpu_full, others = [], [], [], []
    by_short, by_full = {}, {}
    res = {'ping_pong_two_processes_round_trips_per_s': ping_pong_processes(n_rt, cpu_rt)}
    lockstep_processes(d / 4, record=False, cpu=cpu_short, cpu_by_name=by_short)
    res['lockstep_processes_steps_per_s'] = lockstep_processes(
        d, record=False, cpu=cpu_full, cpu_by_name=by_full, others=others)
    res['lockstep_processes_vs_ping_pong'] = (res['lockstep_processes_steps_per_s']
                                              / res['ping_pong_two_processes_round_trips_per_s'])
    # CPU per step without the start-up: the full run's steps beyond the short run's (T_s 100 µs)
    extra_steps = round(d / 1e-4) - round(d / 4 / 1e-4)
    res['lockstep_processes_cpu_us_per_step'] = 1e6 * (cpu_full[0] - cpu_short[0]) / extra_steps
    res['ping_pong_two_processes_cpu_us_per_round_trip'] = 1e6 * cpu_rt[0] / n_rt
    # the step's CPU counted in ping-pong deliveries (one publish and its one take: half a trip)
    res['lockstep_processes_cpu_per_step_in_deliveries'] = (
        res['lockstep_processes_cpu_us_per_step']
        / (res['ping_pong_two_processes_cpu_us_per_round_trip'] / 2))
    res['cores'] = len(os.sched_getaffinity(0))
    res['lockstep_processes_cpu_ceiling_vs_ping_pong'] = (
        res['cores'] * 1e6 / res['lockstep_processes_cpu_us_per_step']
        / res['ping_pong_two_processes_round_trips_per_s'])
    res.update(serial_chain(by_short, by_full, extra_steps, res))
    # the cores the rest of the machine kept busy during the full run: other jobs take CPU the
    # lock-step processes then wait for, and the ratios fall with it
    res['lockstep_processes_other_load_cores'] = others[0]
    return res


def key_runs(runs: int, d: float = 2.0) -> None:
    """
    ``--key [--runs N]``: ``four_processes_over_cpu_ceiling`` alone, N times (about 20 s each).

    One line a run: the key (steps/s × CPU per step over the cores: how busy the lock-step
    processes keep the machine), steps/s, CPU per step and each process's, and the serial
    chain's share (the plant's and the controller's CPU of a step one after the other).
    """
    for i in range(runs):
        r = cpu_ceiling(d, 10000)
        key = (r['lockstep_processes_vs_ping_pong']
               / r['lockstep_processes_cpu_ceiling_vs_ping_pong'])
        pre = 'lockstep_processes_'
        per = ' '.join('%s %.0f' % (n, r[f'{pre}cpu_us_per_step_{n}'])
                       for n in ('plant', 'controller', 'observer'))
        print('run %d: four_processes_over_cpu_ceiling %.3f  %.0f steps/s  %.0f µs CPU/step '
              '(%s)  serial plant+controller %.0f µs  other jobs %.2f cores'
              % (i, key, r[f'{pre}steps_per_s'], r[f'{pre}cpu_us_per_step'], per,
                 r[f'{pre}serial_us_per_step'], r[f'{pre}other_load_cores']), flush=True)


if __name__ == '__main__':
    if '--pong' in sys.argv:
        _pong_main()
    elif '--key' in sys.argv:
        a = sys.argv
        key_runs(int(a[a.index('--runs') + 1]) if '--runs' in a else 1)
    elif '--free-run-record' in sys.argv:
        a = sys.argv
        dur = float(a[a.index('--free-run-record') + 1])
        n = int(a[a.index('--runs') + 1]) if '--runs' in a else 1
        for i in range(n):
            print(f'run {i}:', free_run_record(dur, busy='--busy' in a), flush=True)
    else:                       # the table and JSON come from the driver
        from run_all import main
        sys.exit(main(['--only', 'processes'] + sys.argv[1:]))
