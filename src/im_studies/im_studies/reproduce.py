"""
``make reproduce``: the thesis's tables re-run through the four-node lock-step graph.

Chapter 3 (seed 000 §3.4): position and speed tasks × {min_energy, constant_flux, min_loss} at
T_s = 100 µs with the thesis's motor, loads and gains, and the ``optimal`` strategy beside them
(the loss-optimal flux trajectory, docs/controller.md §10). Per task a ``bound`` row: the convex
lower bound on the losses over every flux trajectory that delivers the task's torque exactly
(copper only, and copper + core), from each run's own start flux, and each strategy's ratio to
it. Chapter 4 (§4.3): the same tasks under the
chapter-4 variation profile, nominal vs the thesis's adaptation law vs the improved law. Robust
gains (seed 001): the thesis's gains at 1 kHz (they diverge), and the chapter-3 tasks with the
certified gains at 1 kHz and 10 kHz.

Writes ``<out>/summary.json`` (a list, one object per run, then the bound rows and the
:func:`wall_row`) and ``<out>/summary.md`` (each figure next to the thesis's, the wall time at the
end). Progress on stderr.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
from typing import List, Optional

from im_bringup.offline import Scenario
from im_bringup.scenario import run_scenario
from im_common.cli import parse_args
from im_controller.control_law import THESIS_TASKS
from im_controller.design_gains import design_for_scenario
from im_controller.flux import COMPARED_STRATEGIES
from im_recording.report import jsonable

from im_studies import thesis
from im_studies.campaign_pool import pool_map, wall_line, WallTime

from .loss_bound import run_loss_bound

CH3_KEYS = ('task', 'strategy', 'controller', 'rate_hz', 'E_in_J', 'E_loss_J', 'E_copper_J',
            'E_core_J', 'W_load_J', 'E_friction_J', 'dE_kinetic_J', 'dW_magnetic_J',
            'balance_residual_J', 'pos_err_max_rad', 'pos_err_rms_rad', 'speed_err_max_rad_s',
            'torque_err_max_Nm', 'V_max_V', 'i_max_A', 'steps', 'wall_s')


def chapter3_runs(T_s: float = 1e-4) -> List[dict]:
    return [{'task': task, 'strategy': strategy, 'controller': 'nominal', 'variation': 'none',
             'T_s': T_s}
            for task in THESIS_TASKS for strategy in COMPARED_STRATEGIES]


def optimal_runs(T_s: float = 1e-4) -> List[dict]:
    """Return the chapter-3 tasks with the loss-optimal flux trajectory (nominal controller)."""
    return [{'task': task, 'strategy': 'optimal', 'controller': 'nominal', 'variation': 'none',
             'T_s': T_s}
            for task in THESIS_TASKS]


def start_flux(task: str, strategy: str) -> float:
    """
    Return |φ_r(0)| of the plant in a run of ``make reproduce``.

    It is 0 from rest (demagnetized), else the controller's own steady state (the plant's
    initial_flux parameter).
    """
    flux = Scenario(task=task, strategy=strategy).node_parameters()['plant'].get('initial_flux')
    return 0.0 if flux is None else math.hypot(*flux)


def loss_bound(task: str, phi0: float, step: float = 1e-3, core: bool = True):
    """
    Return the convex lower bound on the losses of a thesis task, a FluxPlan.

    The task's run (thesis motor, load, reference) over [0, duration] from the start flux φ0,
    end flux free: :func:`im_studies.loss_bound.run_loss_bound`, the floor of any run file.
    """
    return run_loss_bound(Scenario(task=task), step, core=core, phi0=phi0)


def bound_rows(results: List[dict], step: float = 1e-3) -> List[dict]:
    """
    Return the bound row of each task.

    Per task: copper-only and copper + core bounds from each nominal 100 µs
    run's own start flux (one bound per distinct start), the grid refinement check (the same
    bounds at step/2) and each strategy's ratios (losses / total bound, copper / copper bound).
    """
    rows = []
    for task in THESIS_TASKS:
        runs = [r for r in results if r.get('task') == task and r.get('controller') == 'nominal'
                and r.get('variation', 'none') == 'none' and r.get('rate_hz') == 1e4]
        if not runs:
            continue
        cache = {}
        row = {'task': task, 'strategy': 'bound', 'controller': 'nominal', 'variation': 'none',
               'rate_hz': 1e4, 'grid_s': step, 'start_flux_Wb': {}, 'E_copper_bound_J': {},
               'E_loss_bound_J': {}, 'ratio_loss': {}, 'ratio_copper': {}}
        for r in runs:
            phi0 = round(start_flux(task, r['strategy']), 12)
            if phi0 not in cache:
                cu, tot = loss_bound(task, phi0, step, core=False), loss_bound(task, phi0, step)
                cu2, tot2 = (loss_bound(task, phi0, step / 2, core=False),
                             loss_bound(task, phi0, step / 2))
                cache[phi0] = (cu, tot, max(abs(cu2.copper_J / cu.copper_J - 1.0),
                                            abs(tot2.loss_J / tot.loss_J - 1.0)))
            cu, tot, refine = cache[phi0]
            st = r['strategy']
            row['start_flux_Wb'][st] = phi0
            row['E_copper_bound_J'][st] = cu.copper_J
            row['E_loss_bound_J'][st] = tot.loss_J
            row['ratio_loss'][st] = r['E_loss_J'] / tot.loss_J
            row['ratio_copper'][st] = r['E_copper_J'] / cu.copper_J
            row['refinement_rel'] = max(row.get('refinement_rel', 0.0), refine)
            row['solve_s_max'] = max(row.get('solve_s_max', 0.0), cu.solve_s, tot.solve_s)
        rows.append(row)
    return rows


def run_one(item) -> dict:
    """
    Run one run of ``make reproduce`` through the in-process graph.

    ``item`` = (n, spec, out_dir, record); DDS domain 150 + n mod 80, so the pool's concurrent
    graphs never share one.
    """
    n, spec, out_dir, record = item
    run = Scenario(task=spec['task'], strategy=spec['strategy'], controller=spec['controller'],
                   variation=spec.get('variation', 'none'), T_s=spec['T_s'],
                   duration=spec.get('duration'), parameters=spec.get('parameters'))
    bag = None
    if record:
        bag = os.path.join(out_dir, f"{spec['task']}_{spec['strategy']}_{spec['controller']}_"
                                    f"{spec.get('variation', 'none')}_"
                                    f"{1.0 / spec['T_s']:g}Hz.mcap")
    s = run_scenario(run, record=bag, force=True, progress=False, domain_id=150 + n % 80)
    s.pop('_run', None)
    return s


def run_all(specs: List[dict], out_dir: str, record: bool = False,
            workers: Optional[int] = None) -> List[dict]:
    """Every spec through the graph on the campaign pool (im_studies.campaign_pool), in order."""
    return pool_map(run_one, [(n, spec, out_dir, record) for n, spec in enumerate(specs)],
                    workers=workers, label='reproduce')


def wall_row(figures: dict, runs: List[dict], part_of: List[str]) -> dict:
    """
    Return the summary's last row, ``strategy: 'wall'``: the command's wall time, not a run.

    :meth:`WallTime.figures <im_studies.campaign_pool.WallTime.figures>` (``wall_parts_s``: the
    runs on the pool, the bound rows) and ``run_s_by_part``: per part (``ch3``, ``ch4``,
    ``robust``) the sum of its runs' own ``wall_s`` (``part_of``: each run's part), as the runs
    share the pool's workers.
    """
    by_part: dict = {}
    for r, part in zip(runs, part_of):
        by_part[part] = by_part.get(part, 0.0) + r.get('wall_s', 0.0)
    return {'strategy': 'wall', **figures, 'run_s_by_part': by_part}


def _f(value, fmt: str, scale: float = 1.0) -> str:
    """Format a table cell: the number formatted, or '—' where the figure does not apply."""
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return '—'
    return format(value * scale, fmt)


def _status(r: dict) -> str:
    if r.get('ok', True):
        return 'ok'
    why = '; '.join(str(v) for v in (r.get('failures') or {}).values())
    return f'stopped: {why}'.replace('|', '/')


def markdown(results: List[dict]) -> str:
    rows = ['| task | strategy | controller | variation | rate [Hz] | E_in [J] | thesis E_in | '
            'losses [J] | thesis losses | copper | core | load work | friction | ΔE_kin | '
            'ΔW_mag | balance residual | pos err max [mrad] | speed err max [rad/s] | '
            'torque err max [N·m] | steps/s | run |',
            '|' + ' --- |' * 21]
    for r in results:
        if r.get('strategy') in ('bound', 'wall'):
            continue
        th = None
        if r.get('variation', 'none') == 'none':
            th = thesis.energy(r['task'], r['strategy'])
        the, thl = ('', '')
        if th and r['controller'] == 'nominal':
            the, thl = (f'{th[0]:.2f}', f'{th[1]:.2f}')
        rows.append(
            f"| {r['task']} | {r['strategy']} | {r['controller']} | {r.get('variation', 'none')} "
            '| '
            f"{r['rate_hz']:g} | {r['E_in_J']:.2f} | {the} | {r['E_loss_J']:.2f} | {thl} | "
            f"{r['E_copper_J']:.2f} | {r['E_core_J']:.2f} | {r['W_load_J']:.2f} | "
            f"{r['E_friction_J']:.2f} | {r['dE_kinetic_J']:.2f} | {r['dW_magnetic_J']:.2f} | "
            f"{r['balance_residual_J']:.2e} | {_f(r.get('pos_err_max_rad'), '.2f', 1e3)} | "
            f"{_f(r.get('speed_err_max_rad_s'), '.3f')} | {_f(r.get('torque_err_max_Nm'), '.3f')} "
            '| '
            f"{r['steps'] / r['wall_s']:.0f} | {_status(r)} |")
    return '\n'.join(rows) + '\n'


def bound_markdown(results: List[dict]) -> str:
    """Return the bound rows: per task and run, the start flux, both bounds and the ratios."""
    rows = ['| task | strategy | start flux [Wb] | copper bound [J] | copper / bound | '
            'loss bound (copper + core) [J] | losses / bound |', '|' + ' --- |' * 7]
    for b in results:
        if b.get('strategy') != 'bound':
            continue
        for st, phi0 in b['start_flux_Wb'].items():
            rows.append(f"| {b['task']} | {st} | {phi0:.3f} | {b['E_copper_bound_J'][st]:.2f} | "
                        f"{b['ratio_copper'][st]:.4f} | {b['E_loss_bound_J'][st]:.2f} | "
                        f"{b['ratio_loss'][st]:.4f} |")
    return '\n'.join(rows) + '\n'


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog='reproduce', description=__doc__.split('\n\n')[0])
    ap.add_argument('--out', default='bags/reproduce')
    ap.add_argument('--record', action='store_true', help='also record every run to MCAP')
    ap.add_argument('--only', choices=('ch3', 'ch4', 'robust'), nargs='*')
    ap.add_argument('--workers', type=int, help='parallel runs (default: every core)')
    args = parse_args(ap, argv)
    clock = WallTime()
    os.makedirs(args.out, exist_ok=True)
    parts = args.only or ['ch3', 'ch4', 'robust']
    specs: List[dict] = []
    part_of: List[str] = []
    for part, make in (('ch3', lambda: chapter3_runs() + optimal_runs()),
                       ('ch4', chapter4_runs), ('robust', robust_runs)):
        if part in parts:
            new = make()
            specs += new
            part_of += [part] * len(new)
    with clock.part('runs'):
        results = run_all(specs, args.out, record=args.record, workers=args.workers)
    with clock.part('bound'):
        results += bound_rows(results)
    wall = wall_row(clock.figures(), results, part_of)
    results.append(wall)
    with open(os.path.join(args.out, 'summary.json'), 'w') as f:
        json.dump(jsonable(results), f, indent=2, allow_nan=False)
    with open(os.path.join(args.out, 'summary.md'), 'w') as f:
        f.write('# Thesis figures re-run through the lock-step graph\n\n')
        f.write("Thesis: seed 000 §3.4.7 (energy drawn / losses). Energies from the plant's "
                'integrated books; balance residual = E_in − copper − friction − load work − '
                'E_param − ΔW_mag − ΔE_kin (core loss is accounting only).\n\n')
        f.write(markdown(results))
        f.write('\nLower bound on the losses over every flux trajectory with exact torque '
                'tracking '
                "(docs/controller.md §10), from each run's own start flux, end flux free:\n\n")
        f.write(bound_markdown(results))
        f.write(f'\n{wall_line(wall)}.\n')
    print(markdown(results))
    print(bound_markdown(results))
    print(f'written: {args.out}/summary.json, {args.out}/summary.md')
    print(wall_line(wall))
    return 0


def chapter4_runs() -> List[dict]:
    """Nominal vs the thesis's adaptation law vs the improved law under the chapter-4 profile."""
    return [{'task': task, 'strategy': strategy, 'controller': controller,
             'variation': 'chapter4', 'T_s': 1e-4}
            for task in THESIS_TASKS
            for strategy in COMPARED_STRATEGIES
            for controller in ('nominal', 'adaptive_thesis', 'adaptive')]


def robust_runs() -> List[dict]:
    """Return the chapter-3 tasks at 1 kHz with certified robust gains (and with the thesis's)."""
    runs = [{'task': task, 'strategy': 'min_energy', 'controller': 'nominal', 'variation': 'none',
             'T_s': 1e-3}
            for task in THESIS_TASKS]          # the thesis's gains at 1 kHz
    for T_s in (1e-3, 1e-4):
        gains = design_for_scenario(T_s)
        for task in THESIS_TASKS:
            for strategy in COMPARED_STRATEGIES:
                runs.append({'task': task, 'strategy': strategy, 'controller': 'robust',
                             'variation': 'none', 'T_s': T_s, 'parameters': gains})
    return runs


if __name__ == '__main__':
    sys.exit(main())
