"""
``python -m im_studies.study_motors --out bags/motors``: every shipped motor, rating-scaled.

Every shipped motor, every flux strategy, position and speed tasks scaled to the motor's ratings,
on the offline loop — a ``make reproduce``-style table per motor (summary.json + summary.md).

Scaling (from the motor file's ratings; docs/limits.md):

* rated flux φ_n = m·V_n·L_sr/(L_s·v·ω_n) (m = voltage margin 0.85): the flux at which the
  field weakening starts at rated speed; constant_flux holds it, the optimizing strategies use
  [0.2 φ_n, φ_n];
* limits: voltage V_n, current 2 I_n (a usual short-time overload), speed 1.2 ω_n;
* mechanical gains scale with the inertia (k_p, k_v of the thesis motor × J/J_thesis) so the
  mechanical loop has the thesis's bandwidth on every motor, and the current gain with the
  transient inductance (k₁ = 40 × σL_s/σL_s,thesis): k₁T_s/σL_s, the discrete current loop's
  gain per period, stays the thesis's 0.63 (the thesis's k₁ = 40 on the 50 hp machine, σL_s =
  1.6 mH, would be 2.5: unstable);
* position task: a quarter turn in 0.6 s and back, against a constant load of 0.2 T_n;
* speed task: a reversal +0.9 ω_n → −0.9 ω_n against a load of 0.1 T_n, as fast as lets the
  quintic's peak acceleration (1.875 Δω / T) need 75 % of :func:`peak_torque`, the steady torque
  the 2 I_n current limit gives at rated flux (1.25 T_n on the thesis motor, 1.55 and 1.68 T_n on
  the Krause motors): the reversal is feasible inside the limits on every motor, with room for
  the flux and current loops. (A fixed 2.2 T_m, T_m = J ω_n / T_n, asked ≈ 1.5 T_n: more than
  the thesis motor can give, so every controller, a perfect model included, fell behind by
  12 rad/s on the thesis motor's reversal.)

The thesis motor's row is not the thesis reproduction (``make reproduce``): its flux is the
motor's rated flux, not the 1.2 Wb of seed 000 §3.4.6.

``--drift``: the same runs under the chapter-4 drift scaled to each motor (:func:`drift_schedule`:
R_r from 0.5 to 1.5 times the motor file's over the run, L_s, L_r, L_sr swing by ±16 % of L_sr, as
in seed 000 §4.3), controller and observer starting from the motor file, with the nominal
controller, the adapter's two improved-law feeds and the truth-fed bound (docs/adaptation.md §6) —
the issue-13 rows for every shipped motor.
"""
from __future__ import annotations

import argparse
from dataclasses import replace
import glob
import json
import math
import os
import sys

from im_adapt.hook import LockstepAdapter
from im_bringup.offline import Scenario, simulate
from im_common.cli import error as cli_error
from im_common.loads import ConstantLoad, LinearLoad
from im_common.model import torque
from im_common.params import (load_motor_file, MotorParams, ParameterSchedule, ramp,
                              shipped_motors_dir, sinusoid, THESIS_MOTOR)
from im_controller.control_law import (ControllerConfig, DEFAULT_GAINS, DEFAULT_VOLTAGE_MARGIN,
                                       THESIS_TASKS)
from im_controller.flux import COMPARED_STRATEGIES
from im_controller.profiles import from_setpoints
import numpy as np

from .campaign_pool import pool_map
from .study_ch4 import gains_for, TRUTH_FED, TruthFed

OVERLOAD = 2.0


def rated_flux(motor: MotorParams, margin: float = DEFAULT_VOLTAGE_MARGIN) -> float:
    """
    Return φ_n = m V_n L_sr / (L_s v ω_n), the motor's rated flux.

    It is the flux whose steady voltage fills the margin at rated speed (field weakening starts
    there).
    """
    if not (motor.rated_voltage > 0 and motor.rated_speed > 0):
        raise ValueError('the motor file gives no rated_voltage / rated_speed to scale to')
    return (margin * motor.rated_voltage * motor.L_sr
            / (motor.L_s * motor.pole_pairs * motor.rated_speed))


