"""
The campaign's results (docs/campaign.md): the runs table, the summary and the report.

That is ``runs.parquet`` (one row per run), the summary and ``report.md`` with its histograms,
stability map and worst runs.
"""
from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Dict, List

from im_controller.gain_design.motor import THESIS_K1
from im_recording.bag import write_atomic
from im_recording.plots import pyplot
import numpy as np

from .campaign_journal import versions
from .campaign_pool import wall_line
from .campaign_spec import COMMISSION_TASK, DRAWN, FIGURES, spec_hash, UNSTABLE
from .commission_sim import COMPARED

COLUMNS = (('index', 'int64'), ('draw', 'int64'), ('task', 'string'), ('strategy', 'string'),
           ('controller', 'string'),
           ('gain_set', 'string'), ('T_s', 'float64'), ('load', 'string'), ('profile', 'string'),
           *((k, 'float64') for k in DRAWN), ('sigma', 'float64'), ('sigma_L_s', 'float64'),
           ('status', 'string'),
           ('trip', 'string'), ('t_end_s', 'float64'), ('error', 'string'),
           *((k, 'float64') for k in FIGURES), ('wall_s', 'float64'),
           # the commissioning axis (``commission: true``): identified/true − 1 and the reported
           # standard deviation [%] of each commissioned parameter (null on the runs' rows)
           *((n + x, 'float64') for n in COMPARED for x in ('_err_pct', '_std_pct')))


def write_parquet(rows: List[dict], path: Path, metadata: dict) -> None:
    import pyarrow as pa                # heavy: pyarrow, only for runs.parquet
    import pyarrow.parquet as pq        # heavy: as above
    types = {'int64': pa.int64(), 'float64': pa.float64(), 'string': pa.string()}
    schema = pa.schema([(k, types[t]) for k, t in COLUMNS],
                       metadata={k: json.dumps(v) for k, v in metadata.items()})
    table = pa.Table.from_pylist([{k: r.get(k) for k, _ in COLUMNS} for r in rows], schema=schema)
    tmp = path.with_name('.' + path.name + '.tmp')
    pq.write_table(table, tmp)
    os.replace(tmp, path)


def read_rows(path) -> List[dict]:
    """Rows of a campaign's ``runs.parquet`` in index order."""
    import pyarrow.parquet as pq        # heavy: pyarrow, only for runs.parquet
    return pq.read_table(path).to_pylist()


def replay_command(spec_path: str, index: int) -> str:
    return f'ros2 run im_studies campaign {spec_path} --run {index}'


def split_commissioning(rows: List[dict]):
    """Split a campaign's rows into (the runs' rows, the commissioning rows)."""
    return ([r for r in rows if r['task'] != COMMISSION_TASK],
            [r for r in rows if r['task'] == COMMISSION_TASK])


def commissioning_summary(rows: List[dict]) -> dict:
    """
    Summarize the commissioning rows of a campaign.

    Per draw each parameter's error and reported std [%], and per parameter the largest
    |error| and the median |error|/std over the draws that were identified.
    """
    draws = [{'draw': r['draw'], 'index': r['index'], 'status': r['status'],
              'error': r['error'], 'sigma': r['sigma'],
              **{n + x: r[n + x] for n in COMPARED for x in ('_err_pct', '_std_pct')}}
             for r in rows]
    ok = [d for d in draws if d['status'] == 'ok']
    return {'draws': draws, 'identified': len(ok), 'refused': len(draws) - len(ok),
            'max_abs_err_pct': {n: max((abs(d[n + '_err_pct']) for d in ok), default=None)
                                for n in COMPARED},
            'median_err_over_std': {n: float(np.median([abs(d[n + '_err_pct']) / d[n + '_std_pct']
                                                        for d in ok])) if ok else None
                                    for n in COMPARED}}


