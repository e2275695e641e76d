"""
Campaigns: Monte Carlo validation of the drive over a parameter box (docs/campaign.md).

    ros2 run im_studies campaign SPEC.yaml [--out DIR] [--workers N | --address tcp://HOST:8786]
    ros2 run im_studies campaign SPEC.yaml --run INDEX [--graph] [--record BAG]   # one run alone

A spec (YAML) names the parameter box or distributions of the plant's motor, the number of draws,
the tasks, strategies, gain sets (each with its period), loads, profiles and the seed. Every draw
is a motor; every run is one draw × task × strategy × controller × gain set × load × profile,
executed by the
ROS-free loop (``im_bringup.offline``; same numbers as the graph) or, with ``mode: graph``, by
the in-process ROS graph. Runs are Dask tasks on a local cluster of every core, or on an existing
Dask scheduler (``--address``); Dask was chosen over Ray by ``benchmarks/bench_campaign.py``.

Every column of a row but ``wall_s`` is a function of (spec, index): the same spec and seed give
the same rows on any number of workers. Each finished run is appended to ``DIR/rows.jsonl`` (and
synced) before the next is counted, so a killed campaign resumes where it stopped with the same
command and runs nothing twice. At the end: ``DIR/runs.parquet`` (one row per run; spec, seed and
versions in its metadata), ``DIR/summary.json``, ``DIR/report.md`` with figures.

The jobs live in their modules: ``campaign_spec`` (reading and checking a spec, drawing the motors,
one run), ``campaign_pool`` (the Dask pool, also used by the studies), ``campaign_journal`` (the
journal, resumption, versions) and ``campaign_report`` (Parquet, summary, report); this module
runs a campaign from them and is the ``ros2 run im_studies campaign`` command.
"""
from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
import sys
import time
from typing import List, Optional

from im_bringup.scenario import run_scenario
from im_common.cli import error as cli_error, logger, parse_args
from im_recording.bag import write_atomic
from im_recording.report import jsonable
import numpy as np

from .campaign_journal import JOURNAL, Journal, prepare_out, versions
from .campaign_pool import log_progress, Pool, wall_line, WallTime
from .campaign_report import summarize, write_parquet, write_report
from .campaign_spec import (gain_arguments, graph_scenario, jobs, read_spec, run_job, spec_hash,
                            SpecError)

_log = logger('campaign')


def measure_speedup(all_jobs: List[dict], spec: dict, gains: dict, n: int,
                    workers: Optional[int], progress: bool) -> dict:
    """Wall time of the same ``n`` runs (spread over the campaign) on 1 worker and on all."""
    idx = np.linspace(0, len(all_jobs) - 1, min(n, len(all_jobs))).round().astype(int)
    subset = [all_jobs[i] for i in sorted(set(idx.tolist()))]
    walls = {}
    for w in (1, workers or os.cpu_count() or 1):
        with Pool(w) as pool:
            t0 = time.perf_counter()
            for _ in pool.map(run_job, subset, spec, gains):
                pass
            walls[w] = time.perf_counter() - t0
        if progress:
            _log(f'speed-up subset: {len(subset)} runs on {w} worker(s) in {walls[w]:.1f} s')
    one, many = walls[1], walls[max(walls)]
    return {'speedup_vs_one_worker': one / many, 'speedup_runs': len(subset),
            'speedup_wall_1_worker_s': one, 'speedup_wall_all_workers_s': many,
            'speedup_workers': max(walls)}


