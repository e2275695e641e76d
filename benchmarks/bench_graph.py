"""Lock-step throughput of the drive graph, next to the bare protocol loop of the same run.

* in one process (DriveGraph, EventsExecutor): steps/s of the full graph, with and without the
  adapter on the critical path, with and without in-process MCAP recording;
* (separate processes: benchmarks/bench_processes.py);
* the bare loop (benchmarks/bench_rclpy.py: same messages, no computation) measured in this run.
Targets: >= 5,000 steps/s and >= 0.8 of the bare loop in one process; recording costs <= 15 %.
"""
from __future__ import annotations

import importlib.util
import os
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))


def _bench_rclpy():
    spec = importlib.util.spec_from_file_location('bench_rclpy', os.path.join(HERE, 'bench_rclpy.py'))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def in_process(duration: float, controller: str = 'nominal', record: bool = False) -> float:
    from im_bringup.testing import run_graph
    path = None
    if record:
        path = os.path.join(tempfile.mkdtemp(prefix='bench_graph_'), 'run.mcap')
    res = run_graph(task='speed', strategy='min_energy', controller=controller, duration=duration,
                    record=path)
    if not res.summary['ok']:
        raise RuntimeError(f'graph run failed: {res.summary["failures"]}')
    return res.summary['steps'] / res.summary['wall_s']


def run(quick: bool = False) -> dict:
    d = 0.2 if quick else 1.0
    bare = _bench_rclpy()
    res = {}
    res['bare_loop_adapter_off_path_steps_per_s'] = bare.bare_loop(int(d * 1e4), adapter_on_path=False)
    res['bare_loop_adapter_on_path_steps_per_s'] = bare.bare_loop(int(d * 1e4), adapter_on_path=True)
    res['graph_in_process_steps_per_s'] = in_process(d)
    res['graph_in_process_recording_steps_per_s'] = in_process(d, record=True)
    res['graph_in_process_adaptive_steps_per_s'] = in_process(d, controller='adaptive')
    res['nominal_graph_vs_bare_loop'] = (res['graph_in_process_steps_per_s']
                                         / res['bare_loop_adapter_off_path_steps_per_s'])
    res['adaptive_graph_vs_bare_loop'] = (res['graph_in_process_adaptive_steps_per_s']
                                          / res['bare_loop_adapter_on_path_steps_per_s'])
    res['recording_slowdown'] = 1.0 - (res['graph_in_process_recording_steps_per_s']
                                       / res['graph_in_process_steps_per_s'])
    return res


if __name__ == '__main__':
    for k, v in run('--quick' in sys.argv).items():
        print(f'{k:45s} {v:12.4g}')
