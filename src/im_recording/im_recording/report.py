"""
Figures of merit and figures from recorded runs.

``ros2 run im_recording report bags/a.mcap [more.mcap ...] [--out DIR] [--no-plots]``

writes ``DIR/report.md`` (a Markdown table, one column per run), ``DIR/report.json`` (the same
numbers with the runs' metadata) and PNG figures in the style of seed 000 (:mod:`.plots`), and
prints where they are. Default DIR: ``<first bag without .mcap>_report``.

The numbers come from :mod:`im_common.metrics` (tracking errors, peaks) and
:func:`im_common.metrics.energy_summary` (energy books), plus parameter-estimate errors when an
adapter ran. An unreadable bag is a one-line error and exit code 2.
"""
from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
import sys
from typing import Dict, List, Sequence

from im_common import topics as T
from im_common.cli import error as cli_error, parse_args
from im_common.lockstep_protocol import FAILED, FINISHED, STOPPED
from im_common.metrics import balance_relative, energy_figures, LOAD_STEP_BAND
import numpy as np

from .bag import BagError, check_output, write_atomic
from .plots import all_figures
from .recorded_run import load_run, RunningFigures

# (key, label, unit) rows of the table, in order; absent keys are skipped.
ROWS = [
    ('E_in_J', 'energy drawn E_in', 'J'),
    ('E_dc_J', "energy drawn from the DC link (E_in + the inverter's losses)", 'J'),
    ('E_inverter_J', 'inverter losses (conduction + switching)', 'J'),
    ('E_switching_J', 'inverter switching losses', 'J'),
    ('E_loss_J', 'losses (copper + core)', 'J'),
    ('E_copper_J', 'copper losses', 'J'),
    ('E_core_J', 'core losses', 'J'),
    ('W_load_J', 'work on the load', 'J'),
    ('E_friction_J', 'friction', 'J'),
    ('dE_kinetic_J', 'Δ kinetic energy', 'J'),
    ('dW_magnetic_J', 'Δ magnetic energy', 'J'),
    ('E_param_J', 'parameter-variation energy', 'J'),
    ('balance_residual_J', 'energy balance residual', 'J'),
    ('balance_relative', 'balance residual / E_in', '—'),
    ('pos_err_max_rad', 'position error max', 'rad'),
    ('pos_err_rms_rad', 'position error RMS', 'rad'),
    ('speed_err_max_rad_s', 'speed error max', 'rad/s'),
    ('speed_err_rms_rad_s', 'speed error RMS', 'rad/s'),
    ('load_step_t', 'load step at', 's'),
    ('speed_dip_rad_s', 'speed dip after the load step (max |ω − ω*|)', 'rad/s'),
    ('speed_recovery_s', f'recovery: back within {LOAD_STEP_BAND:g} rad/s for good (NaN: not by '
                         'the end)', 's'),
    ('torque_err_max_Nm', 'torque error max', 'N·m'),
    ('torque_err_rms_Nm', 'torque error RMS', 'N·m'),
    ('flux_err_max_Wb', 'flux tracking error max', 'Wb'),
    ('flux_err_rms_Wb', 'flux tracking error RMS', 'Wb'),
    ('flux_est_err_max_Wb', 'flux estimate error max', 'Wb'),
    ('flux_est_err_rms_Wb', 'flux estimate error RMS', 'Wb'),
    ('R_r_est_err_max', 'R_r estimate error max', 'Ω'),
    ('R_r_est_err_rms', 'R_r estimate error RMS', 'Ω'),
    ('R_r_est_err_final_rel', 'R_r estimate error at end (relative)', '—'),
    ('theta_est_err_max', 'θ estimate error max', '—'),
    ('theta_est_err_rms', 'θ estimate error RMS', '—'),
    ('theta_est_err_final_rel', 'θ estimate error at end (relative)', '—'),
    ('L_M_est_err_max', 'L_M estimate error max', 'H'),
    ('L_M_est_err_final_rel', 'L_M estimate error at end (relative)', '—'),
    ('R_R_est_err_max', 'R_R estimate error max', 'Ω'),
    ('R_R_est_err_final_rel', 'R_R estimate error at end (relative)', '—'),
    ('V_max_V', 'voltage peak |V_s|', 'V'),
    ('i_max_A', 'current peak |i_s|', 'A'),
    ('duration_s', 'recorded duration', 's'),
    ('steps', 'steps integrated by the plant', '—'),
]


