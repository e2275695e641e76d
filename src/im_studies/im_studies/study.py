"""
Closed-loop study of seed 000 chapter 3: the energy table of §3.4.7 and the sampled-data limit.

    python -m im_studies.study --out study_out [--quick] [--no-limit] [--no-exponent1] [--sweep]

Runs position and speed tasks × {min_energy, constant_flux, min_loss} at T_s = 100 µs with the
thesis motor, loads and gains (offline lock-step loop, :mod:`im_bringup.offline`), prints a table
(progress on stderr) and writes ``study.json`` into the output directory:

* the six runs with the core-loss exponent 2 (the units of k_e, k_h) and again with exponent 1
  (as printed in eq. 3.34), with the thesis's figures beside ours and the energy balance
  E_in = copper + W_load + friction + ΔE_kin + ΔW_mag (core loss is an accounting model of the
  thesis, outside the balance);
* the targets of issue 3 checked on the numbers;
* the largest T_s at which the thesis's gains keep the loop stable (bisection over T_s), with
  the scalar current-loop estimate beside it;
* optionally (``--sweep``) the min_loss design knobs (flux filter time constant, preview);
* the wall time (``wall_s``), per part (``wall_parts_s``) and whether the real plant runs
  compiled (``real_plant_kernel``; :class:`~im_studies.campaign_pool.WallTime`), also printed.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys

from im_bringup.offline import Scenario, simulate
from im_common.cli import logger, parse_args
from im_common.params import THESIS_MOTOR
from im_controller.control_law import THESIS_TASKS
from im_controller.flux import COMPARED_STRATEGIES
from im_controller.gain_design.motor import thesis_gain_stability_limit

from . import thesis
from .campaign_pool import wall_line, WallTime


_log = logger()


def energy_table(T_s: float, exponent: float, quick: bool, progress: bool) -> list:
    rows = []
    for task in THESIS_TASKS:
        for strategy in COMPARED_STRATEGIES:
            duration = (0.8 if task == 'position' else 0.5) if quick else None
            r = simulate(Scenario(task=task, strategy=strategy, T_s=T_s, duration=duration,
                                  core_loss_exponent=exponent), progress=progress, timing=True)
            s = dict(r.summary)
            th = thesis.energy(task, strategy)
            s['thesis_E_in_J'], s['thesis_E_loss_J'] = th if th else (None, None)
            s['books_J'] = (s['E_copper_J'] + s['W_load_J'] + s['E_friction_J'] + s['dE_kinetic_J']
                            + s['dW_magnetic_J'] + s.get('E_param_J', 0.0))
            s['mechanical_out_J'] = s['W_load_J'] + s['E_friction_J'] + s['dE_kinetic_J']
            rows.append(s)
    return rows


def print_energy_table(rows: list, title: str) -> None:
    print(f'\n{title}')
    hdr = (f"{'task':8s} {'strategy':13s} {'E_in':>8s} {'(thesis)':>9s} {'losses':>8s} "
           f"{'(thesis)':>9s}"
           f" {'copper':>8s} {'core':>7s} {'W_load':>7s} {'fric':>7s} {'dE_kin':>7s} "
           f"{'dW_mag':>7s}"
           f" {'resid':>8s} {'pos_err':>8s} {'spd_err':>8s} {'tau_err':>7s} {'V_max':>6s} "
           f"{'i_max':>6s}"
           f" {'us/ctl':>6s} {'us/obs':>6s}")
    print(hdr)
    print('-' * len(hdr))
    for s in rows:
        te = '' if s['thesis_E_in_J'] is None else f"{s['thesis_E_in_J']:.2f}"
        tl = '' if s['thesis_E_loss_J'] is None else f"{s['thesis_E_loss_J']:.2f}"
        pe = s['pos_err_max_rad']
        print(f"{s['task']:8s} {s['strategy']:13s} {s['E_in_J']:8.2f} {te:>9s} "
              f"{s['E_loss_J']:8.2f} {tl:>9s}"
              f" {s['E_copper_J']:8.2f} {s['E_core_J']:7.2f} {s['W_load_J']:7.2f} "
              f"{s['E_friction_J']:7.2f}"
              f" {s['dE_kinetic_J']:7.2f} {s['dW_magnetic_J']:7.2f} {s['balance_residual_J']:8.1e}"
              f" {('%.2e' % pe) if not math.isnan(pe) else '-':>8s} "
              f"{s['speed_err_max_rad_s']:8.2e}"
              f" {s['torque_err_max_Nm']:7.4f} {s['V_max_V']:6.0f} {s['i_max_A']:6.1f}"
              f" {s['us_per_compute']:6.1f} {s['us_per_observer_step']:6.1f}")


def targets(rows: list) -> dict:
    by = {(s['task'], s['strategy']): s for s in rows}
    out = {}
    cf = by[('position', 'constant_flux')]
    cf_thesis = thesis.losses('position', 'constant_flux')
    out['constant_flux_position_losses_within_3pct'] = {
        'value_J': cf['E_loss_J'], 'thesis_J': cf_thesis,
        'deviation': cf['E_loss_J'] / cf_thesis - 1.0,
        'pass': abs(cf['E_loss_J'] / cf_thesis - 1.0) <= 0.03}
    ml = by[('position', 'min_loss')]
    me_thesis = thesis.losses('position', 'min_energy')
    out['min_loss_position_losses_below_thesis_min_energy'] = {
        'value_J': ml['E_loss_J'], 'thesis_J': me_thesis, 'aim_J': 120.0,
        'pass': ml['E_loss_J'] < me_thesis}
    out['min_loss_position_error_below_5mrad'] = {
        'value_rad': ml['pos_err_max_rad'], 'pass': ml['pos_err_max_rad'] <= 5e-3}
    ms, cs = by[('speed', 'min_loss')], by[('speed', 'constant_flux')]
    out['min_loss_speed_losses_at_most_half_constant_flux'] = {
        'ratio': ms['E_loss_J'] / cs['E_loss_J'], 'pass': ms['E_loss_J'] <= 0.5 * cs['E_loss_J']}
    return out


def current_loop_estimate(k1: float = 40.0) -> float:
    """
    Largest T_s of the sampled scalar current-error loop σL_s ė = −R_eq e − k₁ e_k.

    e_{k+1} = [a − (1 − a) k₁/R_eq] e_k, a = exp(−R_eq T_s/σL_s); stable while
    (1 − a)(1 + k₁/R_eq) < 2, i.e. T_s < −(σL_s/R_eq) ln(1 − 2R_eq/(R_eq + k₁)).
    """
    p = THESIS_MOTOR
    sls = p.L_s - p.L_sr ** 2 / p.L_r
    R_eq = p.R_s + p.R_r * (p.L_sr / p.L_r) ** 2
    return -(sls / R_eq) * math.log(1.0 - 2.0 * R_eq / (R_eq + k1))


def is_stable(task: str, strategy: str, T_s: float, duration: float | None = None):
    """Tell whether a run completes with bounded currents and a working drive's tracking error."""
    try:
        s = simulate(Scenario(task=task, strategy=strategy, T_s=T_s, duration=duration),
                     record_every=1).summary
    except (FloatingPointError, OverflowError, ValueError) as exc:
        return False, {'error': str(exc)}
    if s.get('trip'):                   # the protection stopped a run that lost control
        return False, {'trip': s['trip']}
    if task == 'position':
        err_ok = s['pos_err_max_rad'] < 0.05
    else:
        err_ok = s['speed_err_max_rad_s'] < 2.0
    ok = math.isfinite(s['E_in_J']) and s['i_max_A'] < 100.0 and err_ok
    return ok, {k: s[k] for k in ('pos_err_max_rad', 'speed_err_max_rad_s', 'torque_err_max_Nm',
                                  'i_max_A', 'E_loss_J')}


