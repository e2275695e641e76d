"""
Lock-step throughput of the drive graph, next to its yardsticks measured in the same run.

* in one process (DriveGraph, EventsExecutor): steps/s of the full graph, with and without the
  adapter on the critical path, with and without in-process MCAP recording;
* (separate processes: benchmarks/bench_processes.py);
* the bare loop (benchmarks/bench_rclpy.py: same messages, no computation), with and without the
  message tags, and the plain model kernel (benchmarks/bench_kernel.py) measured in this run, so a
  slower graph shows up as a smaller ratio whatever the machine's speed that day.

Each figure is the best of ``repeats`` runs, the yardsticks and the graph taken in turn (the
machine is shared: the best run is the one least disturbed). Rates are taken from the plant's first
step on, in the graph and in the bare loop alike; the graph's start-up before it (discovery and the
run protocol's handshake, ≈ 0.5 s, a third of a 1 s run's wall time) is its own figure
(``graph_in_process_start_s``).
Targets: >= 0.9 of the bare loop in one process (``inprocess_over_bare``); recording <= 15 %.
The computation alone (the same scenario without ROS, ``computation_us_per_step``) bounds that
ratio: ``inprocess_ceiling_over_bare`` = bare step / (bare step + computation). With the message
tags the protocol keeps (every lock-step message signed and checked: what stops a rogue node from
driving the motor), the bound is ``inprocess_tagged_ceiling_over_bare`` = bare step / (tagged bare
step + computation): the best ratio of a graph whose step costs its signed messages, its
computation and nothing else.
"""
from __future__ import annotations

import importlib.util
import os
import shutil
import sys
import tempfile
from typing import Optional

HERE = os.path.dirname(os.path.abspath(__file__))


def _sibling(name: str):
    spec = importlib.util.spec_from_file_location(name, os.path.join(HERE, f'{name}.py'))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def in_process(duration: float, controller: str = 'nominal', record: bool = False,
               start: Optional[list] = None) -> float:
    """
    Steps/s of the speed task (min_energy) as ``scenario`` runs it, optionally recording.

    The graph and its summary tap as :func:`im_bringup.testing.run_graph` builds them; the rate
    from the plant's first step (``DriveGraph.steps_per_s_running``), as the bare loop's and the
    processes' rates are taken; the start-up before it (discovery, the run protocol's handshake)
    is appended to ``start`` [s].
    """
    from im_bringup.config import node_parameters
    from im_bringup.graph import DriveGraph
    from im_recording.bag import BagWriter
    from im_recording.traces import Tap
    tmp = tempfile.mkdtemp(prefix='bench_graph_') if record else None
    writer = BagWriter(os.path.join(tmp, 'run.mcap'), force=True) if tmp else None
    try:
        graph = DriveGraph(node_parameters('speed', 'min_energy', controller, 'none', 1e-4,
                                           duration), recorder=Tap(writer))
        try:
            stats = graph.run()
        finally:
            graph.close()
    finally:
        if writer is not None:
            writer.close()
        if tmp:
            shutil.rmtree(tmp, ignore_errors=True)
    if not stats['ok']:
        raise RuntimeError(f'graph run failed: {stats["failures"]}')
    if start is not None:
        start.append(graph.start_s)
    return graph.steps_per_s_running


def computation_us_per_step(steps: int) -> float:
    """
    Return µs per step of the graph's computation alone: the same scenario, no ROS.

    The speed task (min_energy) stepped as the lock-step graph steps it (measure, control law,
    plant kernel, observer: :mod:`im_bringup.offline`), without recording: what a step costs
    besides its messages however lean the protocol. With the bare loop's step it bounds the
    in-process ratio: bare / (bare + computation) (``inprocess_ceiling_over_bare``).
    """
    import time

    from im_bringup.offline import build
    from im_bringup.run_file import Scenario
    sc = Scenario(task='speed', strategy='min_energy', duration=steps * 1e-4)
    plant, ctl, obs = build(sc)
    x = obs.state
    T_s = sc.T_s
    t0 = time.perf_counter()
    for _ in range(steps):
        m = plant.measure()
        v_a, v_b = ctl.compute(m.t, m.i_alpha, m.i_beta, m.theta_r, m.omega_r, x[2], x[3], None)
        plant.step(v_a, v_b)
        x = obs.step(T_s, v_a, v_b, m.i_alpha, m.i_beta, m.omega_r)
    return 1e6 * (time.perf_counter() - t0) / steps


