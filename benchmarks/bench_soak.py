"""
Memory of a long in-process run (issue 11): RSS over simulated time, and max RSS vs length.

Each run is a fresh child process doing what ``scenario`` does without ``--record`` (DriveGraph,
the publisher tap folding every message into the running figures, the summary at the end). The
child samples its RSS (``/proc/self/statm``) every 0.5 s together with the plant's step, and
reports its peak (``ru_maxrss``) after the summary.

Targets: a 600k-step run grows RSS by < 20 MB after warm-up (the first 20k steps); a 180k-step
run's max RSS is < 20 MB above a 20k-step run's.

    python benchmarks/bench_soak.py            # 20k, 180k and 600k steps (about 4 minutes)
    python benchmarks/bench_soak.py --quick    # 2k and 6k steps (a smoke test: the code path)
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import threading

T_S = 1e-4
WARMUP = 20_000


def _rss_mb() -> float:
    with open('/proc/self/statm') as f:
        return int(f.read().split()[1]) * os.sysconf('SC_PAGE_SIZE') / 2**20


def child(steps: int) -> dict:
    import resource

    from im_bringup.config import node_parameters
    from im_bringup.graph import DriveGraph
    from im_bringup.scenario import summarize
    from im_recording.traces import Tap
    params = node_parameters('speed', 'min_energy', 'nominal', 'none', T_S, steps * T_S)
    tap = Tap(keep=False)
    graph = DriveGraph(params, recorder=tap)
    samples = []
    done = threading.Event()

    def sample():
        while not done.wait(0.5):
            samples.append((graph.plant.sim.k, _rss_mb()))
    th = threading.Thread(target=sample, daemon=True)
    th.start()
    try:
        stats = graph.run()
    finally:
        done.set()
        th.join()
        graph.close()
    summary = summarize(params, stats, tap, task='speed', strategy='min_energy',
                        controller='nominal', variation='none')
    samples.append((stats['steps'], _rss_mb()))
    return {'steps': stats['steps'], 'ok': stats['ok'], 'wall_s': stats['wall_s'],
            'E_in_J': summary['E_in_J'], 'samples': samples,
            'max_rss_mb': resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}


def _spawn(steps: int) -> dict:
    out = subprocess.run([sys.executable, os.path.abspath(__file__), '--child', str(steps)],
                         capture_output=True, text=True, timeout=3600)
    if out.returncode != 0:
        raise RuntimeError(f'soak child ({steps} steps) failed: {out.stderr.strip()[-500:]}')
    return json.loads(out.stdout.strip().splitlines()[-1])


def run(quick: bool = False) -> dict:
    lengths = (2_000, 6_000) if quick else (WARMUP, 180_000, 600_000)
    warmup = lengths[0]
    res = {}
    runs = {n: _spawn(n) for n in lengths}
    longest = runs[lengths[-1]]
    print(f'RSS over the {lengths[-1]}-step run (no recording):')
    print(f"{'step':>8s} {'t_sim [s]':>10s} {'RSS [MB]':>9s}")
    rows = longest['samples']
    for k, rss in rows[::max(1, len(rows) // 15)] + [rows[-1]]:
        print(f'{k:8d} {k * T_S:10.2f} {rss:9.1f}')
    after = [rss for k, rss in rows if k >= warmup]
    res[f'rss_growth_after_warmup_{lengths[-1] // 1000}k_steps_mb'] = \
        (max(after) - after[0]) if after else float('nan')
    for n, r in runs.items():
        res[f'max_rss_{n // 1000}k_steps_mb'] = r['max_rss_mb']
    res[f'max_rss_{lengths[1] // 1000}k_minus_{warmup // 1000}k_mb'] = \
        runs[lengths[1]]['max_rss_mb'] - runs[warmup]['max_rss_mb']
    res['samples'] = rows
    return res


if __name__ == '__main__':
    if len(sys.argv) > 2 and sys.argv[1] == '--child':
        print(json.dumps(child(int(sys.argv[2]))))
        sys.exit(0)
    from run_all import main      # the table and JSON come from the driver
    sys.exit(main(['--only', 'soak'] + sys.argv[1:]))
