"""
Campaign engine and scaling (docs/campaign.md).

1. Engines on this machine, each in a fresh interpreter with as many workers as cores: the
   standard library's process pool (the floor: no scheduler), a Dask local cluster, a local Ray
   instance. Startup to the first result [s], per-task overhead over 2,000 empty tasks [ms], the
   resident memory of the driver and every process the engine started [MB], and the wall time of
   the same 16 campaign runs (position task, 0.5 s at 1 kHz, drawn motors) [s]. These rows chose
   Dask as the campaign engine (Ray is a benchmark-only dependency: benchmarks/requirements.txt).
2. Scaling of a campaign on Dask: wall time against the number of runs (1 and all workers) and
   against the number of workers for a fixed set of runs.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time

import yaml

HERE = os.path.dirname(os.path.abspath(__file__))
GAINS = os.path.join(HERE, '..', 'src', 'im_bringup', 'config', 'gains_1ms.yaml')


def _spec(tmp: str, draws: int, duration: float = 0.5) -> str:
    path = os.path.join(tmp, f'bench_{draws}.yaml')
    with open(path, 'w') as f:
        yaml.safe_dump({'name': f'bench{draws}', 'seed': 1, 'draws': draws,
                        'tasks': ['position'], 'duration': duration,
                        'gain_sets': [{'name': 'certified', 'gains': os.path.abspath(GAINS),
                                       'T_s': 1e-3}]}, f)
    return path


def _noop(x):
    return x


def _rss_mb(pid: int) -> float:
    """Resident memory of ``pid`` and all its descendants [MB] (from /proc)."""
    total = 0
    todo = [pid]
    seen = set()
    while todo:
        p = todo.pop()
        if p in seen:
            continue
        seen.add(p)
        try:
            with open(f'/proc/{p}/status') as f:
                for line in f:
                    if line.startswith('VmRSS:'):
                        total += int(line.split()[1]) * 1024
            for tid in os.listdir(f'/proc/{p}/task'):   # children of every thread, not only
                with open(f'/proc/{p}/task/{tid}/children') as f:   # the main one (Dask's
                    todo += [int(c) for c in f.read().split()]      # nannies start elsewhere)
        except OSError:
            continue
    return total / 2 ** 20


def _engine(name: str, n_noop: int, spec_path: str) -> dict:
    """Run in a child interpreter: one engine's figures."""
    from im_studies import campaign_pool, campaign_spec
    spec = campaign_spec.read_spec(spec_path)
    jobs = campaign_spec.jobs(spec)
    gains = campaign_spec.gain_arguments(spec)
    workers = os.cpu_count() or 1
    t0 = time.perf_counter()
    if name == 'process_pool':
        from concurrent.futures import ProcessPoolExecutor
        ex = ProcessPoolExecutor(workers)
        ex.submit(_noop, 1).result()
        start = time.perf_counter() - t0
        t0 = time.perf_counter()
        list(ex.map(_noop, range(n_noop), chunksize=1))
        per_task = (time.perf_counter() - t0) / n_noop
        t0 = time.perf_counter()
        list(ex.map(campaign_spec.run_job, jobs, [spec] * len(jobs), [gains] * len(jobs)))
        runs = time.perf_counter() - t0
        mem = _rss_mb(os.getpid())
        ex.shutdown()
    elif name == 'dask':
        with campaign_pool.Pool(workers) as pool:
            pool.client.submit(_noop, 1, pure=False).result()
            start = time.perf_counter() - t0
            t0 = time.perf_counter()
            pool.client.gather(pool.client.map(_noop, range(n_noop), pure=False))
            per_task = (time.perf_counter() - t0) / n_noop
            t0 = time.perf_counter()
            for _ in pool.map(campaign_spec.run_job, jobs, spec, gains):
                pass
            runs = time.perf_counter() - t0
            mem = _rss_mb(os.getpid())
    else:
        import ray
        ray.init(num_cpus=workers, include_dashboard=False, log_to_driver=False,
                 logging_level='ERROR')
        noop = ray.remote(_noop)
        ray.get(noop.remote(1))
        start = time.perf_counter() - t0
        t0 = time.perf_counter()
        ray.get([noop.remote(i) for i in range(n_noop)])
        per_task = (time.perf_counter() - t0) / n_noop
        run = ray.remote(campaign_spec.run_job)
        s_ref, g_ref = ray.put(spec), ray.put(gains)
        t0 = time.perf_counter()
        ray.get([run.remote(j, s_ref, g_ref) for j in jobs])
        runs = time.perf_counter() - t0
        mem = _rss_mb(os.getpid())
        ray.shutdown()
    return {'startup_s': start, 'per_task_ms': per_task * 1e3, 'memory_mb': mem,
            'runs_s': runs, 'runs': len(jobs), 'workers': workers}