def sampling_limit(task: str, strategy: str, lo: float = 1e-4, hi: float = 2e-3,
                   rel_tol: float = 0.01) -> dict:
    ok_lo, fig_lo = is_stable(task, strategy, lo)
    if not ok_lo:
        return {'task': task, 'strategy': strategy, 'limit_s': None, 'note': f'unstable at {lo:g} '
                                                                             's'}
    ok_hi, fig_hi = is_stable(task, strategy, hi)
    if ok_hi:
        return {'task': task, 'strategy': strategy, 'limit_s': None, 'note': 'stable up to '
                                                                             f'{hi:g} s'}
    while (hi - lo) / lo > rel_tol:
        mid = math.sqrt(lo * hi)
        ok, fig = is_stable(task, strategy, mid)
        _log(f'  T_s limit {task}/{strategy}: {mid * 1e6:7.1f} us -> '
             f'{"stable" if ok else "unstable"}')
        if ok:
            lo, fig_lo = mid, fig
        else:
            hi, fig_hi = mid, fig
    return {'task': task, 'strategy': strategy, 'largest_stable_T_s': lo,
            'smallest_unstable_T_s': hi, 'rate_hz_needed': 1.0 / lo, 'at_largest_stable': fig_lo,
            'at_smallest_unstable': fig_hi}


