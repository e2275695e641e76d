"""
Chapter-4 study (seed 000 §4.2.1 and §4.3): ``python -m im_studies.study_ch4 --out DIR``.

1. Sensitivity (§4.2.1): the nominal controller under one electrical parameter varied at a time
   (the thesis's profiles where they are physical, constant factors ×0.5/×1.5 for resistances,
   ×1.2 and ×0.8 for inductances, and saturation of all three inductances ×0.8), position and
   speed tasks: tracking and torque errors against the unvaried run.
2. Nominal vs adaptive (§4.3): chapter-4 profile and nominal parameters, both tasks, every flux
   strategy, controller ∈ {nominal, adaptive_thesis, adaptive}; each result carries the
   chapter-3 summary keys plus the final estimates against the truth, and the identification
   figures over the last second (relative RMS and peak-to-peak of the error of L̂_M, R̂_R).

Writes ``study_ch4.json`` and ``study_ch4.md`` into DIR; progress on stderr. Runs through
:func:`im_bringup.offline.simulate` with :class:`im_adapt.hook.LockstepAdapter` as its adapter.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from typing import Callable, Dict, List, Optional

from im_adapt.adaptation import AdaptationGains
from im_adapt.hook import LockstepAdapter
from im_bringup import offline
from im_bringup.config import ADAPTATION
from im_bringup.offline import CHAPTER4_ESTIMATES, Scenario, simulate
from im_common.cli import logger, parse_args
from im_common.params import (constant, InvalidParameter, ParameterSchedule, ramp, sinusoid,
                              THESIS_MOTOR)
from im_controller.control_law import THESIS_TASKS
from im_controller.flux import COMPARED_STRATEGIES
from im_studies.campaign_pool import pool_map
import numpy as np

from .campaign_spec import NOMINAL_AND_ADAPTIVE

TRUTH_FED = 'truth_fed'   # not a controller: the truth's R_s, L_σ, L_M, R_R handed to the model
SENS_KEYS = ('pos_err_rms_rad', 'pos_err_max_rad', 'speed_err_rms_rad_s', 'speed_err_max_rad_s',
             'torque_err_rms_Nm', 'torque_err_max_Nm', 'E_in_J', 'E_loss_J')


_log = logger()


# ---------------------------------------------------------------------------------------------
# Schedules
# ---------------------------------------------------------------------------------------------
def sensitivity_cases(base=THESIS_MOTOR) -> Dict[str, Callable[[], ParameterSchedule]]:
    """§4.2.1: one parameter at a time (saturation: the three inductances together)."""
    P = base
    pi = math.pi
    cases = {
        'R_s = 0.33t + 0.35 (thesis)': {'R_s': ramp(0.35, 0.33)},
        'R_s x0.5': {'R_s': constant(0.5 * P.R_s)},
        'R_s x1.5': {'R_s': constant(1.5 * P.R_s)},
        'R_r = 0.42t + 0.42 (thesis)': {'R_r': ramp(0.42, 0.42)},
        'R_r x0.5': {'R_r': constant(0.5 * P.R_r)},
        'R_r x1.5': {'R_r': constant(1.5 * P.R_r)},
        'L_s = 0.1 + 0.016 sin(pi t) (thesis)': {'L_s': sinusoid(0.1, 0.016, pi)},
        'L_s x1.2': {'L_s': constant(1.2 * P.L_s)},
        'L_r = 0.1 + 0.016 sin(pi t) (thesis)': {'L_r': sinusoid(0.1, 0.016, pi)},
        'L_r x1.2': {'L_r': constant(1.2 * P.L_r)},
        'L_sr = 0.097 + 0.016 sin(pi t) (thesis)': {'L_sr': sinusoid(0.097, 0.016, pi)},
        'L_sr x0.8': {'L_sr': constant(0.8 * P.L_sr)},
        'saturation: L_s, L_r, L_sr x0.8': {'L_s': constant(0.8 * P.L_s),
                                            'L_r': constant(0.8 * P.L_r),
                                            'L_sr': constant(0.8 * P.L_sr)},
    }
    return {name: (lambda v=v, name=name: ParameterSchedule(base, v, name=name))
            for name, v in cases.items()}


# ---------------------------------------------------------------------------------------------
# Runs
# ---------------------------------------------------------------------------------------------
class TruthFed:
    """
    Feed the controller and observer the plant's true parameters (a bound, not a controller).

    It hands the controller and observer the plant's *true*
    identifiable parameters (R_s, L_σ, L_M, R_R at t_k+1; docs/adaptation.md §7) — what a perfect
    adapter would. Fed these, the controller's model is terminal-equivalent to the drifting motor
    at every step; what is left of the tracking error is the drift's speed (dL/dt terms), not a
    wrong model.
    """

    def __init__(self, schedule, est_params, record_every: int = 10):
        self.schedule = schedule
        self.gauge = est_params
        self.record_every = record_every
        self.k = 0
        self.t, self.samples = [], []

    def step(self, T_s, t, v_alpha, v_beta, meas, x_hat) -> dict:
        p = self.schedule.params_at(t + T_s)
        est = p.identifiable()
        model = self.gauge.with_identifiable(**est)      # the controller's image of it
        self.k += 1
        if self.k % self.record_every == 0:
            self.t.append(t + T_s)
            self.samples.append((model.R_r, model.theta, p.L_M, p.R_R, p.L_sigma))
        return est


def gains_for(controller: str, **overrides) -> Optional[AdaptationGains]:
    if controller == 'nominal':
        return None
    return AdaptationGains(**{**ADAPTATION[controller], **overrides})


def run_case(task: str, strategy: str, controller: str, variation: str,
             gains: Optional[AdaptationGains] = None, T_s: float = 1e-4,
             duration: Optional[float] = None, record_every: int = 10,
             schedule: Optional[ParameterSchedule] = None, start_flux: float = 1.0) -> dict:
    """
    Run one closed loop; return the summary plus estimates against truth (see module docstring).

    ``schedule`` overrides the named variation (``variation`` is then only a label);
    ``start_flux`` scales a steady start's rotor flux (the speed task's).
    """
    ctl_label = controller if controller in offline.CONTROLLERS else 'nominal'
    sc = Scenario(task=task, strategy=strategy, variation=variation, T_s=T_s, duration=duration,
                  schedule=schedule, controller=ctl_label, start_flux=start_flux)
    est_params = CHAPTER4_ESTIMATES if variation == 'chapter4' else THESIS_MOTOR
    hook = None
    if controller == TRUTH_FED:
        hook = TruthFed(sc.plant_schedule(), est_params, record_every=record_every)
    elif controller != 'nominal':
        hook = LockstepAdapter.build(est_params, gains or gains_for(controller),
                                     record_every=record_every)
    res = simulate(sc, adapter=hook, record_every=record_every)
    out = dict(res.summary)
    out['controller'] = controller
    out['variation'] = variation
    schedule = sc.plant_schedule()
    t_end = sc.duration
    truth = schedule.params_at(t_end)
    if hook is not None and hook.samples:
        t = np.asarray(hook.t)
        s = np.asarray(hook.samples)
        R_r_hat, th_hat, L_M_hat, R_R_hat = s[:, 0], s[:, 1], s[:, 2], s[:, 3]
    else:
        t = np.asarray(res.trace['t'])
        n = len(t)
        R_r_hat = np.full(n, est_params.R_r)
        th_hat = np.full(n, est_params.theta)
        L_M_hat = np.full(n, est_params.L_sr * est_params.theta)
        R_R_hat = np.full(n, est_params.R_r * est_params.theta ** 2)
    out.update({
        'R_r_hat_final': float(R_r_hat[-1]), 'R_r_true_final': truth.R_r,
        'theta_hat_final': float(th_hat[-1]), 'theta_true_final': truth.theta,
        'L_M_hat_final': float(L_M_hat[-1]), 'L_M_true_final': truth.L_M,
        'R_R_hat_final': float(R_R_hat[-1]), 'R_R_true_final': truth.R_R,
    })
    if hook is not None and hook.samples and s.shape[1] > 4:
        out['L_sigma_hat_final'] = float(s[-1, 4])
        out['L_sigma_true_final'] = truth.L_s - truth.L_M
    # Identification over the last second: relative RMS and peak-to-peak of the error.
    last = t > t_end - 1.0
    params = [schedule.params_at(float(x)) for x in t[last]]
    for name, hat, true_of in (('R_r', R_r_hat, lambda p: p.R_r),
                               ('theta', th_hat, lambda p: p.theta),
                               ('L_M', L_M_hat, lambda p: p.L_M),
                               ('R_R', R_R_hat, lambda p: p.R_R)):
        tru = np.array([true_of(p) for p in params])
        err = hat[last] - tru
        out[f'{name}_err_rms_rel_last1s'] = float(math.sqrt(np.mean((err / tru) ** 2)))
        out[f'{name}_err_ptp_rel_last1s'] = float(np.ptp(err) / np.mean(tru))
    return out


def sensitivity(tasks=THESIS_TASKS, strategy: str = 'min_energy', T_s: float = 1e-4) -> List[dict]:
    rows = []
    for task in tasks:
        base = run_case(task, strategy, 'nominal', 'none', T_s=T_s)
        base['case'] = 'none'
        rows.append(base)
        _log(f'sensitivity {task}: none')
        for name, factory in sensitivity_cases().items():
            duration = offline.DEFAULT_DURATION[task]
            try:
                factory().validate(duration)
            except InvalidParameter as exc:
                rows.append({'task': task, 'strategy': strategy, 'case': name,
                             'skipped': f'not a physical motor: {exc}'})
                _log(f'sensitivity {task}: {name}: skipped ({exc.name})')
                continue
            r = run_case(task, strategy, 'nominal', name, T_s=T_s, schedule=factory())
            r['case'] = name
            r['variation'] = name
            rows.append(r)
            _log(f'sensitivity {task}: {name}')
    return rows


def _case(args) -> dict:
    task, strategy, controller, variation, T_s = args
    return run_case(task, strategy, controller, variation, T_s=T_s)


def comparison(tasks=THESIS_TASKS, strategies=COMPARED_STRATEGIES,
               controllers=NOMINAL_AND_ADAPTIVE + (TRUTH_FED,),
               variations=('chapter4', 'none'), T_s: float = 1e-4,
               workers: Optional[int] = None) -> List[dict]:
    """Every (variation, task, strategy, controller) case on the campaign pool, in order."""
    cases = [(task, strategy, controller, variation, T_s) for variation in variations
             for task in tasks for strategy in strategies for controller in controllers]
    return pool_map(_case, cases, workers=workers, label='compare')


# ---------------------------------------------------------------------------------------------
# Targets and tables
# ---------------------------------------------------------------------------------------------
def _find(rows, **kw):
    for r in rows:
        if all(r.get(k) == v for k, v in kw.items()):
            return r
    return None


def targets(rows: List[dict]) -> List[dict]:
    """Issue-5 targets for the improved law, per task and strategy (measured, pass/fail)."""
    out = []
    for task in THESIS_TASKS:
        for strategy in COMPARED_STRATEGIES:
            nom = _find(rows, task=task, strategy=strategy,
                        controller='nominal', variation='chapter4')
            ada = _find(rows, task=task, strategy=strategy,
                        controller='adaptive', variation='chapter4')
            ada_n = _find(rows, task=task, strategy=strategy,
                          controller='adaptive', variation='none')
            nom_n = _find(rows, task=task, strategy=strategy,
                          controller='nominal', variation='none')
            orc = _find(rows, task=task, strategy=strategy, controller=TRUTH_FED,
                        variation='chapter4')
            the_n = _find(rows, task=task, strategy=strategy, controller='adaptive_thesis',
                          variation='none')
            if nom is None or ada is None:
                continue
            key = 'pos_err_rms_rad' if task == 'position' else 'speed_err_rms_rad_s'
            ratio = ada[key] / nom[key]
            t = {'task': task, 'strategy': strategy,
                 'tracking_rms_ratio_adaptive_over_nominal': ratio,
                 'tracking_half_of_nominal': ratio <= 0.5,
                 'R_R_rms_rel_last1s': ada['R_R_err_rms_rel_last1s'],
                 'L_M_rms_rel_last1s': ada['L_M_err_rms_rel_last1s'],
                 'within_5pct_rms': max(ada['R_R_err_rms_rel_last1s'],
                                        ada['L_M_err_rms_rel_last1s']) <= 0.05,
                 'R_R_ptp_rel_last1s': ada['R_R_err_ptp_rel_last1s'],
                 'L_M_ptp_rel_last1s': ada['L_M_err_ptp_rel_last1s'],
                 'ptp_below_5pct': max(ada['R_R_err_ptp_rel_last1s'],
                                       ada['L_M_err_ptp_rel_last1s']) < 0.05}
            if ada_n is not None and the_n is not None:
                rel = ada_n['E_in_J'] / the_n['E_in_J'] - 1.0
                t['E_in_nominal_params_vs_thesis_law'] = rel
                t['energy_within_5pct'] = abs(rel) <= 0.05
            if ada_n is not None and nom_n is not None:
                t['E_in_nominal_params_vs_nominal_controller'] = (ada_n['E_in_J'] / nom_n['E_in_J']
                                                                  - 1.0)
            if orc is not None:
                t['tracking_rms_ratio_truth_fed_over_nominal'] = orc[key] / nom[key]
            out.append(t)
    return out


def _f(x, fmt='{:.4g}'):
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return '—'
    if isinstance(x, bool):
        return 'yes' if x else 'no'
    return fmt.format(x) if isinstance(x, (int, float)) else str(x)


def markdown(sens: List[dict], comp: List[dict], tgt: List[dict]) -> str:
    lines = ['# Chapter-4 study (seed 000 §4.2.1, §4.3)', '',
             'Generated by `python -m im_studies.study_ch4`. Errors are RMS/max over the run; '
             'identification figures over the last second.', '']
    if sens:
        lines += ['## Sensitivity of the nominal controller (§4.2.1, min-energy strategy)', '',
                  '| task | variation | pos RMS [rad] | pos max [rad] | speed RMS [rad/s] | '
                  'speed max [rad/s] | torque RMS [N·m] | torque max [N·m] | E_in [J] |',
                  '|---|---|---|---|---|---|---|---|---|']
        for r in sens:
            if 'skipped' in r:
                lines.append(f"| {r['task']} | {r['case']} | skipped: {r['skipped']} |||||||")
                continue
            lines.append('| ' + ' | '.join([r['task'], r['case']] + [
                _f(r.get(k)) for k in ('pos_err_rms_rad', 'pos_err_max_rad', 'speed_err_rms_rad_s',
                                       'speed_err_max_rad_s', 'torque_err_rms_Nm',
                                       'torque_err_max_Nm', 'E_in_J')]) + ' |')
        lines.append('')
    if comp:
        lines += ['## Nominal vs adaptive', '',
                  '| variation | task | strategy | controller | pos RMS [rad] | speed RMS [rad/s] '
                  '| '
                  'torque RMS [N·m] | E_in [J] | E_loss [J] | R̂_r / R_r | θ̂ / θ | '
                  'L̂_M / L_M [mH] | R̂_R / R_R | L_M RMS / p-p | R_R RMS / p-p |',
                  '|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|']
        for r in comp:
            lines.append('| ' + ' | '.join([
                r['variation'], r['task'], r['strategy'], r['controller'],
                _f(r.get('pos_err_rms_rad')), _f(r.get('speed_err_rms_rad_s')),
                _f(r.get('torque_err_rms_Nm')), _f(r['E_in_J'], '{:.1f}'),
                _f(r['E_loss_J'], '{:.1f}'),
                f"{r['R_r_hat_final']:.3f} / {r['R_r_true_final']:.3f}",
                f"{r['theta_hat_final']:.3f} / {r['theta_true_final']:.3f}",
                f"{1e3 * r['L_M_hat_final']:.1f} / {1e3 * r['L_M_true_final']:.1f}",
                f"{r['R_R_hat_final']:.3f} / {r['R_R_true_final']:.3f}",
                f"{100 * r['L_M_err_rms_rel_last1s']:.1f} % / "
                f"{100 * r['L_M_err_ptp_rel_last1s']:.1f} %",
                f"{100 * r['R_R_err_rms_rel_last1s']:.1f} % / "
                f"{100 * r['R_R_err_ptp_rel_last1s']:.1f} %",
            ]) + ' |')
        lines.append('')
    if tgt:
        lines += ['## Issue-5 targets for the improved law (chapter-4 profile)', '',
                  '| task | strategy | tracking RMS adaptive/nominal | ≤ ½ | L_M RMS | R_R RMS | '
                  '≤ 5 % | L_M p-p | R_R p-p | < 5 % | E_in (nominal params) vs thesis law | '
                  '≤ 5 % | E_in (nominal params) vs nominal controller | truth-fed/nominal |',
                  '|---|---|---|---|---|---|---|---|---|---|---|---|---|---|']
        for t in tgt:
            lines.append('| ' + ' | '.join([
                t['task'], t['strategy'],
                _f(t['tracking_rms_ratio_adaptive_over_nominal'], '{:.3f}'),
                _f(t['tracking_half_of_nominal']),
                f"{100 * t['L_M_rms_rel_last1s']:.1f} %", f"{100 * t['R_R_rms_rel_last1s']:.1f} %",
                _f(t['within_5pct_rms']),
                f"{100 * t['L_M_ptp_rel_last1s']:.1f} %", f"{100 * t['R_R_ptp_rel_last1s']:.1f} %",
                _f(t['ptp_below_5pct']),
                f"{100 * t.get('E_in_nominal_params_vs_thesis_law', float('nan')):+.1f} %",
                _f(t.get('energy_within_5pct')),
                f"{100 * t.get('E_in_nominal_params_vs_nominal_controller', float('nan')):+.1f} %",
                _f(t.get('tracking_rms_ratio_truth_fed_over_nominal'), '{:.3f}')]) + ' |')
        lines.append('')
    return '\n'.join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--out', required=True, help='output directory (JSON + Markdown)')
    ap.add_argument('--part', choices=('all', 'sensitivity', 'compare'), default='all')
    ap.add_argument('--tasks', default=','.join(THESIS_TASKS))
    ap.add_argument('--strategies', default=','.join(COMPARED_STRATEGIES))
    ap.add_argument('--T-s', type=float, default=1e-4, dest='T_s')
    args = parse_args(ap, argv)
    tasks = tuple(x for x in args.tasks.split(',') if x)
    strategies = tuple(x for x in args.strategies.split(',') if x)
    os.makedirs(args.out, exist_ok=True)
    t0 = time.perf_counter()
    sens = sensitivity(tasks, T_s=args.T_s) if args.part in ('all', 'sensitivity') else []
    comp = (comparison(tasks, strategies, T_s=args.T_s)
            if args.part in ('all', 'compare') else [])
    tgt = targets(comp)
    doc = {'sensitivity': sens, 'comparison': comp, 'targets': tgt,
           'gains': {'adaptive_thesis': AdaptationGains(law='thesis').as_dict(),
                     'adaptive': AdaptationGains(law='improved').as_dict()},
           'wall_s': time.perf_counter() - t0}
    with open(os.path.join(args.out, 'study_ch4.json'), 'w') as f:
        json.dump(doc, f, indent=1, default=float)
    with open(os.path.join(args.out, 'study_ch4.md'), 'w') as f:
        f.write(markdown(sens, comp, tgt))
    _log(f'wrote {args.out}/study_ch4.json and study_ch4.md in {time.perf_counter() - t0:.0f} s')
    return 0


if __name__ == '__main__':
    sys.exit(main())
