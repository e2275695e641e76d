"""Run every benchmark in this folder, print one table, write benchmarks/results/<name>.json.

Benchmarks are files ``bench_*.py`` exposing ``run(quick=False) -> dict``. ``--quick`` shortens
them (for a smoke run); the figures in the README come from a full run.
"""
from __future__ import annotations

import argparse
import importlib.util
import json
import os
import platform
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))


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
    return {'platform': platform.platform(), 'python': platform.python_version(),
            'cpus': os.cpu_count(), 'cpu_model': cpu}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument('--quick', action='store_true', help='short runs (smoke test)')
    ap.add_argument('--only', nargs='*', help='run only these benchmarks (e.g. kernel graph)')
    args = ap.parse_args(argv)
    out_dir = os.path.join(HERE, 'results')
    os.makedirs(out_dir, exist_ok=True)
    names = sorted(f[6:-3] for f in os.listdir(HERE) if f.startswith('bench_') and f.endswith('.py'))
    if args.only:
        names = [n for n in names if n in args.only]
    info = machine()
    rows = []
    for name in names:
        print(f'[bench] {name} ...', file=sys.stderr, flush=True)
        spec = importlib.util.spec_from_file_location(f'bench_{name}', os.path.join(HERE, f'bench_{name}.py'))
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
        t0 = time.perf_counter()
        res = mod.run(quick=args.quick)
        res = {'benchmark': name, 'machine': info, 'quick': args.quick,
               'wall_s': time.perf_counter() - t0, 'results': res}
        with open(os.path.join(out_dir, f'{name}.json'), 'w') as f:
            json.dump(res, f, indent=2, default=float)
        for k, v in res['results'].items():
            if isinstance(v, (int, float)):
                rows.append((name, k, v))
    print(f"\nmachine: {info['cpu_model']} ({info['cpus']} cpus), Python {info['python']}")
    print(f"{'benchmark':10s} {'figure':52s} {'value':>14s}")
    for name, k, v in rows:
        print(f'{name:10s} {k:52s} {v:14.6g}')
    print(f'\nJSON written to {out_dir}/')
    return 0


if __name__ == '__main__':
    sys.exit(main())