def sweep_min_loss(progress: bool) -> list:
    out = []
    T_r = THESIS_MOTOR.T_r
    for task in THESIS_TASKS:
        for tc in ((0.05, 1e-3), (T_r, 1e-3), (0.2, 1e-3)):
            for lead in (0.0, 0.03, 0.06, 0.1):
                s = simulate(Scenario(task=task, strategy='min_loss', controller_options={
                    'flux_time_constants': tc, 'flux_preview': lead})).summary
                out.append({'task': task, 'flux_time_constants': tc, 'flux_preview': lead,
                            'E_loss_J': s['E_loss_J'], 'pos_err_max_rad': s['pos_err_max_rad'],
                            'speed_err_max_rad_s': s['speed_err_max_rad_s'],
                            'V_max_V': s['V_max_V']})
                if progress:
                    _log(f'  sweep {task} tc={tc[0]:.3f} preview={lead:.2f}: '
                         f'{s["E_loss_J"]:.2f} J')
    return out


def _print_balance(rows2: list) -> None:
    """Print the energy balance of each run, the thesis's E_in − losses beside ours."""
    print('\nEnergy balance (J): E_in = copper + W_load + friction + dE_kin + dW_mag; '
          'thesis "E_in - losses" vs ours')
    for s in rows2:
        th = '' if s['thesis_E_in_J'] is None else \
            f"thesis E_in-losses = {s['thesis_E_in_J'] - s['thesis_E_loss_J']:8.2f}"
        print(f"  {s['task']:8s} {s['strategy']:13s} E_in = {s['E_in_J']:8.2f} = "
              f"{s['E_copper_J']:.2f} + "
              f"{s['W_load_J']:.2f} + {s['E_friction_J']:.2f} + {s['dE_kinetic_J']:.2f} + "
              f"{s['dW_magnetic_J']:.2f} (+{s['balance_residual_J']:.1e});  ours E_in-losses = "
              f"{s['E_in_J'] - s['E_loss_J']:8.2f}  {th}")