def summarize(rows: List[dict], spec: dict, info: dict, spec_path: str) -> dict:
    rows, commissioned = split_commissioning(rows)
    by_set: Dict[str, dict] = {}
    for g in spec['gain_sets']:
        rs = [r for r in rows if r['gain_set'] == g['name']]
        ok = [r for r in rs if r['status'] == 'ok']

        def pct(key, rr=ok):
            v = np.array([r[key] for r in rr if math.isfinite(r[key])])
            return ({'p50': float(np.percentile(v, 50)), 'p95': float(np.percentile(v, 95)),
                     'max': float(v.max())} if v.size else None)
        by_set[g['name']] = {
            'T_s': g['T_s'], 'gains': g['gains'] if g['gains'] in ('thesis', 'certified')
            else os.path.basename(g['gains']),
            'runs': len(rs), 'ok': len(ok),
            'unstable': sum(r['status'] in UNSTABLE for r in rs),
            'failed': sum(r['status'] == 'failed' for r in rs),
            'unstable_draws': sorted({r['draw'] for r in rs if r['status'] in UNSTABLE}),
            'E_loss_J': pct('E_loss_J'), 'pos_err_max_rad': pct('pos_err_max_rad'),
            'speed_err_max_rad_s': pct('speed_err_max_rad_s')}
    groups = []     # per gain set × controller × task × strategy: the spread of the figures
    for g in spec['gain_sets']:
        for c in spec['controllers']:
            for task in spec['tasks']:
                for strategy in spec['strategies']:
                    rs = [r for r in rows if (r['gain_set'], r['controller'], r['task'],
                                              r['strategy']) == (g['name'], c, task, strategy)]
                    ok = [r for r in rs if r['status'] == 'ok']
                    err = 'pos_err_rms_rad' if task == 'position' else 'speed_err_rms_rad_s'
                    if task == 'torque':
                        err = 'torque_err_max_Nm'
                    groups.append({'gain_set': g['name'], 'controller': c, 'task': task,
                                   'strategy': strategy, 'runs': len(rs), 'ok': len(ok),
                                   'unstable': sum(r['status'] in UNSTABLE for r in rs),
                                   'error_figure': err, err: pct(err, ok),
                                   'E_loss_J': pct('E_loss_J', ok)})
    worst = sorted(rows, key=_badness, reverse=True)[:spec['worst']]
    out = {'name': spec['name'], 'spec_hash': spec_hash(spec), 'seed': spec['seed'],
           'draws': spec['draws'], 'runs': len(rows),
           'failed': sum(r['status'] == 'failed' for r in rows),
           'failures': [{'index': r['index'], 'error': r['error'],
                         'replay': replay_command(spec_path, r['index'])}
                        for r in rows if r['status'] == 'failed'],
           **info,
           **{f'unstable_{n}': s['unstable'] for n, s in by_set.items()},
           'gain_sets': by_set,
           'groups': groups,
           'worst': [{'index': r['index'], 'draw': r['draw'], 'task': r['task'],
                      'strategy': r['strategy'], 'controller': r['controller'],
                      'gain_set': r['gain_set'],
                      'status': r['status'], 'trip': r['trip'], 'error': r['error'],
                      'pos_err_max_rad': r['pos_err_max_rad'],
                      'speed_err_max_rad_s': r['speed_err_max_rad_s'],
                      **{k: r[k] for k in DRAWN}, 'sigma': r['sigma'],
                      'sigma_L_s': r['sigma_L_s'],
                      'replay': replay_command(spec_path, r['index'])} for r in worst],
           'versions': versions()}
    if commissioned:
        out['commissioning'] = commissioning_summary(commissioned)
    return out


def _badness(r: dict) -> tuple:
    """
    Return the sort key of 'worst runs'.

    Unstable first (earliest end first), then failures, then the
    largest tracking error relative to the task's own scale.
    """
    rank = {'diverged': 3, 'tripped': 3, 'failed': 2, 'ok': 0}[r['status']]
    err = r['pos_err_max_rad'] if r['task'] == 'position' else r['speed_err_max_rad_s'] / 10.0
    err = err if math.isfinite(err) else 0.0
    t_end = r['t_end_s'] if math.isfinite(r['t_end_s']) else 0.0
    return (rank, -t_end if rank == 3 else err)