#: The speed reversal's peak acceleration torque as a share of :func:`peak_torque`.
REVERSAL_TORQUE_SHARE = 0.75


def peak_torque(motor: MotorParams) -> float:
    """
    Return the steady field-oriented torque at the current limit (OVERLOAD · I_n) and rated flux.

    i_d = φ_n/L_sr, i_q = √(I² − i_d²), τ = v (L_sr/L_r) φ_n i_q (:func:`im_common.model.torque`).
    """
    phi = rated_flux(motor)
    i_lim = OVERLOAD * motor.rated_current
    i_d = phi / motor.L_sr
    if i_d >= i_lim:
        raise ValueError(f'the rated flux {phi:.3g} Wb needs i_d = {i_d:.3g} A, at or above the '
                         f"current limit {i_lim:.3g} A: the motor file's ratings disagree")
    return torque(i_d, math.sqrt(i_lim * i_lim - i_d * i_d), phi, 0.0, motor.L_r, motor.L_sr,
                  motor.pole_pairs)


def reversal_time(motor: MotorParams, span: float = 1.8) -> float:
    """
    Return the duration T of the quintic speed reversal over ``span`` · ω_n.

    Its peak acceleration J·1.875·Δω/T
    is :data:`REVERSAL_TORQUE_SHARE` of :func:`peak_torque` (the load, braking the forward
    speed, is left as margin).
    """
    return (1.875 * span * motor.rated_speed * motor.J
            / (REVERSAL_TORQUE_SHARE * peak_torque(motor)))


def scaled_options(motor: MotorParams, task: str) -> dict:
    """Return the controller options of a rating-scaled run (module doc)."""
    phi = rated_flux(motor)
    kp, kv = DEFAULT_GAINS[task]
    s = motor.J / THESIS_MOTOR.J
    k1 = ControllerConfig().k1 * motor.sigma * motor.L_s / (THESIS_MOTOR.sigma * THESIS_MOTOR.L_s)
    return {'phi_d': phi, 'phi_max': phi, 'phi_min': 0.2 * phi, 'k_p': kp * s, 'k_v': kv * s,
            'k1': k1, 'current_limit': OVERLOAD * motor.rated_current,
            'speed_limit': 1.2 * motor.rated_speed}


def scaled_scenario(motor: MotorParams, task: str, strategy: str) -> Scenario:
    w = motor.rated_speed
    if task == 'position':
        prof = from_setpoints([{'t': 0.0, 'position': 0.0},
                               {'t': 0.3, 'position': 0.5 * math.pi, 'duration': 0.6},
                               {'t': 1.2, 'position': 0.0, 'duration': 0.6}])
        load = ConstantLoad(0.2 * motor.rated_torque)
        duration = 2.2
    else:
        ramp = reversal_time(motor)
        prof = from_setpoints([{'t': 0.0, 'velocity': 0.9 * w},
                               {'t': 0.2, 'velocity': -0.9 * w, 'duration': ramp}])
        load = LinearLoad(0.1 * motor.rated_torque, 0.0)
        duration = 0.2 + ramp + 0.8
    return Scenario(task=task, strategy=strategy, motor=motor, profile=prof, load_model=load,
                    duration=duration, v_limit=motor.rated_voltage,
                    controller_options=scaled_options(motor, task))