def _stability_limits(result: dict, clock: WallTime) -> None:
    """Bisect the thesis gains' T_s limit per run and over the parameter box; print, keep them."""
    est = current_loop_estimate(40.0)
    limits = []
    with clock.part('limit'):
        for task in THESIS_TASKS:
            for strategy in COMPARED_STRATEGIES:
                _log(f'T_s stability limit: {task}/{strategy}')
                limits.append(sampling_limit(task, strategy))
    result['sampling_limit'] = {'scalar_current_loop_estimate_s': est, 'runs': limits}
    _log('T_s stability limit over the chapter-4 parameter box (eigenvalues on a grid)')
    with clock.part('limit_box'):
        box = thesis_gain_stability_limit(samples=12, refine_steps=10)
    result['sampling_limit']['parameter_box'] = {k: v for k, v in box.items() if k != 'table'}
    print('\nSampled-data limit with the thesis gains (k1 = 40 V/A, k_e = 1/sigma), '
          'bisection over T_s;'
          f' scalar current-loop estimate {est * 1e6:.1f} us')
    for L in limits:
        if L.get('largest_stable_T_s'):
            print(f"  {L['task']:8s} {L['strategy']:13s} stable at "
                  f"{L['largest_stable_T_s'] * 1e6:7.1f} us,"
                  f" unstable at {L['smallest_unstable_T_s'] * 1e6:7.1f} us"
                  f"  (>= {L['rate_hz_needed']:.0f} Hz)")
        else:
            print(f"  {L['task']:8s} {L['strategy']:13s} {L['note']}")
    print(f"  over the chapter-4 parameter box, |omega_r| <= {box['omega_max']:g} rad/s "
          '(eigenvalues on a grid, not a certificate): current loop stable up to '
          f"{box['current_loop_limit'] * 1e6:.0f} us, observer up to "
          f"{box['observer_limit'] * 1e6:.0f} us")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--out', default='study_out', help='output directory for study.json')
    ap.add_argument('--T-s', type=float, default=1e-4, dest='T_s', help='control period [s]')
    ap.add_argument('--quick', action='store_true', help='short runs (smoke test)')
    ap.add_argument('--no-limit', action='store_true', help='skip the T_s stability bisection')
    ap.add_argument('--no-exponent1', action='store_true', help='skip the core-loss exponent-1 '
                                                                'table')
    ap.add_argument('--sweep', action='store_true', help='also sweep the min_loss design knobs')
    args = parse_args(ap, argv)
    clock = WallTime()
    result = {'T_s': args.T_s, 'quick': args.quick}
    with clock.part('exponent2'):
        rows2 = energy_table(args.T_s, 2.0, args.quick, True)
    result['runs_core_exponent_2'] = rows2
    print_energy_table(rows2, f'Energy table, T_s = {args.T_s * 1e6:g} us, core loss (k_h + k_e '
                              'f_e) f_e phi_m^2'
                              ' [J; errors rad, rad/s, N m; V, A; us per call]')
    if not args.quick:
        result['targets'] = targets(rows2)
        print('\nTargets (issue 3):')
        for k, v in result['targets'].items():
            print(f"  {'PASS' if v['pass'] else 'FAIL'}  {k}: " +
                  ', '.join(f'{a}={b:.4g}' for a, b in v.items() if isinstance(b, float)))
    _print_balance(rows2)
    if not args.no_exponent1:
        with clock.part('exponent1'):
            rows1 = energy_table(args.T_s, 1.0, args.quick, True)
        result['runs_core_exponent_1'] = rows1
        print_energy_table(rows1, 'Same with core loss (k_h + k_e f_e) f_e phi_m (exponent 1, as '
                                  'printed)')
        order = {}
        for rows, ex in ((rows2, 2), (rows1, 1)):
            for task in THESIS_TASKS:
                ranked = sorted((s for s in rows if s['task'] == task),
                                key=lambda s: s['E_loss_J'])
                order[f'{task}_exp{ex}'] = [s['strategy'] for s in ranked]
        result['loss_ranking'] = order
        print('\nLoss ranking (lowest first): '
              + '; '.join(f'{k}: {" < ".join(v)}' for k, v in order.items()))
    if not args.no_limit:
        _stability_limits(result, clock)
    if args.sweep:
        with clock.part('sweep'):
            result['min_loss_sweep'] = sweep_min_loss(True)
        print('\nmin_loss design knobs (flux filter time constant tau1, preview) -> losses [J]')
        for s in result['min_loss_sweep']:
            print(f"  {s['task']:8s} tau1={s['flux_time_constants'][0]:.4f} s "
                  f"preview={s['flux_preview']:.2f} s:"
                  f" {s['E_loss_J']:8.2f}")
    result.update(clock.figures())
    os.makedirs(args.out, exist_ok=True)
    path = os.path.join(args.out, 'study.json')
    with open(path, 'w') as fh:
        json.dump(result, fh, indent=1, default=float)
    _log(f'wrote {path}')
    print(f'\n{wall_line(result)}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