def _finite(x):
    x = np.asarray(x, float)
    return x[np.isfinite(x)]


def estimate_figures(trace, last_window: float = 1.0) -> Dict[str, float]:
    """
    Each adapted parameter against the truth.

    Max / RMS / final relative error, the final values (``<n>_hat_final``, ``<n>_true_final``),
    and over the last ``last_window`` seconds the relative RMS and peak-to-peak of the error
    (issue targets: < 5 %).
    """
    acc = RunningFigures(last_window)
    acc.rows(trace)
    return acc.estimates()


def figures_of_merit(run) -> Dict[str, float]:
    """
    Every figure of merit a run's recording supports, over every control instant.

    From the run's running figures when it was streamed
    (:func:`im_recording.recorded_run.stream_run`), else from its trace.
    """
    acc = run.running
    if acc is None:
        acc = RunningFigures()
        acc.rows(run.trace)
    fig: Dict[str, float] = dict(acc.tracking(run.task))
    fig.update(acc.load_step_figures())
    need = ('E_in', 'E_cu_s', 'E_cu_r', 'E_core', 'E_friction', 'W_load', 'E_param',
            'dE_kin', 'dW_mag', 'balance_residual')
    if all(k in run.truth_final for k in need):
        fig.update(energy_figures(run.truth_final))
        fig['balance_relative'] = balance_relative(fig)
    fig.update(acc.estimates())
    if acc.steps:
        fig['duration_s'] = float(acc.t_last - acc.t_first)
        # the plant's integration steps from the first to the last control instant recorded (the
        # instants less one: a run of 2 s at 100 µs is 20,000 steps between 20,001 instants), the
        # count the in-process graph and the plant's 'finished' event give
        fig['steps'] = int(acc.steps) - 1
    return fig


def run_status(run, fig: Dict[str, float]) -> dict:
    """
    Whether a recording holds the whole run.

    ``interrupted`` (stopped by a signal), ``partial`` (the run ended before its duration — a
    node failed or stopped it, a signal interrupted it, the recorder did not see it finish — or
    the file was recovered from a damaged one, or holds fewer control steps than its duration
    asks), ``ended`` (the failed/stopped events, with their reasons), ``gaps`` (lock-step
    topics without a message at some control instants, with the ranges), and one human-readable
    note per finding in ``notes``.
    """
    md = run.metadata
    recording = md.get('recording', {})     # im_recording.session: the same on both paths
    notes: List[str] = []
    st: dict = {'interrupted': None, 'partial': False, 'ended': [], 'gaps': {}, 'notes': notes}
    if recording.get('interrupted'):
        st['interrupted'] = recording['interrupted']
        st['partial'] = True
        notes.append(f"interrupted by {st['interrupted']} at step "
                     f"{recording.get('counted_to_step', '?')}")
    for e in run.events:
        if e['state'] in (FAILED, STOPPED):
            st['partial'] = True
            st['ended'].append(e)
            notes.append(f"{e['node']} {e['state']} at t = {e['t']:.6f} s"
                         + (f": {e['reason']}" if e['reason'] else ''))
    run_end = recording.get('run_end')
    if run_end and not run_end.startswith(FINISHED) and not st['ended']:
        st['partial'] = True          # the recorder saw no normal end (and no failed event)
        notes.append(f'run end: {run_end}')
    rec = md.get('recovered_from')
    if rec:
        st['partial'] = True
        notes.append(f"recovered from {rec.get('path')} ({rec.get('reason')})"
                     + (f"; {rec['lost']}" if rec.get('lost') else ''))
    plant = md.get('parameters/plant', {})
    try:
        want = int(round(float(plant['duration']) / float(plant['T_s'])))
    except (KeyError, ValueError, ZeroDivisionError):
        want = None
    have = fig.get('steps')
    if want and have is not None and have < want:
        st['partial'] = True
        st['steps_expected'] = want
        notes.append(f'{have} of {want} steps recorded')
    if run.running is not None:
        st['gaps'] = run.running.gaps()
        for topic, g in st['gaps'].items():
            rs = ', '.join(f'{a:.6f}-{b:.6f} s' for a, b in g['ranges'])
            notes.append(f"{topic}: {g['missing']} control instants missing "
                         f'({rs})')
    if run.late:
        notes.append(f'{run.late} messages arrived out of order and are not in the figures')
    st['refused'] = run.refused         # a rogue's or another graph's: not part of the run
    st['refusals'] = refusals(run)
    return st


