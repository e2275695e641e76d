"""
The real plant's cost: every block on against the ideal plant, in the same run (docs/plant.md).

The speed task (min_energy) on the shipped thesis motor file, once with the ideal plant and once
with every block of docs/plant.md on (switched inverter at 10 kHz with dead time, on-state drop
and a DC link with chopper, the motor file's saturation and thermal blocks, the iron loss acting,
encoder and ADC), run interleaved, best of the repeats:

- ``offline_*_steps_per_s``: the ROS-free loop (:func:`im_bringup.offline.simulate`);
- ``graph_*_steps_per_s``: the in-process graph (from the plant's first step, as bench_graph's);
- ``real_plant_over_ideal``: the smaller of the two ratios (real / ideal steps/s), the figure of
  summary.json (target >= 0.5: the blocks must not cost more than the whole ideal step).

The real plant's period is compiled (:mod:`im_common.real_plant_kernel`, numba) unless
``--no-kernel`` (its pure-Python reference path, ``RealPlant.use_kernel = False``). Run
standalone: ``python benchmarks/bench_real_plant.py [--quick] [--no-kernel]`` (prints the figures
as JSON); a first 20-period run compiles the kernel, or loads it from the cache, before the
clock starts (``first_real_run_s``);
``benchmarks/run_all.py --only real_plant`` imports :func:`run`.
"""
from __future__ import annotations

import argparse
import json
import os
import time

#: every block on (docs/plant.md): the run-file keys added to the ideal scenario
BLOCKS = {
    'saturation': 'motor', 'thermal': 'motor', 'iron_loss': True,
    'inverter': {'V_dc': 340.0, 'pwm_frequency': 10000.0, 'deadtime': 2.0e-6, 'v_on': 1.0,
                 'r_on': 0.02, 'C_dc': 1.0e-3, 'V_chopper': 400.0, 'R_chopper': 40.0},
    'sensors': {'encoder_lines': 2048, 'adc_bits': 12, 'current_range': 40.0},
}


def scenario(duration: float, real: bool):
    from im_bringup.run_file import Scenario
    from im_common.params import shipped_motors_dir
    motor = os.path.join(shipped_motors_dir(), 'thesis.yaml')
    return Scenario(task='speed', strategy='min_energy', duration=duration, motor=motor,
                    **(BLOCKS if real else {}))


def offline_steps_per_s(duration: float, real: bool) -> float:
    from im_bringup.offline import simulate
    sc = scenario(duration, real)
    t0 = time.perf_counter()
    res = simulate(sc)
    wall = time.perf_counter() - t0
    if res.summary.get('trip'):
        raise RuntimeError(f'run tripped: {res.summary["trip"]}')
    return round(duration / sc.T_s) / wall


def graph_steps_per_s(duration: float, real: bool) -> float:
    from im_bringup.graph import DriveGraph
    from im_recording.traces import Tap
    graph = DriveGraph(scenario(duration, real).node_parameters(), recorder=Tap(None))
    try:
        stats = graph.run()
    finally:
        graph.close()
    if not stats['ok']:
        raise RuntimeError(f'graph run failed: {stats["failures"]}')
    return graph.steps_per_s_running


def run(quick: bool = False) -> dict:
    duration = 0.05 if quick else 0.5
    repeats = 1 if quick else 3
    t0 = time.perf_counter()
    offline_steps_per_s(0.002, True)        # the kernel compiled or loaded from its cache
    first = time.perf_counter() - t0
    best = {}
    for _ in range(repeats):                  # interleaved: the same machine load for both
        for kind in ('offline', 'graph'):
            fn = offline_steps_per_s if kind == 'offline' else graph_steps_per_s
            for real in (False, True):
                key = f'{kind}_{"real" if real else "ideal"}_steps_per_s'
                best[key] = max(best.get(key, 0.0), fn(duration, real))
    res = dict(best)
    res['offline_real_over_ideal'] = best['offline_real_steps_per_s'] / \
        best['offline_ideal_steps_per_s']
    res['graph_real_over_ideal'] = best['graph_real_steps_per_s'] / best['graph_ideal_steps_per_s']
    res['real_plant_over_ideal'] = min(res['offline_real_over_ideal'],
                                       res['graph_real_over_ideal'])
    res['duration_s'] = duration
    res['first_real_run_s'] = first         # a 20-period run, the kernel's compilation with it
    return res


def main(argv=None) -> None:
    """Print :func:`run`'s figures (and the kernel's first call) as JSON."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    ap.add_argument('--quick', action='store_true', help='short runs (smoke test)')
    ap.add_argument('--no-kernel', action='store_true',
                    help='the pure-Python period (RealPlant.use_kernel = False)')
    args = ap.parse_args(argv)
    from im_common.real_plant import RealPlant
    if args.no_kernel:
        RealPlant.use_kernel = False
    res = run(quick=args.quick)
    res['use_kernel'] = bool(getattr(RealPlant, 'use_kernel', False))
    print(json.dumps(res, indent=1))


if __name__ == '__main__':
    main()
