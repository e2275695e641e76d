"""
Certified gains at the node period against the thesis's, in the offline closed loop.

    python -m im_studies.robust_study --out DIR

Runs the chapter-3 position and speed tasks × {min_energy, constant_flux, min_loss}
(im_bringup.offline, the lock-step order of the ROS graph) with

- the thesis's gains (k1 = 40 V/A, k_e = 1/σ, flux coupling 'cancel') at 100 µs and at 1 ms;
- the certified gains of :func:`im_controller.gain_design.drive.design_drive_gains` at 100 µs and
at 1 ms
  (current gain K; the observer in the thesis's structure where it is certified, else the
  discrete injection L; the flux-coupling mode chosen for the period).

A diverging run is reported with the simulated time at which the plant or observer state left
the finite numbers (the simulator raises there) — no traces are kept. Writes DIR/robust_study.json
and DIR/robust_study.md; progress on stderr.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import re
import sys
import time
from typing import List, Optional

from im_bringup.offline import Scenario, simulate
from im_common.cli import logger, parse_args
from im_controller.control_law import THESIS_TASKS
from im_controller.flux import COMPARED_STRATEGIES
from im_controller.gain_design.drive import design_drive_gains
from im_studies.campaign_pool import pool_map
import numpy as np

KEYS = ('E_in_J', 'E_loss_J', 'E_copper_J', 'E_core_J', 'pos_err_max_rad', 'speed_err_max_rad_s',
        'torque_err_max_Nm', 'i_max_A', 'balance_relative', 'wall_s')
LOSS_TOLERANCE = 0.05


_log = logger('robust_study')


def gains_for(T_s: float, progress: bool = True) -> dict:
    """Certified gains at T_s as offline Scenario arguments, with the design summary."""
    g = design_drive_gains(T_s, progress=progress)
    if not g.certified:
        raise RuntimeError(f'no certified gains at T_s = {T_s:g} s')
    return {'current_gain': g.K.tolist(), 'observer_gain': None if g.L is None else g.L.tolist(),
            'k_e': g.k_e, 'controller_options': {'flux_coupling': g.flux_coupling},
            'design': g.summary()}


def run_one(task: str, strategy: str, T_s: float, gains: Optional[dict]) -> dict:
    names = ('current_gain', 'observer_gain', 'k_e', 'controller_options')
    kw = {} if gains is None else {k: gains[k] for k in names}
    sc = Scenario(task=task, strategy=strategy, T_s=T_s, **kw)
    row = {'task': task, 'strategy': strategy, 'T_s': T_s,
           'gains': 'thesis' if gains is None else 'certified'}
    t0 = time.perf_counter()
    try:
        s = simulate(sc).summary
    except (FloatingPointError, OverflowError, ValueError) as exc:
        m = re.search(r't = ([0-9.eE+-]+)', str(exc))
        row.update(diverged=True, t_diverged_s=float(m.group(1)) if m else None,
                   error=str(exc), wall_s=time.perf_counter() - t0)
        return row
    row['diverged'] = not all(math.isfinite(s.get(k, 0.0)) for k in ('E_in_J', 'E_loss_J'))
    row.update({k: s.get(k) for k in KEYS})
    return row


def _run_item(item) -> dict:
    return run_one(*item)


def study(progress: bool = True) -> dict:
    designs = {T: gains_for(T, progress) for T in (1e-3, 1e-4)}
    plan = [(task, strategy, T, None if which == 'thesis' else designs[T])
            for T in (1e-4, 1e-3) for which in ('thesis', 'certified')
            for task in THESIS_TASKS for strategy in COMPARED_STRATEGIES]
    rows = pool_map(_run_item, plan, label='robust_study', progress=progress)
    return {'designs': {f'{T:g}': d['design'] for T, d in designs.items()},
            'gains': {f'{T:g}': {k: d[k] for k in ('current_gain', 'observer_gain', 'k_e',
                                                   'controller_options')}
                      for T, d in designs.items()},
            'runs': rows, 'comparison': compare(rows)}


def _find(rows, task, strategy, T_s, gains):
    return next(r for r in rows if r['task'] == task and r['strategy'] == strategy
                and r['T_s'] == T_s and r['gains'] == gains)


def compare(rows: List[dict]) -> List[dict]:
    """
    Compare the certified gains with the thesis's, per task and strategy.

    Per task/strategy: 1 ms certified vs 100 µs thesis (losses within 5 %), 100 µs certified vs
    100 µs thesis (no worse), and how the thesis's gains fail at 1 ms.
    """
    out = []
    for task in THESIS_TASKS:
        for strategy in COMPARED_STRATEGIES:
            ref = _find(rows, task, strategy, 1e-4, 'thesis')
            c1 = _find(rows, task, strategy, 1e-3, 'certified')
            c01 = _find(rows, task, strategy, 1e-4, 'certified')
            t1 = _find(rows, task, strategy, 1e-3, 'thesis')
            d = {'task': task, 'strategy': strategy,
                 'loss_100us_thesis': ref.get('E_loss_J'),
                 'loss_1ms_certified': c1.get('E_loss_J'),
                 'loss_100us_certified': c01.get('E_loss_J'),
                 'thesis_1ms_diverged': t1['diverged'],
                 'thesis_1ms_t_diverged': t1.get('t_diverged_s')}
            if not c1['diverged'] and not ref['diverged']:
                d['rel_loss_1ms'] = c1['E_loss_J'] / ref['E_loss_J'] - 1.0
                d['within_5pct'] = abs(d['rel_loss_1ms']) <= LOSS_TOLERANCE
            if not c01['diverged'] and not ref['diverged']:
                d['rel_loss_100us'] = c01['E_loss_J'] / ref['E_loss_J'] - 1.0
                err = 'pos_err_max_rad' if task == 'position' else 'speed_err_max_rad_s'
                d['err_key'] = err
                d['err_100us_thesis'] = ref.get(err)
                d['err_100us_certified'] = c01.get(err)
                d['err_1ms_certified'] = c1.get(err)
            out.append(d)
    return out


def _f(x, fmt):
    return '–' if x is None or (isinstance(x, float) and not math.isfinite(x)) else format(x, fmt)


def markdown(res: dict) -> str:
    lines = ["# Certified gains at the node period vs the thesis's (offline loop)", '']
    lines.append('| T_s | current gain K [V/A] | certified current-error rate [1/s] | '
                 'observer | observer 4-state certificate | flux coupling |')
    lines.append('|---|---|---|---|---|---|')
    for T, d in res['designs'].items():
        cur = d['current']
        if d.get('observer_structure') == 'thesis':
            t = d['thesis_observer']
            obs = f"thesis structure, k_e = {t['k_e']:.4g} (1/σ) + skew"
            oc = (f"{t['scope']} (|Δω| ≤ {t['speed_step']:g} rad/s per period), "
                  f"ρ = {t['worst_rho_dense']:.6f}")
        else:
            o = d['observer']
            obs = f"discrete L = [{d['observer_current']['gain'][0][0]:.4f} I; 0]"
            oc = f"{o['scope']}, ρ = {o['worst_rho_dense']:.6f}"
        lines.append(f"| {T} s | {cur['gain'][0][0]:.3f} I ({cur['source']}) | "
                     f"{cur['certified_rate_dense']:.1f} (ρ = {cur['lyapunov_rho_dense']:.5f}, "
                     'best '
                     f"{cur['best_feasible_rate']:.1f}) | {obs} | {oc} | {d['flux_coupling']} |")
    lines += ['', '## Losses [J] and tracking', '',
              '| task | strategy | 100 µs thesis | 1 ms certified | Δ | within 5 % | '
              '100 µs certified | Δ | max err 100 µs thesis | 100 µs certified | 1 ms certified | '
              'thesis gains at 1 ms |',
              '|---|---|---|---|---|---|---|---|---|---|---|---|']
    for c in res['comparison']:
        unit = 'mrad' if c.get('err_key') == 'pos_err_max_rad' else 'rad/s'
        scale = 1e3 if unit == 'mrad' else 1.0

        def e(x):
            return '–' if x is None else f'{scale * x:.3g} {unit}'
        div = (f"diverged at t = {c['thesis_1ms_t_diverged']:.3f} s" if c['thesis_1ms_diverged']
               else 'bounded')
        lines.append(f"| {c['task']} | {c['strategy']} | {_f(c['loss_100us_thesis'], '.2f')} | "
                     f"{_f(c['loss_1ms_certified'], '.2f')} | "
                     f"{_f(100 * c.get('rel_loss_1ms', float('nan')), '+.2f')} % | "
                     f"{'yes' if c.get('within_5pct') else 'no'} | "
                     f"{_f(c['loss_100us_certified'], '.2f')} | "
                     f"{_f(100 * c.get('rel_loss_100us', float('nan')), '+.2f')} % | "
                     f"{e(c.get('err_100us_thesis'))} | {e(c.get('err_100us_certified'))} | "
                     f"{e(c.get('err_1ms_certified'))} | {div} |")
    lines.append('')
    return '\n'.join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog='robust_study', description=__doc__.split('\n\n')[0])
    ap.add_argument('--out', default='robust_study_out', help='output directory')
    args = parse_args(ap, argv)
    os.makedirs(args.out, exist_ok=True)
    t0 = time.perf_counter()
    res = study()
    res['wall_s'] = time.perf_counter() - t0
    with open(os.path.join(args.out, 'robust_study.json'), 'w') as f:
        json.dump(res, f, indent=2, default=lambda x: x.tolist() if isinstance(x, np.ndarray)
                  else float(x))
    md = markdown(res)
    with open(os.path.join(args.out, 'robust_study.md'), 'w') as f:
        f.write(md)
    print(md)
    _log(f'written {args.out}/robust_study.json and robust_study.md ({res["wall_s"]:.0f} s)')
    return 0


if __name__ == '__main__':
    sys.exit(main())