def refusals(run) -> dict:
    """
    Return the messages refused as not signed by the recorded graph, and who sent them.

    ``{'refused_unsigned': {node: {topic: n}}, 'foreign_publishers': {node: {topic: [names]}}}``
    (the in-process graph's summary has the same shape), from what the recording holds: the
    recorder's own (kept on ``/im/refused<topic>``; its ``recording`` metadata names the foreign
    publishers), the plant's refused commands (its ``finished`` event), and the nodes' counts
    the in-process scenario writes as a ``refusals`` metadata record.
    """
    counts: Dict[str, Dict[str, int]] = {}
    foreign: Dict[str, Dict[str, List[str]]] = {}
    if run.refused:
        counts['recorder'] = dict(run.refused)
    for token in run.metadata.get('recording', {}).get('foreign_publishers', '').split():
        name, _, topic = token.rpartition('@')
        if name and topic:
            foreign.setdefault('recorder', {}).setdefault(topic, []).append(name)
    for e in run.events:
        if e.get('unsigned_commands'):
            counts.setdefault(e['node'], {})[T.CMD_VOLTAGE] = e['unsigned_commands']
            if e.get('foreign_publishers'):
                foreign.setdefault(e['node'], {})[T.CMD_VOLTAGE] = list(e['foreign_publishers'])
    for key, value in run.metadata.get('refusals', {}).items():
        kind, _, where = key.partition('/')
        node, _, topic = where.partition('/')
        if not node or not topic:
            continue
        if kind == 'refused_unsigned':
            counts.setdefault(node, {})['/' + topic] = int(value)
        elif kind == 'foreign_publishers':
            foreign.setdefault(node, {})['/' + topic] = value.split()
    for nodes in foreign.values():
        for topic in nodes:
            nodes[topic] = sorted(set(nodes[topic]))
    return {'refused_unsigned': counts, 'foreign_publishers': foreign}


def refusal_lines(r: dict) -> List[str]:
    """Say :func:`refusals` per node: counts per topic and the foreign publishers named."""
    out = []
    foreign = r['foreign_publishers']
    for node in sorted(set(r['refused_unsigned']) | set(foreign)):
        topics = r['refused_unsigned'].get(node, {})
        names = foreign.get(node, {})
        parts = []
        for topic in sorted(set(topics) | set(names)):
            who = ', '.join(names.get(topic, [])) or 'none named'
            n = topics.get(topic)
            parts.append((f'{n} on `{topic}`' if n is not None else f'`{topic}`')
                         + f' (foreign publishers: {who})')
        out.append(f'refused by {node}: ' + '; '.join(parts))
    return out


def _fmt(v) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return '—'
    if isinstance(v, int):
        return str(v)
    a = abs(v)
    if a != 0 and (a < 1e-3 or a >= 1e5):
        return f'{v:.3e}'
    return f'{v:.4g}' if a < 1 else f'{v:.2f}'


def markdown_table(results: List[dict]) -> str:
    heads = [r['label'].replace('|', '\\|') for r in results]
    lines = ['| figure of merit | unit | ' + ' | '.join(heads) + ' |',
             '| --- | --- | ' + ' | '.join('---:' for _ in heads) + ' |']
    for key, label, unit in ROWS:
        vals = [r['figures'].get(key) for r in results]
        if all(v is None for v in vals):
            continue
        label = label.replace('|', '\\|')
        lines.append(f'| {label} | {unit} | ' + ' | '.join(_fmt(v) for v in vals) + ' |')
    return '\n'.join(lines)