def run_campaign(spec: dict, out: str, spec_path: str, workers: Optional[int] = None,
                 address: Optional[str] = None, force: bool = False,
                 progress: bool = True) -> dict:
    """Run (or resume) a campaign into ``out``; returns the summary (also written)."""
    out_p = Path(out)
    done = prepare_out(out_p, spec, force)
    all_jobs = jobs(spec)
    gains = gain_arguments(spec)
    todo = [j for j in all_jobs if j['index'] not in done]
    if progress:
        _log(f"{spec['name']}: {len(all_jobs)} runs ({spec['draws']} draws), "
             f'{len(done)} already done, {len(todo)} to run')
    info: dict = {}
    sp_file = out_p / 'speedup.json'
    if spec['speedup_runs'] and not address:
        if sp_file.exists():
            info.update(json.loads(sp_file.read_text()))
        else:
            info.update(measure_speedup(all_jobs, spec, gains, spec['speedup_runs'], workers,
                                        progress))
            write_atomic(sp_file, json.dumps(info, indent=2))
    journal = Journal(out_p / JOURNAL)
    clock = WallTime()
    failed = 0
    try:
        with Pool(workers, address) as pool:
            info.update(engine='dask', address=address or 'local', workers=pool.n_workers,
                        startup_s=pool.startup_s)
            clock.parts['pool_startup'] = pool.startup_s
            t_run = time.perf_counter()
            last = 0.0
            for k, (_, row) in enumerate(pool.map(run_job, todo, spec, gains), 1):
                journal.append(row)
                done[row['index']] = row
                failed += row['status'] == 'failed'
                now = time.perf_counter()
                if progress and (now - last > 2.0 or k == len(todo)):
                    last = now
                    log_progress(spec['name'], len(done), len(all_jobs), failed, now - t_run)
            info['run_wall_s'] = clock.parts['runs'] = time.perf_counter() - t_run
    finally:
        journal.close()
    info.update(clock.figures())
    info['runs_this_invocation'] = len(todo)
    rows = [done[i] for i in sorted(done)]
    meta = {'spec': spec, 'spec_hash': spec_hash(spec), 'seed': spec['seed'],
            'versions': versions(), 'engine': 'dask'}
    write_parquet(rows, out_p / 'runs.parquet', meta)
    summary = summarize(rows, spec, info, spec_path)
    write_atomic(out_p / 'summary.json', json.dumps(jsonable(summary), indent=2,
                                                    allow_nan=False))
    write_report(rows, summary, spec, out_p)
    return summary


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog='campaign', description=__doc__.split('\n\n')[0])
    ap.add_argument('spec', help='campaign spec (YAML); see docs/campaign.md')
    ap.add_argument('--out', help='output folder (default bags/campaign/<spec name>)')
    ap.add_argument('--workers', type=int, help='local worker processes (default: every core)')
    ap.add_argument('--address', help='an existing Dask scheduler, e.g. tcp://10.0.0.5:8786')
    ap.add_argument('--force', action='store_true',
                    help='start over in an --out that holds another campaign')
    ap.add_argument('--run', type=int, metavar='INDEX', help='run only this index, alone, in '
                    'this process, and print its row (the worst runs list this command)')
    ap.add_argument('--graph', action='store_true', help='with --run: through the ROS graph')
    ap.add_argument('--record', help='with --run --graph: record the run to this MCAP file')
    ap.add_argument('--no-progress', action='store_true')
    return ap


def _run_alone(spec: dict, args) -> int:
    all_jobs = jobs(spec)
    if not 0 <= args.run < len(all_jobs):
        return cli_error('campaign',
                         f'--run {args.run}: the campaign has runs 0..{len(all_jobs) - 1}')
    job = all_jobs[args.run]
    gains = gain_arguments(spec)
    if args.record:
        s = run_scenario(graph_scenario(job, spec, gains), record=args.record,
                         progress=not args.no_progress)
        print(f"recorded {args.record}; ok={s.get('ok')}, E_in = {s.get('E_in_J')}")
        return 0
    row = run_job(job, dict(spec, mode='graph' if args.graph else spec['mode']), gains,
                  alone=True)
    for k, v in row.items():
        print(f'  {k:22s} {v}')
    return 0


def main(argv=None) -> int:
    args = parse_args(build_parser(), argv)
    try:
        spec = read_spec(args.spec)
    except SpecError as exc:
        return cli_error('campaign', exc)
    if args.workers is not None and args.workers < 1:
        return cli_error('campaign', f'--workers {args.workers}: must be >= 1')
    if args.record and not (args.run is not None and args.graph):
        return cli_error('campaign', '--record needs --run INDEX --graph')
    try:
        if args.run is not None:
            return _run_alone(spec, args)
        out = args.out or os.path.join('bags', 'campaign', spec['name'])
        s = run_campaign(spec, out, args.spec, workers=args.workers, address=args.address,
                         force=args.force, progress=not args.no_progress)
    except (SpecError, FileExistsError, ConnectionError) as exc:
        return cli_error('campaign', exc)
    except KeyboardInterrupt:
        print(f'\ninterrupted; finished runs are kept in {out}/{JOURNAL}: the same command '
              'resumes the campaign', file=sys.stderr)
        return 130
    for n, g in s['gain_sets'].items():
        print(f"{n:>12s} (T_s = {g['T_s'] * 1e6:g} µs): {g['runs']} runs, {g['unstable']} "
              f"unstable, {g['failed']} failed")
    if 'speedup_vs_one_worker' in s:
        print(f"speed-up vs one worker: ×{s['speedup_vs_one_worker']:.2f}")
    print(f'written: {out}/runs.parquet, {out}/summary.json, {out}/report.md')
    print(wall_line(s))
    return 0


if __name__ == '__main__':
    sys.exit(main())
