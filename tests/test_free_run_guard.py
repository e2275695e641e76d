"""
free_run on a machine that cannot hold the rate: refused before step 0, or stopped at once.

The pre-flight probe (``im_common.timing.assess_probe``, run by the plant before step 0) and the
deadline watchdog (``im_common.timing.DeadlineWatchdog``): the judgement without ROS, then the
graph in one process with an injected delay — a node that echoes the probe late (refused, the line
naming the measured latency, the period and the rate held) and a controller that computes late
while the rate is forced (stopped by the watchdog within 0.1 s of its threshold, at zero voltage).
"""
import math
import time

from im_common.timing import (assess_probe, CANDIDATE_RATES_HZ, DeadlineWatchdog, PROBE_BUDGET)
import pytest


def test_a_loop_within_the_budget_holds_its_rate_and_names_the_fastest_it_holds():
    v = assess_probe([100e-6] * 300, 300, 1e-3, compute=50e-6)
    assert v.holds and v.lost == 0
    assert v.p50 == pytest.approx(150e-6) and v.p99 == pytest.approx(150e-6)
    # 2 kHz: 100 µs round trip + the plant's step at half the period (25 µs) <= 0.5 * 500 µs
    assert v.rate_held == 2000
    text = v.text()
    assert 'free_run at 1000 Hz' in text and 'p99 150 µs' in text and 'holds it' in text
    assert f'budget {PROBE_BUDGET:g} of the period = 500 µs' in text


def test_a_loop_slower_than_the_budget_is_refused_with_the_rate_it_holds():
    # 700 µs round trips: over half of 1 ms, within half of 2 ms (500 Hz)
    v = assess_probe([700e-6] * 300, 300, 1e-3)
    assert not v.holds and v.rate_held == 500
    assert 'cannot hold it' in v.text() and 'this machine holds 500 Hz (T_s = 0.002 s)' in v.text()
    # the plant's own step grows with the period: 200 µs at 1 ms is 800 µs at 250 Hz
    v = assess_probe([1.3e-3] * 300, 300, 1e-3, compute=200e-6)
    assert v.rate_held is None and 'holds none of' in v.text()


def test_the_tail_decides_and_a_lost_probe_counts_as_infinitely_late():
    fast = [100e-6] * 297
    assert assess_probe(fast + [5e-3] * 3, 300, 1e-3).holds          # 1 % slow: p99 still fast
    assert not assess_probe(fast + [5e-3] * 4, 300, 1e-3).holds      # over 1 %: p99 is slow
    v = assess_probe(fast[:296], 300, 1e-3)                          # 4 of 300 never came back
    assert v.lost == 4 and math.isinf(v.p99) and not v.holds and v.rate_held is None
    assert 'p99 inf' in v.text() and '4 lost' in v.text()


def test_the_probe_refuses_what_cannot_be_judged():
    with pytest.raises(ValueError, match='period'):
        assess_probe([1e-4], 1, 0.0)
    with pytest.raises(ValueError, match='sent nothing'):
        assess_probe([], 0, 1e-3)


def test_the_watchdog_trips_at_the_step_its_window_passes_the_limit_and_forgets_old_misses():
    w = DeadlineWatchdog(window=100, limit=0.1)
    assert all(w.add(True) is None for _ in range(10))      # 10 of 100: at the limit, not past
    why = w.add(True)
    assert why == ('deadline watchdog: 11 of the last 11 steps missed their deadline (limit 10% '
                   'of 100)')
    w = DeadlineWatchdog(window=100, limit=0.1)
    for k in range(1000):                                    # one miss in ten: never past 10 %
        assert w.add(k % 10 == 0) is None, k
    assert w.missed_in_window == 10
    off = DeadlineWatchdog(window=10, limit=0.0)
    assert all(off.add(True) is None for _ in range(100))
    with pytest.raises(ValueError, match='deadline_window'):
        DeadlineWatchdog(window=0)
    with pytest.raises(ValueError, match='deadline_miss_limit'):
        DeadlineWatchdog(limit=1.5)


def test_the_shipped_gains_cover_every_rate_the_probe_names():
    from im_bringup.processes import free_run_gains, load_params_yaml
    for rate in CANDIDATE_RATES_HZ:
        gains = load_params_yaml(free_run_gains(1.0 / rate))
        assert gains['controller']['gain_period'] == pytest.approx(1.0 / rate)
        assert gains['observer']['gain_period'] == pytest.approx(1.0 / rate)
    with pytest.raises(ValueError, match='no certified gains shipped for T_s = 0.003 s'):
        free_run_gains(3e-3)


