"""
Run every benchmark in this folder, print one table, write <out>/<name>.json and summary.json.

Benchmarks are files ``bench_*.py`` exposing ``run(quick=False) -> dict``. ``--quick`` shortens
them to seconds (tests/test_benchmarks.py runs every one that way, so none can break unseen); the
figures in the README come from a full run (``make bench``). ``summary.json`` holds the ratios
the targets are stated in, each measured within this run (:data:`RATIOS`).
"""
from __future__ import annotations

import argparse
import datetime
import importlib.util
import json
import math
import os
import platform
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
if HERE not in sys.path:        # the benchmarks import each other (run standalone or from here)
    sys.path.insert(0, HERE)

#: summary.json key -> (benchmark, figure): the ratios of issue 25, each from one benchmark's run,
#: and next to them the ceilings the same run measures for them (the best ratio a graph whose step
#: costs its computation and its signed messages can reach in one process; the best the processes'
#: CPU per step allows on this machine's cores): docs/benchmarks.md.
RATIOS = {
    'inprocess_over_bare': ('graph', 'inprocess_over_bare'),
    'inprocess_ceiling_over_bare': ('graph', 'inprocess_ceiling_over_bare'),
    'inprocess_tagged_ceiling_over_bare': ('graph', 'inprocess_tagged_ceiling_over_bare'),
    'inprocess_over_tagged_bare': ('graph', 'inprocess_over_tagged_bare'),
    'inprocess_over_kernel': ('graph', 'inprocess_over_kernel'),
    'four_processes_over_pingpong': ('processes', 'lockstep_processes_vs_ping_pong'),
    'four_processes_cpu_ceiling_over_pingpong': ('processes',
                                                 'lockstep_processes_cpu_ceiling_vs_ping_pong'),
    # the rate if the plant's and the controller's CPU of a step came one after the other whole
    'four_processes_serial_rate_over_pingpong': (
        'processes', 'lockstep_processes_serial_rate_vs_ping_pong'),
    'free_run_missed_fraction_busy': ('processes', 'free_run_1kHz_busy_missed_fraction'),
    'free_run_rate_held_hz_busy': ('processes', 'free_run_rate_held_hz_busy'),
    # the delayed step overlapped: delay 1 over delay 0, its ceiling from the CPU per step, and
    # the serial order's (the same numbers, one node at a time)
    'four_processes_delay1_over_delay0': ('processes', 'four_processes_delay1_over_delay0'),
    'four_processes_delay1_over_delay0_ceiling': (
        'processes', 'four_processes_delay1_over_delay0_ceiling'),
    'four_processes_delay1_over_ceiling': ('processes', 'four_processes_delay1_over_ceiling'),
    'four_processes_delay1_serial_over_delay0': (
        'processes', 'four_processes_delay1_serial_over_delay0'),
    # every real-plant block on over the ideal plant (docs/plant.md)
    'real_plant_over_ideal': ('real_plant', 'real_plant_over_ideal'),
    # the ROS-free loop on the real plant, compiled over its pure-Python reference (same run)
    'real_plant_compiled_over_reference': ('real_plant', 'offline_real_compiled_over_reference'),
}


#: summary.json key -> (reached ratio, its ceiling): both keys of RATIOS, from the same run
CEILING_SHARES = {
    'inprocess_over_ceiling': ('inprocess_over_bare', 'inprocess_tagged_ceiling_over_bare'),
    'four_processes_over_cpu_ceiling': ('four_processes_over_pingpong',
                                        'four_processes_cpu_ceiling_over_pingpong'),
    # what four_processes_over_cpu_ceiling would be if they did (not a bound: part of the
    # controller's CPU overlaps the plant's), and the reached rate over that one
    'four_processes_serial_over_cpu_ceiling': ('four_processes_serial_rate_over_pingpong',
                                               'four_processes_cpu_ceiling_over_pingpong'),
    'four_processes_over_serial_rate': ('four_processes_over_pingpong',
                                        'four_processes_serial_rate_over_pingpong'),
}


#: summary.json key -> (at least / at most, the bound, where it comes from): the targets the
#: opening table of docs/benchmarks.md holds each run to (``benchmarks/today.py``)
TARGETS = {
    'four_processes_delay1_over_delay0': ('>=', 1.2, 'issue 46: the delayed step overlapped'),
    'four_processes_delay1_over_ceiling': ('>=', 0.9, 'issue 46: of the ceiling its CPU allows'),
    'four_processes_over_serial_rate': ('>=', 0.9, 'issue 46: delay 0 does not fall'),
    'inprocess_over_ceiling': ('>=', 0.7, 'issue 46: delay 0 does not fall'),
    'free_run_rate_held_hz_busy': ('>=', 500.0, 'issue 46: delay 0 does not fall'),
    'free_run_missed_fraction_busy': ('<=', 0.01, 'issue 25: 1 kHz beside a busy process'),
    'real_plant_over_ideal': ('>=', 0.9, 'issue 46: the real plant as fast as the ideal'),
    'real_plant_compiled_over_reference': ('>=', 2.0, 'issue 46: the ROS-free loop 2x'),
}