RAY_MISSING = 'ray is not installed (make bench installs benchmarks/requirements.txt)'


def ray_installed() -> bool:
    import importlib.util
    return importlib.util.find_spec('ray') is not None


def _child(name: str, n_noop: int, spec_path: str) -> dict:
    p = subprocess.run([sys.executable, __file__, name, str(n_noop), spec_path],
                       capture_output=True, text=True, timeout=900)
    if p.returncode != 0:
        tail = (p.stderr.strip().splitlines() or ['?'])[-1]
        raise RuntimeError(f'{name} engine benchmark failed: {tail}')
    return json.loads(p.stdout.strip().splitlines()[-1])


def _campaign_wall(spec_path: str, workers: int, out: str) -> float:
    from im_studies.campaign import run_campaign
    from im_studies.campaign_spec import read_spec
    s = run_campaign(read_spec(spec_path), out, spec_path, workers=workers,
                     progress=False)
    return s['wall_s']


def run(quick: bool = False) -> dict:
    """
    Full: every row (Ray must be installed: ``make bench`` installs it).

    ``quick`` (a smoke test, seconds): 4 runs per engine, 100 empty tasks, campaigns of 4 runs;
    without Ray the Ray row is skipped with its reason (``engine_ray_skipped``).
    """
    res: dict = {}
    cores = os.cpu_count() or 1
    with tempfile.TemporaryDirectory() as tmp:
        engine_spec = _spec(tmp, 4 if quick else 16, 0.1 if quick else 0.5)
        for name in ('process_pool', 'dask', 'ray'):
            if name == 'ray' and not ray_installed():
                if not quick:
                    raise RuntimeError(f'campaign benchmark: {RAY_MISSING}')
                print(f'[bench] campaign engine ray skipped: {RAY_MISSING}', file=sys.stderr)
                res['engine_ray_skipped'] = RAY_MISSING
                continue
            print(f'[bench] campaign engine: {name}', file=sys.stderr, flush=True)
            r = _child(name, 100 if quick else 2000, engine_spec)
            for k in ('startup_s', 'per_task_ms', 'memory_mb', 'runs_s'):
                if k in r:
                    res[f'engine_{name}_{k}'] = r[k]
        sizes = (4,) if quick else (16, 32, 64)
        for n in sizes:
            spec_path = _spec(tmp, n, 0.1 if quick else 0.5)
            for w in sorted({1, cores}):
                print(f'[bench] campaign: {n} runs on {w} worker(s)', file=sys.stderr,
                      flush=True)
                res[f'campaign_{n}_runs_{w}_workers_wall_s'] = _campaign_wall(
                    spec_path, w, os.path.join(tmp, f'out_{n}_{w}'))
        n = sizes[-1]
        res[f'campaign_{n}_runs_speedup_{cores}_workers'] = (
            res[f'campaign_{n}_runs_1_workers_wall_s']
            / res[f'campaign_{n}_runs_{cores}_workers_wall_s'])
    return res


if __name__ == '__main__':
    if len(sys.argv) == 4:
        print(json.dumps(_engine(sys.argv[1], int(sys.argv[2]), sys.argv[3])))
    else:                           # the table and JSON come from the driver
        from run_all import main
        sys.exit(main(['--only', 'campaign'] + sys.argv[1:]))
