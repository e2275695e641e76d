"""
``python -m im_studies.study_delay [--json FILE]``: one period of delay and the thesis's law.

The computational delay (docs/plant.md §10: the command computed at step k acts over step k + 1, as
on a DSP) against the theses' plant, which acts at once. Two parts, each a Markdown table:

* ``current loop`` — the sampled current error e_{k+1} = a e_k − b K e_{k−d} of each shipped motor
  with its current gain (the thesis's k₁ = 40 V/A on the thesis motor, scaled by σL_s on the
  others, docs/limits.md; the certified 1 ms gain of docs/robust.md §7): the spectral radius at
  the nominal parameters and over the certification box, and the longest stable period, without
  and with the delay (:func:`im_controller.gain_design.drive.current_error_radius`);
* ``runs`` — the closed loop on the ROS-free loop, ideal plant: every shipped motor's
  rating-scaled position and speed tasks (:func:`im_studies.study_motors.scaled_scenario`,
  min_loss) at 100 µs with the shipped gains, and the thesis's own speed task at 1 ms with the
  certified gains, each without the delay, with it and the law as printed, and with it and the
  law told the delay (:data:`LAWS`): trip, tracking error (max, RMS), losses;
* ``certificate`` — the thesis motor's two shipped current gains (100 µs, k₁ = 40; the certified
  1 ms gain) with the law told the delay: the decay rate one quadratic Lyapunov function
  certifies over the box's vertex models with the commands already sent as states, without and
  with one period, the predicting law's best K = k I for the delay and its rate, and the best
  rate seed 001's synthesis certifies for any gain on the error and the past commands
  (:func:`im_controller.gain_design.drive.delayed_current_design`).

Ends with the wall time; ``--json`` writes each part's rows and ``wall_s``, ``wall_parts_s`` per
part and ``real_plant_kernel`` (:class:`~im_studies.campaign_pool.WallTime`).
"""
from __future__ import annotations

import argparse
from dataclasses import replace
import json
import os
import sys

from im_bringup.offline import Scenario, simulate
from im_bringup.processes import free_run_gains
from im_common.cli import error as cli_error
from im_common.params import load_motor_file, MotorParams, shipped_motors_dir, THESIS_MOTOR
from im_common.yamlio import load_parameters_file
from im_controller.control_law import ControllerConfig, THESIS_TASKS
from im_controller.gain_design.drive import (current_error_limit, current_error_radius,
                                             delayed_current_design, SUBSYSTEM_CERTIFY_POINTS,
                                             subsystem_points)
import numpy as np

from .campaign_pool import wall_line, WallTime
from .study_motors import scaled_options, scaled_scenario

PARTS = ('current loop', 'certificate', 'runs')
DELAYS = (0, 1)
#: the runs' (delay, law): the law as printed (told no delay: controller_options {delay: 0}) and
#: the law told the delay (it predicts across it, im_controller.control_law)
LAWS = ((0, 'as printed'), (1, 'as printed'), (1, 'predicting'))
STRATEGY = 'min_loss'


def shipped_motors() -> dict:
    """Return {name: MotorParams} of every shipped motor file."""
    d = shipped_motors_dir()
    return {f[:-5]: load_motor_file(os.path.join(d, f)) for f in sorted(os.listdir(d))
            if f.endswith('.yaml')}


def gains_1ms() -> dict:
    """Return the shipped gains certified at 1 ms (docs/robust.md §7): {node: {name: value}}."""
    return {node: dict(values) for node, values in load_parameters_file(
        free_run_gains(1e-3), nodes=('controller', 'observer')).items()}


def _nominal(m: MotorParams) -> np.ndarray:
    return np.array([[m.R_s + m.R_r * (m.L_sr / m.L_r) ** 2, m.L_s - m.L_sr ** 2 / m.L_r]])


def current_loop_rows() -> list:
    """Return the current loop's rows (module doc)."""
    rows = []
    cases = [(name, m, '100 µs, k₁ scaled by σL_s', 1e-4,
              scaled_options(m, 'speed')['k1'] * np.eye(2), None)
             for name, m in shipped_motors().items() if name != 'thesis']
    cases[0:0] = [('thesis', THESIS_MOTOR, '100 µs, k₁ = 40 (shipped)', 1e-4,
                   ControllerConfig().k1 * np.eye(2), subsystem_points(SUBSYSTEM_CERTIFY_POINTS))]
    K1 = np.reshape(gains_1ms()['controller']['current_gain'], (2, 2))
    cases.append(('thesis', THESIS_MOTOR, '1 ms, certified (robust.md §7)', 1e-3, K1,
                  subsystem_points(SUBSYSTEM_CERTIFY_POINTS)))
    for name, m, gains, T_s, K, box in cases:
        row = {'motor': name, 'gains': gains, 'T_s': T_s}
        for d in DELAYS:
            row[f'rho_nominal_d{d}'] = float(current_error_radius(_nominal(m), T_s, K, d)[0])
            row[f'rho_box_d{d}'] = (None if box is None
                                    else float(current_error_radius(box, T_s, K, d).max()))
            row[f'limit_s_d{d}'] = current_error_limit(_nominal(m), K, d)
        rows.append(row)
    return rows