def meets(key: str, value: float) -> bool:
    """Tell whether ``value`` of summary key ``key`` meets its target (:data:`TARGETS`)."""
    op, bound, _ = TARGETS[key]
    return value >= bound if op == '>=' else value <= bound


def benchmark_names() -> list:
    return sorted(f[6:-3] for f in os.listdir(HERE)
                  if f.startswith('bench_') and f.endswith('.py'))


def machine() -> dict:
    cpu = ''
    try:
        with open('/proc/cpuinfo') as f:
            for line in f:
                if line.startswith('model name'):
                    cpu = line.split(':', 1)[1].strip()
                    break
    except OSError:
        pass
    load = os.getloadavg()[0] if hasattr(os, 'getloadavg') else float('nan')
    return {'platform': platform.platform(), 'python': platform.python_version(),
            'cpus': os.cpu_count(), 'cpu_model': cpu, 'load_1min_at_start': load}


def strict(obj):
    """
    ``obj`` with every non-finite float as its name ('inf', 'nan').

    The JSON stays standard (a latency quantile beyond the histogram's last bin is 'inf', not
    the non-JSON Infinity).
    """
    if isinstance(obj, float) and not math.isfinite(obj):
        return repr(obj)
    if isinstance(obj, dict):
        return {k: strict(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [strict(v) for v in obj]
    return obj


def run_one(name: str, quick: bool, info: dict) -> dict:
    spec = importlib.util.spec_from_file_location(f'bench_{name}',
                                                  os.path.join(HERE, f'bench_{name}.py'))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    t0 = time.perf_counter()
    res = mod.run(quick=quick)
    return {'benchmark': name, 'machine': info, 'quick': quick,
            'wall_s': time.perf_counter() - t0, 'results': res}


def summary(results: dict, info: dict, quick: bool) -> dict:
    """Return the ratios measured in this run (a ratio whose benchmark did not run is left out)."""
    out = {'date': datetime.datetime.now().isoformat(timespec='seconds'), 'quick': quick,
           'machine': info, 'benchmarks': sorted(results)}     # those that completed
    for key, (bench, fig) in RATIOS.items():
        v = results.get(bench, {}).get('results', {}).get(fig)
        if isinstance(v, (int, float)) and math.isfinite(v):
            out[key] = v
    # each reached ratio over the ceiling the same run measures for it (the targets of
    # docs/benchmarks.md: the node logic's share of a step, what a restructure can take out)
    for key, (num, den) in CEILING_SHARES.items():
        if out.get(num) and out.get(den):
            out[key] = out[num] / out[den]
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument('--quick', action='store_true', help='short runs (smoke test, seconds each)')
    ap.add_argument('--only', nargs='*', help='run only these benchmarks (e.g. kernel graph)')
    ap.add_argument('--out', default=os.path.join(HERE, 'results'),
                    help='directory for the JSON files (default: benchmarks/results)')
    args = ap.parse_args(argv)
    names = benchmark_names()
    if args.only:
        unknown = [n for n in args.only if n not in names]
        if unknown:
            print(f'run_all: error: no benchmark {", ".join(unknown)} (have: {", ".join(names)})',
                  file=sys.stderr)
            return 2
        names = [n for n in names if n in args.only]
    os.makedirs(args.out, exist_ok=True)
    info = machine()
    results = {}
    rows = []
    failed = {}
    for name in names:
        print(f'[bench] {name} ...', file=sys.stderr, flush=True)
        try:
            res = results[name] = run_one(name, args.quick, info)
        except Exception as exc:  # noqa: BLE001 - the others still run; the exit code says it
            import traceback
            traceback.print_exc()
            failed[name] = f'{type(exc).__name__}: {exc}'
            continue
        with open(os.path.join(args.out, f'{name}.json'), 'w') as f:
            json.dump(strict(res), f, indent=2, default=float, allow_nan=False)
        for k, v in res['results'].items():
            if isinstance(v, (int, float)):
                rows.append((name, k, v))
            elif isinstance(v, str):
                rows.append((name, k, v))
    summ = summary(results, info, args.quick)
    with open(os.path.join(args.out, 'summary.json'), 'w') as f:
        json.dump(strict(summ), f, indent=2, allow_nan=False)
    print(f"\nmachine: {info['cpu_model']} ({info['cpus']} cpus), Python {info['python']}, "
          f"load {info['load_1min_at_start']:.2f} at start"
          + (' (quick run)' if args.quick else ''))
    print(f"{'benchmark':10s} {'figure':52s} {'value':>14s}")
    for name, k, v in rows:
        print(f'{name:10s} {k:52s} ' + (f'{v:14.6g}' if not isinstance(v, str) else v))
    print('\nsummary (ratios within this run):')
    for k in list(RATIOS) + list(CEILING_SHARES):
        if k in summ:
            target = ''
            if k in TARGETS:
                op, bound, _ = TARGETS[k]
                target = f'  target {op} {bound:g}: ' + ('met' if meets(k, summ[k]) else 'NOT met')
            print(f'  {k:48s} {summ[k]:8.3f}{target}')
    print(f'\nJSON written to {args.out}/')
    for name, why in failed.items():
        print(f'run_all: error: benchmark {name} failed: {why}', file=sys.stderr)
    return 1 if failed else 0


if __name__ == '__main__':
    sys.exit(main())