def run_motor(motor: MotorParams, name: str, record_every: int = 10) -> list:
    rows = []
    for task in THESIS_TASKS:
        for strategy in COMPARED_STRATEGIES:
            r = simulate(scaled_scenario(motor, task, strategy), record_every=record_every)
            tr, s = r.trace, r.summary
            v = np.hypot(tr['v_alpha'], tr['v_beta'])
            i = np.hypot(tr['i_alpha'], tr['i_beta'])
            tail = tr['t'] >= tr['t'][-1] - 0.5
            err = (np.abs(tr['theta_r'] - tr['theta_ref']) if task == 'position'
                   else np.abs(tr['omega_r'] - tr['omega_ref']))
            rows.append({'motor': name, 'task': task, 'strategy': strategy,
                         'E_in_J': s['E_in_J'], 'E_loss_J': s['E_loss_J'],
                         'err_max': float(err.max()), 'err_tail': float(err[tail].max()),
                         'V_max_V': float(v.max()), 'i_max_A': float(i.max()),
                         'balance_relative': s['balance_relative'],
                         'trip': s['trip']})
    return rows


DRIFT_CONTROLLERS = ('nominal', 'adaptive', 'adaptive_thesis_pair', TRUTH_FED)


def drift_schedule(motor: MotorParams, duration: float) -> ParameterSchedule:
    """
    Return the chapter-4 profile (seed 000 §4.3) scaled to ``motor`` and to a run of ``duration``.

    R_r rises from half to 1.5 times the motor file's value over the run (the thesis's 0.42 →
    1.26 Ω against the model's 0.842 Ω over its 2 s), and L_s, L_r, L_sr each swing by
    + 0.16 L_sr sin(πt) (the thesis's 0.016 H on 0.1 H; σL_s stays nearly constant).
    """
    a = 0.16 * motor.L_sr
    return ParameterSchedule(motor, {'R_r': ramp(0.5 * motor.R_r, motor.R_r / duration),
                                     'L_s': sinusoid(motor.L_s, a, math.pi),
                                     'L_r': sinusoid(motor.L_r, a, math.pi),
                                     'L_sr': sinusoid(motor.L_sr, a, math.pi)},
                             name='chapter4_scaled')


def _drift_case(args) -> dict:
    motor, name, task, strategy, controller = args
    sc = scaled_scenario(motor, task, strategy)
    sched = drift_schedule(motor, sc.duration)
    sched.validate(sc.duration)
    sc = replace(sc, schedule=sched, variation='chapter4_scaled', estimates=motor)
    hook = (None if controller == 'nominal'
            else TruthFed(sched, motor) if controller == TRUTH_FED
            else LockstepAdapter.build(motor, gains_for(controller)))
    row = {'motor': name, 'task': task, 'strategy': strategy, 'controller': controller}
    try:
        r = simulate(sc, adapter=hook, record_every=10)
    except FloatingPointError as exc:          # a diverged run is a row of the table, not an abort
        return {**row, 'err_rms': None, 'E_in_J': None, 'trip': {'reason': f'diverged: {exc}'}}
    key = 'pos_err_rms_rad' if task == 'position' else 'speed_err_rms_rad_s'
    return {**row, 'err_rms': r.summary[key], 'E_in_J': r.summary['E_in_J'],
            'trip': r.summary['trip']}


def run_drift(motors: dict, workers=None) -> list:
    """Every motor × task × strategy × :data:`DRIFT_CONTROLLERS` under :func:`drift_schedule`."""
    cases = [(m, name, task, strategy, c) for name, m in motors.items()
             for task in THESIS_TASKS for strategy in COMPARED_STRATEGIES
             for c in DRIFT_CONTROLLERS]
    return pool_map(_drift_case, cases, workers=workers, label='motors drift')