def _histograms(plt, rows: List[dict], spec: dict, sets: List[str], out: Path):
    """Draw histograms.png (losses and errors of the stable runs); return it and its caption."""
    colors = dict(zip(sets, plt.rcParams['axes.prop_cycle'].by_key()['color']))
    panels = [('E_loss_J', 'losses E_loss [J]')]
    if 'position' in spec['tasks']:
        panels.append(('pos_err_max_rad', 'max position error [rad]'))
    if 'speed' in spec['tasks']:
        panels.append(('speed_err_max_rad_s', 'max speed error [rad/s]'))
    fig, axes = plt.subplots(len(spec['tasks']), len(panels),
                             figsize=(4.2 * len(panels), 3.2 * len(spec['tasks'])), squeeze=False)
    for ti, task in enumerate(spec['tasks']):
        for pi, (key, label) in enumerate(panels):
            ax = axes[ti][pi]
            for s in sets:
                v = np.array([r[key] for r in rows if r['task'] == task and r['gain_set'] == s
                              and r['status'] == 'ok' and math.isfinite(r[key])])
                if v.size:
                    ax.hist(v, bins=30, alpha=0.6, color=colors[s], label=f'{s} ({v.size})')
            ax.set_xlabel(label)
            ax.set_title(f'{task} task', fontsize=9)
            if ax.get_legend_handles_labels()[0]:
                ax.legend(fontsize=7)
            else:   # e.g. the position error of the speed task: the task has no such figure
                ax.set_axis_off()
                ax.text(0.5, 0.5, f'{task} task: no {label.split(" [")[0]}', ha='center',
                        va='center', transform=ax.transAxes, fontsize=9, color='0.4')
    fig.tight_layout()
    fig.savefig(out / 'histograms.png', dpi=110)
    plt.close(fig)
    return 'histograms.png', 'Losses and tracking errors of the stable runs'


def _stability_map(plt, rows: List[dict], summary: dict, spec: dict, sets: List[str], out: Path):
    """Draw stability_map.png (every run of each gain set); return it and its caption."""
    x, y = spec['map']
    fig, axes = plt.subplots(1, len(sets), figsize=(4.5 * len(sets), 3.8), squeeze=False)
    for ax, s in zip(axes[0], sets):
        rs = [r for r in rows if r['gain_set'] == s]
        for status, marker, col in (('ok', '.', 'tab:green'), ('tripped', 'x', 'tab:red'),
                                    ('diverged', 'x', 'tab:purple'), ('failed', 's', 'k')):
            pts = [(r[x], r[y]) for r in rs if r['status'] == status]
            if pts:
                a = np.array(pts)
                ax.scatter(a[:, 0], a[:, 1], marker=marker, c=col, s=14,
                           label=f'{status} ({len(pts)})')
        g = summary['gain_sets'][s]
        if g['gains'] == 'thesis' and 'sigma_L_s' in (x, y):
            # the thesis's scalar current gain k1 on σL_s: discrete pole 1 − k1·T_s/(σL_s)
            # leaves the unit circle below σL_s = k1·T_s/2 (docs/campaign.md)
            edge = THESIS_K1 * g['T_s'] / 2.0
            (ax.axvline if x == 'sigma_L_s' else ax.axhline)(
                edge, ls='--', c='tab:red', lw=0.8, label=f'k1·T_s/2 = {edge * 1e3:.3g} mH')
        ax.set_xlabel(x)
        ax.set_ylabel(y)
        ax.set_title(f'{s} (T_s = {g["T_s"] * 1e6:g} µs): {g["unstable"]} unstable', fontsize=9)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / 'stability_map.png', dpi=110)
    plt.close(fig)
    return 'stability_map.png', f'Stability over ({x}, {y}), every run of each gain set'