def certificate_rows(progress=print) -> list:
    """Return the certificate part's rows (module doc)."""
    rows = []
    for gains, T_s, K in (('100 µs, k₁ = 40 (shipped)', 1e-4, ControllerConfig().k1 * np.eye(2)),
                          ('1 ms, certified (robust.md §7)', 1e-3,
                           np.reshape(gains_1ms()['controller']['current_gain'], (2, 2)))):
        d = delayed_current_design(K, T_s, 1)
        progress(f'  {gains}: {d.rate:.1f} 1/s with the delay (undelayed '
                 f'{d.rate_undelayed:.1f}), best k {d.k_best:.4g} V/A at {d.rate_best:.1f}, '
                 f'bound {d.rate_bound:.1f}')
        rows.append(dict({'motor': 'thesis', 'gains': gains}, **d.summary()))
    return rows


def _figures(sc: Scenario) -> dict:
    r = simulate(sc, record_every=10)
    s, tr = r.summary, r.trace
    err = (np.abs(tr['theta_r'] - tr['theta_ref']) if sc.task == 'position'
           else np.abs(tr['omega_r'] - tr['omega_ref']))
    trip = s['trip']
    return {'trip': None if trip is None else f"{trip['t']:.4f} s: {trip['reason']}",
            'err_max': float(err.max()), 'err_rms': float(np.sqrt(np.mean(err ** 2))),
            'E_loss_J': s['E_loss_J'], 'E_in_J': s['E_in_J']}


def run_rows(progress=print) -> list:
    """Return the closed-loop rows (module doc)."""
    cases = [(name, task, '100 µs, shipped', scaled_scenario(m, task, STRATEGY))
             for name, m in shipped_motors().items() for task in THESIS_TASKS]
    cases.append(('thesis', 'speed', '1 ms, certified',
                  Scenario(task='speed', strategy=STRATEGY, T_s=1e-3,
                           gains=gains_1ms())))
    rows = []
    for name, task, gains, sc in cases:
        for d, law in LAWS:
            opts = dict(sc.controller_options, **({'delay': 0} if law == 'as printed' else {}))
            run = replace(sc, inverter={'delay': d} if d else None, controller_options=opts)
            row = dict({'motor': name, 'task': task, 'gains': gains, 'delay': d, 'law': law},
                       **_figures(run))
            what = 'trip ' + row['trip'] if row['trip'] else f"max error {row['err_max']:.4g}"
            progress(f'  {name} {task} {gains} delay {d} {law}: {what}')
            rows.append(row)
    return rows


def markdown(part: str, rows: list) -> str:
    """Return one part's rows as a Markdown table."""
    if part == 'current loop':
        out = ['| motor | gains | ρ nominal, d = 0 → 1 | ρ over the box, d = 0 → 1 | longest '
               'stable T_s, d = 0 → 1 |', '|---|---|---|---|---|']
        for r in rows:
            box = ('—' if r['rho_box_d0'] is None
                   else f"{r['rho_box_d0']:.4f} → {r['rho_box_d1']:.4f}")
            out.append(f"| {r['motor']} | {r['gains']} | {r['rho_nominal_d0']:.4f} → "
                       f"{r['rho_nominal_d1']:.4f} | {box} | {r['limit_s_d0'] * 1e6:.1f} → "
                       f"{r['limit_s_d1'] * 1e6:.1f} µs |")
        return '\n'.join(out)
    if part == 'certificate':
        out = ['| motor | gains | certified rate, d = 0 → 1 (predicting) | its spectral radius '
               'over the box, d = 1 | best k for d = 1: k, rate | any gain on the error and '
               'past commands, d = 1 |', '|---|---|---|---:|---|---:|']
        for r in rows:
            out.append(f"| {r['motor']} | {r['gains']} | {r['rate_undelayed']:.1f} → "
                       f"{r['rate']:.1f} 1/s | {r['dense_spectral_radius']:.4f} | "
                       f"{r['k_best']:.4g} V/A, {r['rate_best']:.1f} 1/s | "
                       f"{r['rate_bound']:.1f} 1/s |")
        return '\n'.join(out)
    out = ['| motor | task | gains | delay | law | tracking error, max / RMS | motor losses [J] |',
           '|---|---|---|---:|---|---|---:|']
    for r in rows:
        unit = 'mrad' if r['task'] == 'position' else 'rad/s'
        scale = 1e3 if r['task'] == 'position' else 1.0
        err = (f"trip at {r['trip']}" if r['trip'] else
               f"{r['err_max'] * scale:.4g} / {r['err_rms'] * scale:.4g} {unit}")
        out.append(f"| {r['motor']} | {r['task']} | {r['gains']} | {r['delay']} | {r['law']} | "
                   f"{err} | {r['E_loss_J']:.4g} |")
    return '\n'.join(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog='study_delay', description=__doc__.split('\n\n')[0])
    ap.add_argument('--part', choices=PARTS, action='append',
                    help='run only this part (repeatable; default: all)')
    ap.add_argument('--json', metavar='FILE', help='write the rows as JSON')
    a = ap.parse_args(argv)
    clock = WallTime()
    out = {}
    for part in a.part or PARTS:
        print(f'{part}:', file=sys.stderr)
        progress = lambda line: print(line, file=sys.stderr, flush=True)    # noqa: E731
        with clock.part(part):
            out[part] = (current_loop_rows() if part == 'current loop' else
                         certificate_rows(progress) if part == 'certificate'
                         else run_rows(progress))
        print(f'\n### {part}\n\n{markdown(part, out[part])}\n')
    out.update(clock.figures())
    print(wall_line(out))
    if a.json:
        try:
            os.makedirs(os.path.dirname(a.json) or '.', exist_ok=True)
            with open(a.json, 'w') as f:
                json.dump(out, f, indent=2)
        except OSError as exc:
            return cli_error('study_delay', f'{a.json}: {exc.strerror or exc}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