def drift_markdown(rows: list) -> str:
    out = ['# Shipped motors under the scaled chapter-4 drift', '',
           'Generated by `python -m im_studies.study_motors --drift`: RMS tracking error, '
           'position '
           '[rad] / speed [rad/s]; the controller starts from the motor file (docs/adaptation.md '
           '§6).',
           '', '| motor | task | strategy | ' + ' | '.join(DRIFT_CONTROLLERS) + ' |',
           '| --- | --- | --- |' + ' ---: |' * len(DRIFT_CONTROLLERS)]
    cells = {(r['motor'], r['task'], r['strategy'], r['controller']): r for r in rows}
    runs = dict.fromkeys((r['motor'], r['task'], r['strategy']) for r in rows)
    for motor, task, strategy in runs:
        row = []
        for c in DRIFT_CONTROLLERS:
            r = cells[(motor, task, strategy, c)]
            row.append(f"trip: {r['trip']['reason'][:40]}" if r['trip'] else f"{r['err_rms']:.4g}")
        out.append(f'| {motor} | {task} | {strategy} | ' + ' | '.join(row) + ' |')
    return '\n'.join(out)


def markdown(rows: list, motors: dict) -> str:
    out = ['# Shipped motors: rating-scaled runs on the offline loop', '',
           'Generated by `python -m im_studies.study_motors`; scaling in the module docstring '
           '(rated flux, limits V_n, 2 I_n, 1.2 w_n; gains x J/J_thesis). Errors: position [rad], '
           'speed [rad/s]; tail = last 0.5 s.', '']
    for name, m in motors.items():
        out += [f'## {name}', '',
                f'rated {m.rated_voltage:g} V, {m.rated_current:g} A, {m.rated_speed:g} rad/s, '
                f'{m.rated_torque:g} N m; rated flux {rated_flux(m):.3f} Wb', '',
                '| task | strategy | E_in [J] | E_loss [J] | err max | err tail | V max [V] | '
                'i max [A] | balance | trip |', '| --- | --- | ---: | ---: | ---: | ---: | ---: | '
                '---: | ---: | --- |']
        for r in rows:
            if r['motor'] != name:
                continue
            out.append(f"| {r['task']} | {r['strategy']} | {r['E_in_J']:.2f} | "
                       f"{r['E_loss_J']:.2f} "
                       f"| {r['err_max']:.3g} | {r['err_tail']:.3g} | {r['V_max_V']:.1f} | "
                       f"{r['i_max_A']:.1f} | {r['balance_relative']:.1e} | "
                       f"{r['trip']['reason'] if r['trip'] else '—'} |")
        out.append('')
    return '\n'.join(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog='study_motors', description=__doc__.split('\n\n')[0])
    ap.add_argument('--out', default='bags/motors', help='output directory')
    ap.add_argument('--motor', action='append', metavar='YAML',
                    help='motor file(s) (default: every shipped motor)')
    ap.add_argument('--drift', action='store_true',
                    help='the scaled chapter-4 drift rows instead (nominal, adaptive feeds, '
                         'truth-fed)')
    args = ap.parse_args(argv)
    paths = args.motor or sorted(glob.glob(os.path.join(shipped_motors_dir(), '*.yaml')))
    if not paths:
        return cli_error('study_motors', f'no motor files in {shipped_motors_dir()}')
    motors, rows = {}, []
    try:
        for p in paths:
            name = os.path.splitext(os.path.basename(p))[0]
            motors[name] = load_motor_file(p)
            if not args.drift:
                print(f'{name} ...', file=sys.stderr, flush=True)
                rows += run_motor(motors[name], name)
        if args.drift:
            rows = run_drift(motors)
    except ValueError as exc:
        return cli_error('study_motors', exc)
    os.makedirs(args.out, exist_ok=True)
    stem = 'drift' if args.drift else 'summary'     # the two studies never overwrite each other
    with open(os.path.join(args.out, f'{stem}.json'), 'w') as f:
        json.dump(rows, f, indent=2)
    text = drift_markdown(rows) if args.drift else markdown(rows, motors)
    with open(os.path.join(args.out, f'{stem}.md'), 'w') as f:
        f.write(text + '\n')
    print(text)
    print(f'written: {args.out}/{stem}.json, {args.out}/{stem}.md')
    return 0


if __name__ == '__main__':
    sys.exit(main())