def write_report(rows: List[dict], summary: dict, spec: dict, out: Path) -> None:
    """report.md with loss and error histograms, the stability map and the worst runs."""
    plt = pyplot()
    rows, _ = split_commissioning(rows)
    figs = []
    sets = [g['name'] for g in spec['gain_sets']]
    figs.append(_histograms(plt, rows, spec, sets, out))
    figs.append(_stability_map(plt, rows, summary, spec, sets, out))
    lines = [f"# Campaign {summary['name']}", '',
             f"{summary['runs']} runs ({summary['draws']} draws, seed {summary['seed']}, spec "
             f"{summary['spec_hash']}) on {summary.get('workers', '?')} Dask worker(s) "
             f"({summary.get('address', 'local')}); failures: {summary['failed']}.", '',
             '| gain set | T_s [µs] | runs | stable | unstable | failed | losses p50 / p95 [J] '
             '| pos. err max p95 [mrad] | speed err max p95 [rad/s] |',
             '| --- | ---: | ---: | ---: | ---: | ---: | --- | ---: | ---: |']
    for s, g in summary['gain_sets'].items():
        def p(key, field, scale=1.0):
            v = g.get(key)
            return '—' if not v else f'{v[field] * scale:.3g}'
        lines.append(f"| {s} | {g['T_s'] * 1e6:g} | {g['runs']} | {g['ok']} | {g['unstable']} "
                     f"| {g['failed']} | {p('E_loss_J', 'p50')} / {p('E_loss_J', 'p95')} | "
                     f"{p('pos_err_max_rad', 'p95', 1e3)} | {p('speed_err_max_rad_s', 'p95')} |")
    units = {'pos_err_rms_rad': ('position RMS', 'mrad', 1e3),
             'speed_err_rms_rad_s': ('speed RMS', 'rad/s', 1.0),
             'torque_err_max_Nm': ('torque max', 'N·m', 1.0)}
    lines += ['', '| gain set | controller | task | strategy | runs | unstable | error p50 / p95 '
              '/ max | losses p50 [J] |', '| --- | --- | --- | --- | ---: | ---: | --- | ---: |']
    for g in summary['groups']:
        name, unit, scale = units[g['error_figure']]
        e = g[g['error_figure']]
        err = (f'{e["p50"] * scale:.3g} / {e["p95"] * scale:.3g} / {e["max"] * scale:.3g} '
               f'{unit} ({name})' if e else '—')
        loss = f'{g["E_loss_J"]["p50"]:.1f}' if g['E_loss_J'] else '—'
        lines.append(f"| {g['gain_set']} | {g['controller']} | {g['task']} | {g['strategy']} | "
                     f"{g['runs']} | {g['unstable']} | {err} | {loss} |")
    if 'speedup_vs_one_worker' in summary:
        lines += ['', f"Speed-up: {summary['speedup_runs']} runs took "
                      f"{summary['speedup_wall_1_worker_s']:.1f} s on 1 worker and "
                      f"{summary['speedup_wall_all_workers_s']:.1f} s on "
                      f"{summary['speedup_workers']}: ×{summary['speedup_vs_one_worker']:.2f}."]
    if 'real_plant_kernel' in summary:
        lines += ['', f"This invocation: {summary['runs_this_invocation']} runs, "
                      f'{wall_line(summary)}.']
    lines += ['']
    for f, caption in figs:
        lines += [f'![{caption}]({f})', '', f'*{caption}*', '']
    lines += ['## Worst runs', '', '| index | task | strategy | controller | gain set | status | '
              'why / error | ' + ' | '.join(DRAWN) + ' | σ | σL_s [mH] | replay alone |',
              '| ---: | --- | --- | --- | --- | --- | --- |' + ' ---: |' * (len(DRAWN) + 2)
              + ' --- |']
    for w in summary['worst']:
        why = w['trip'] or w['error'] or (
            f"pos. err {w['pos_err_max_rad'] * 1e3:.3g} mrad" if w['task'] == 'position'
            else f"speed err {w['speed_err_max_rad_s']:.3g} rad/s")
        lines.append(f"| {w['index']} | {w['task']} | {w['strategy']} | {w['controller']} | "
                     f"{w['gain_set']} | {w['status']} | "
                     f"{why.replace('|', '∣')} | "
                     + ' | '.join(f'{w[k]:.4g}' for k in DRAWN)
                     + f" | {w['sigma']:.3f} | {w['sigma_L_s'] * 1e3:.3f} | `{w['replay']}` |")
    if 'commissioning' in summary:
        lines += commissioning_lines(summary['commissioning'])
    write_atomic(out / 'report.md', '\n'.join(lines) + '\n')


COMPARED_LABELS = {'R_s': 'R_s', 'L_sigma': 'σL_s', 'L_M': 'L_M', 'R_R': 'R_R', 'J': 'J'}


def commissioning_lines(c: dict) -> List[str]:
    """Write the report's commissioning section: identified/true − 1 ± reported std per draw."""
    names = [COMPARED_LABELS[n] for n in COMPARED]
    lines = ['', '## Commissioning', '',
             f'Each draw commissioned on the ROS-free plant (docs/commissioning.md): '
             f"{c['identified']} identified, {c['refused']} refused. Errors are "
             'identified/true − 1 ± the reported standard deviation.', '',
             '| draw | σ | ' + ' | '.join(names) + ' |',
             '| ---: | ---: |' + ' ---: |' * len(names)]
    for d in c['draws']:
        if d['status'] != 'ok':
            lines.append(f"| {d['draw']} | {d['sigma']:.3f} | refused: "
                         f"{d['error'].replace('|', '∣')} |" + ' |' * (len(names) - 1))
            continue
        lines.append(f"| {d['draw']} | {d['sigma']:.3f} | " + ' | '.join(
            f"{d[n + '_err_pct']:+.3f} ± {d[n + '_std_pct']:.3f} %" for n in COMPARED) + ' |')
    worst = c['max_abs_err_pct']
    lines.append('| largest \\|error\\| | | ' + ' | '.join(
        '—' if worst[n] is None else f'{worst[n]:.3f} %' for n in COMPARED) + ' |')
    return lines