def jsonable(x):
    """``x`` with numpy scalars as Python numbers and NaN/inf as None (strict JSON)."""
    if isinstance(x, dict):
        return {k: jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if isinstance(x, (np.floating, float)):
        return float(x) if math.isfinite(x) else None
    if isinstance(x, np.integer):
        return int(x)
    return x


def write_report(bag_paths: Sequence, out_dir, plots: bool = True) -> dict:
    """
    Report on one or more recordings; returns {'markdown', 'json', 'figures', 'runs'}.

    Raises :class:`~im_recording.bag.BagError` for an unreadable recording.
    """
    if not bag_paths:
        raise ValueError('write_report needs at least one bag')
    runs = [load_run(p, trace='decimated' if plots else None) for p in bag_paths]
    labels = [r.label for r in runs]
    if len(set(labels)) < len(labels):   # same file names in different directories
        labels = [str(Path(r.path)) for r in runs]
    results = []
    for run, label in zip(runs, labels):
        fig = figures_of_merit(run)
        results.append({'bag': str(run.path), 'label': label, 'task': run.task,
                        'figures': fig, 'truth_final': run.truth_final,
                        'status': run_status(run, fig),
                        'metadata': run.metadata, 'message_counts': run.counts})
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    pngs: List[str] = []
    if plots:
        pngs = all_figures(runs, out)
    md = ['# Run report', '']
    md.append('Recordings: ' + ', '.join(f'`{r["bag"]}`' for r in results))
    md += ['', markdown_table(results), '']
    md.append("Energies are the plant's integrated books over the recorded window "
              '(`/im/truth/energy`); tracking errors and peaks from `im_common.metrics`. '
              'The balance residual is E_in − copper − friction − load − parameter-variation '
              '− ΔW_mag − ΔE_kin (core loss is an accounting model outside the balance, '
              'inside it as `E_iron` when the iron loss of the run acts, docs/plant.md).')
    if pngs:
        md += ['', '## Figures', '']
        md += [f'![{Path(p).stem}]({Path(p).name})' for p in pngs]
    warn = [f'- **{r["label"]}**: ' + '; '.join(r['status']['notes']) for r in results
            if r['status']['notes']]
    if warn:
        md += ['', '## Incomplete runs', ''] + warn
    refused = [f'- **{r["label"]}**: ' + line for r in results
               for line in refusal_lines(r['status']['refusals'])]
    if refused:
        md += ['', '## Refused messages', '',
               'Messages not signed by the recorded graph '
               '(a rogue publisher, another graph on the '
               'domain): refused by the nodes, kept apart by the recorder (on '
               f'`{T.REFUSED_PREFIX}<topic>`), in no figure.', '']
        md += refused
    md_path = out / 'report.md'
    write_atomic(md_path, '\n'.join(md) + '\n')
    json_path = out / 'report.json'
    write_atomic(json_path, json.dumps(jsonable({'runs': results, 'figures': pngs}), indent=1,
                                       allow_nan=False))
    return {'markdown': str(md_path), 'json': str(json_path), 'figures': pngs,
            'runs': results}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog='report', description='Figures of merit and figures of '
                                 'recorded runs (several bags: side-by-side comparison).')
    ap.add_argument('bags', nargs='+', help='MCAP recordings')
    ap.add_argument('--out', '-o', default=None, help='output directory')
    ap.add_argument('--no-plots', action='store_true', help='tables only')
    ap.add_argument('--force', action='store_true', help='replace an existing report in --out')
    a = parse_args(ap, argv)
    out = a.out or str(Path(a.bags[0]).with_suffix('')) + '_report'
    try:
        if Path(out).exists() and not Path(out).is_dir():
            raise FileExistsError(f'{out}: --out must be a directory, and this is a file')
        for name in ('report.md', 'report.json'):
            check_output(Path(out) / name, a.bags, a.force, what='report')
        res = write_report(a.bags, out, plots=not a.no_plots)
    except BagError as exc:
        return cli_error('report', exc)
    except (OSError, ValueError) as exc:
        return cli_error('report', exc)
    print(markdown_table(res['runs']))
    print(f'\nreport: {res["markdown"]}\njson:   {res["json"]}')
    for p in res['figures']:
        print(f'figure: {p}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