def run(quick: bool = False) -> dict:
    d = 0.05 if quick else 1.0
    steps = int(round(d * 1e4))
    repeats = 1 if quick else 3
    bare, kernel = _sibling('bench_rclpy'), _sibling('bench_kernel')
    from im_common.params import THESIS_MOTOR
    starts = []
    figures = {
        'kernel_steps_per_s': lambda: kernel.steps_per_second(THESIS_MOTOR, max(steps, 2000), 1),
        # a minimum, taken as the best run like the rates' maxima (below)
        'computation_steps_per_s': lambda: 1e6 / computation_us_per_step(max(steps, 2000)),
        'bare_loop_adapter_off_path_steps_per_s':
            lambda: bare.bare_loop(steps, adapter_on_path=False),
        'bare_loop_tagged_adapter_off_path_steps_per_s':
            lambda: bare.bare_loop(steps, adapter_on_path=False, tags=True),
        'graph_in_process_steps_per_s': lambda: in_process(d, start=starts),
        'bare_loop_adapter_on_path_steps_per_s':
            lambda: bare.bare_loop(steps, adapter_on_path=True),
        'graph_in_process_adaptive_steps_per_s': lambda: in_process(d, controller='adaptive'),
        'graph_in_process_recording_steps_per_s': lambda: in_process(d, record=True),
    }
    res = dict.fromkeys(figures, 0.0)
    for _ in range(repeats):
        for k, f in figures.items():
            res[k] = max(res[k], f())
    res['graph_in_process_start_s'] = min(starts)
    g = res['graph_in_process_steps_per_s']
    res['inprocess_over_bare'] = g / res['bare_loop_adapter_off_path_steps_per_s']
    res['inprocess_over_tagged_bare'] = g / res['bare_loop_tagged_adapter_off_path_steps_per_s']
    res['inprocess_over_kernel'] = g / res['kernel_steps_per_s']
    bare_us = 1e6 / res['bare_loop_adapter_off_path_steps_per_s']
    res['computation_us_per_step'] = 1e6 / res.pop('computation_steps_per_s')
    res['graph_us_per_step'] = 1e6 / g
    res['bare_loop_us_per_step'] = bare_us
    # the best ratio of a graph whose step costs its messages, its computation and nothing else
    res['inprocess_ceiling_over_bare'] = bare_us / (bare_us + res['computation_us_per_step'])
    tagged_us = 1e6 / res['bare_loop_tagged_adapter_off_path_steps_per_s']
    res['inprocess_tagged_ceiling_over_bare'] = bare_us / (tagged_us
                                                           + res['computation_us_per_step'])
    res['adaptive_graph_vs_bare_loop'] = (res['graph_in_process_adaptive_steps_per_s']
                                          / res['bare_loop_adapter_on_path_steps_per_s'])
    res['tags_us_per_step_in_bare_loop'] = 1e6 * (
        1.0 / res['bare_loop_tagged_adapter_off_path_steps_per_s']
        - 1.0 / res['bare_loop_adapter_off_path_steps_per_s'])
    res['recording_slowdown'] = 1.0 - res['graph_in_process_recording_steps_per_s'] / g
    return res


if __name__ == '__main__':      # the table and JSON come from the driver
    from run_all import main
    sys.exit(main(['--only', 'graph'] + sys.argv[1:]))