def _free_run(T_s=1e-3, duration=0.5, **plant):
    from im_bringup.processes import free_run_gains, load_params_yaml
    from im_bringup.testing import run_graph
    params = load_params_yaml(free_run_gains(T_s))
    params['plant'] = dict(mode='free_run', **plant)
    return run_graph(task='position', T_s=T_s, duration=duration, parameters=params)


def test_no_machine_holds_100_khz_so_the_plant_refuses_it_before_step_0():
    """A Python loop's round trip is far above 5 µs: refused, not run away."""
    from im_bringup.testing import run_graph
    res = run_graph(task='position', T_s=1e-5, duration=0.1,
                    parameters={'plant': {'mode': 'free_run'}})
    assert not res.summary['ok'] and res.summary['steps'] == 0
    why = res.summary['failures']['plant']
    assert why.startswith('free_run at 100000 Hz: measured loop latency p50 '), why
    assert 'budget 0.5 of the period = 5 µs: cannot hold it' in why
    assert 'refusing to start (the plant parameter force_rate: true starts anyway)' in why


def test_a_loop_whose_echo_is_late_is_refused_before_step_0(monkeypatch):
    """Injected: the controller answers every probe 5 ms late; 250 Hz allows 2 ms."""
    from im_common.status_channel import StatusChannel
    from im_controller.controller_node import ControllerNode
    echo = StatusChannel.echo

    def late(self, msg):
        if isinstance(self.node, ControllerNode):
            time.sleep(5e-3)
        echo(self, msg)
    monkeypatch.setattr(StatusChannel, 'echo', late)
    res = _free_run()
    assert not res.summary['ok'] and res.summary['steps'] == 0
    why = res.summary['failures']['plant']
    assert 'free_run at 1000 Hz: measured loop latency' in why and 'cannot hold it' in why, why
    assert 'holds none of 250, 500, 1000, 2000 Hz' in why, why
    assert 'v_cmd_alpha' not in res.trace or len(res.trace['v_cmd_alpha']) == 0


def test_a_forced_rate_that_misses_is_stopped_at_zero_voltage_within_0_1_s(monkeypatch):
    """Injected: every controller step takes 3 ms at 1 kHz; force_rate starts it anyway."""
    from im_controller.controller_node import ControllerNode
    step = ControllerNode.step

    def slow(self, inputs):
        time.sleep(3e-3)
        step(self, inputs)
    monkeypatch.setattr(ControllerNode, 'step', slow)
    res = _free_run(duration=2.0, force_rate=True, deadline_window=100, deadline_miss_limit=0.5)
    assert not res.summary['ok']
    why = res.summary['failures']['plant']
    assert 'protection trip at t = ' in why and 'deadline watchdog: 51 of the last' in why, why
    assert 'does not hold 1000 Hz here; zero voltage' in why
    t_trip = float(why.split('protection trip at t = ')[1].split(' s')[0])
    # more than half of the first 100 steps missed: the 51st miss, at most 0.1 s after the start
    assert t_trip <= 0.1 + 1e-9, t_trip
    assert res.summary['steps'] <= 101
    v = res.trace['v_alpha'], res.trace['v_beta']      # the applied voltage at the trip: zero
    assert v[0][-1] == 0.0 and v[1][-1] == 0.0


def test_the_input_watchdog_counts_only_the_time_its_process_ran():
    """
    A starved process's ticks come late: that time is not a missing input's.

    Ticks on time for 5 s: 5 s waited (a stalled run times out as before); one tick 6 s late (the
    process did not run: a loaded machine) counts two ticks' worth; a new expected step starts
    its own wait.
    """
    from im_common.lockstep import WATCHDOG_TICK_S
    from im_common.lockstep_protocol import WaitClock
    clock = WaitClock(WATCHDOG_TICK_S)
    since = 100.0
    waited = [clock.waited(since, since + 0.1 * k) for k in range(1, 51)]
    assert waited[-1] == pytest.approx(5.0)
    assert clock.waited(since, since + 11.0) == pytest.approx(5.0 + 2 * WATCHDOG_TICK_S)
    assert clock.waited(since, since + 11.1) == pytest.approx(5.3)
    assert clock.waited(120.0, 120.05) == pytest.approx(0.05)      # the next step's own wait
    assert clock.waited(120.0, 119.0) == pytest.approx(0.05)       # time never runs backwards
