"""
``python -m im_studies.study_sensorless [--json FILE]``: the speed-sensorless drive, offline.

It runs on the offline loop (docs/sensorless.md §5) — the thesis speed task per flux strategy,
sensored against sensorless with the measured speed made useless (σ = 50 rad/s), and a ±100 rad/s
reversal against a constant 1 N·m on every shipped motor with its rating-scaled controller
(``study_motors``); then the torque task per strategy, and the adapter on with the plant's R_s
drifted (the thesis speed task and a low-speed hold). Prints Markdown tables; ``--json`` writes
the rows.
"""
from __future__ import annotations

import argparse
import json
import sys

from im_adapt.hook import LockstepAdapter
from im_bringup.offline import Scenario, simulate
from im_common.loads import ConstantLoad
from im_common.params import (constant, load_motor_file, ParameterSchedule, shipped_motors_dir,
                              THESIS_MOTOR)
from im_controller.flux import COMPARED_STRATEGIES
from im_controller.profiles import Profile
import numpy as np

from .commission_sim import identification_errors, plate_of
from .commission_study import motors
from .study_motors import reversal_time, scaled_options

#: the measured speed's noise in the sensorless runs [rad/s]: useless to a speed controller
USELESS_SPEED_NOISE = 50.0
MOTORS = ('thesis', 'krause_3hp', 'krause_50hp')
REVERSAL_SPEED = 100.0
REVERSAL_LOAD = 1.0
#: the speed error is judged after this time [s] (the speed task starts in steady state)
SETTLE = 0.1
#: the torque task's step [N·m]
TORQUE_STEP = 5.0
#: the plant's stator resistance against the model's in the adaptive runs
R_S_DRIFT = 1.3
#: the low-speed hold: speed [rad/s], constant load [N·m], duration [s]
HOLD_SPEED, HOLD_LOAD, HOLD_DURATION = 10.0, 4.0, 1.5


def motor_file(name: str):
    return load_motor_file(f'{shipped_motors_dir()}/{name}.yaml')


def sensorless_reversal(motor: str, strategy: str = 'constant_flux', sensorless: bool = True,
                        **kw) -> Scenario:
    """
    Run the speed reversal +100 → −100 rad/s of one motor.

    +100 → −100 rad/s (quintic as fast as :func:`study_motors.reversal_time` allows for the
    span) against a constant 1 N·m, from steady state, the measured speed useless when sensorless.
    """
    m = motor_file(motor)
    ramp = reversal_time(m, span=2.0 * REVERSAL_SPEED / m.rated_speed)
    prof = Profile('speed', ((0.0, REVERSAL_SPEED, None), (0.2, -REVERSAL_SPEED, ramp)),
                   source='sensorless reversal')
    return Scenario(task='speed', strategy=strategy, motor=m, profile=prof,
                    load_model=ConstantLoad(tau=REVERSAL_LOAD), duration=0.2 + ramp + 0.8,
                    v_limit=m.rated_voltage,
                    controller_options=dict(scaled_options(m, 'speed'), sensorless=sensorless),
                    sensorless=sensorless,
                    speed_noise_std=USELESS_SPEED_NOISE if sensorless else 0.0, **kw)


def sensorless_options(sensorless: bool) -> dict:
    """
    Scenario keywords of a sensorless run.

    The measured speed useless, and the controller told that its θ, ω are the observer's
    (direct field orientation, docs/sensorless.md §4).
    """
    if not sensorless:
        return {'sensorless': False}
    return {'sensorless': True, 'speed_noise_std': USELESS_SPEED_NOISE,
            'controller_options': {'sensorless': True}}


def torque_task(strategy: str, sensorless: bool = True, **kw) -> Scenario:
    """
    Return the torque task: 0 → +5 → −5 N·m from rest, thesis motor.

    The unloaded shaft accelerates, then brakes through zero speed into the other direction.
    """
    prof = Profile('torque', ((0.0, 0.0, None), (0.1, TORQUE_STEP, None),
                              (0.4, -TORQUE_STEP, None)), source='sensorless torque task')
    opts = sensorless_options(sensorless)
    opts.update(kw)
    return Scenario(task='torque', strategy=strategy, profile=prof, duration=0.8, **opts)


def drifted_stator(motor=THESIS_MOTOR, factor: float = R_S_DRIFT) -> ParameterSchedule:
    """Return the plant's schedule: R_s ``factor`` × the model's (a warm stator), nothing else."""
    return ParameterSchedule(motor, {'R_s': constant(factor * motor.R_s)},
                             name=f'R_s x{factor:g}')


def adaptive_speed_task(sensorless: bool, strategy: str = 'min_loss', **kw) -> Scenario:
    """Return the thesis speed task, the plant's R_s drifted (run it with :func:`run_adaptive`)."""
    opts = sensorless_options(sensorless)
    opts.update(kw)
    return Scenario(task='speed', strategy=strategy, schedule=drifted_stator(), **opts)


def low_speed_hold(sensorless: bool = True, **kw) -> Scenario:
    """
    Return a 10 rad/s hold against a constant 4 N·m from steady state, the plant's R_s drifted.

    The low stator frequency where R_s weighs most in the voltage.
    """
    prof = Profile('speed', ((0.0, HOLD_SPEED, None),), source='low-speed hold')
    opts = sensorless_options(sensorless)
    opts.update(kw)
    return Scenario(task='speed', strategy='min_loss', profile=prof,
                    load_model=ConstantLoad(tau=HOLD_LOAD), duration=HOLD_DURATION,
                    schedule=drifted_stator(), **opts)


def run_adaptive(sc: Scenario, record_every: int = 1):
    """
    Run ``sc`` with the adapter on; return (result, estimate samples).

    The adapter runs the improved law with the inverse-Γ feed and is told ``sc.sensorless``;
    samples are rows (R_r, θ, L_M, R_R, L_σ, R_s).
    """
    hook = LockstepAdapter.build(sc.model_estimates(), sensorless=sc.sensorless)
    res = simulate(sc, adapter=hook, record_every=record_every)
    return res, np.asarray(hook.samples)


def torque_error_rms(result) -> float:
    tr = result.trace
    return float(np.sqrt(np.mean((tr['tau_m'] - tr['tau_ref']) ** 2)))


def _row(label: str, motor: str, strategy: str, sensored, sensorless) -> dict:
    tr = sensorless.trace
    late = tr['t'] >= SETTLE
    e = tr['omega_r'] - tr['omega_ref']
    return {'run': label, 'motor': motor, 'strategy': strategy,
            'trip': sensorless.summary['trip'],
            'speed_err_max': float(np.max(np.abs(e[late]))),
            'speed_err_end': float(e[-1]),
            'estimate_err_max': float(np.max(np.abs(tr['omega_hat'] - tr['omega_r']))),
            'speed_err_max_sensored': float(np.max(np.abs(sensored.trace['omega_r']
                                                          - sensored.trace['omega_ref']))),
            'E_loss_sensored': sensored.summary['E_loss_J'],
            'E_loss_sensorless': sensorless.summary['E_loss_J'],
            'loss_change': sensorless.summary['E_loss_J'] / sensored.summary['E_loss_J'] - 1.0}


def run(strategies=COMPARED_STRATEGIES, motors=MOTORS) -> list:
    rows = []
    for st in strategies:
        a = simulate(Scenario(task='speed', strategy=st))
        b = simulate(Scenario(task='speed', strategy=st, **sensorless_options(True)))
        rows.append(_row('thesis speed task', 'thesis', st, a, b))
    for mo in motors:
        for st in strategies:
            a = simulate(sensorless_reversal(mo, st, sensorless=False), record_every=10)
            b = simulate(sensorless_reversal(mo, st), record_every=10)
            rows.append(_row('±100 rad/s reversal, 1 N·m', mo, st, a, b))
    return rows


def run_torque(strategies=COMPARED_STRATEGIES) -> list:
    """Run the torque task per strategy: torque error RMS sensored and sensorless."""
    rows = []
    for st in strategies:
        a = simulate(torque_task(st, False))
        b = simulate(torque_task(st, True))
        tr = b.trace
        rows.append({'strategy': st, 'torque_rms_sensored': torque_error_rms(a),
                     'torque_rms_sensorless': torque_error_rms(b), 'trip': b.summary['trip'],
                     'estimate_err_max': float(np.max(np.abs(tr['omega_hat'] - tr['omega_r']))),
                     'omega_end': float(tr['omega_r'][-1])})
    return rows


def run_adapter() -> list:
    """
    Run the adapter on, the plant's R_s × R_S_DRIFT.

    The thesis speed task (min_loss) sensored and sensorless, and the sensorless low-speed hold
    (R̂_s at the end).
    """
    rows = []
    for label, make in (('thesis speed task, min_loss', adaptive_speed_task),
                        (f'{HOLD_SPEED:g} rad/s hold, {HOLD_LOAD:g} N·m, min_loss',
                         low_speed_hold)):
        (a, _), (b, s) = run_adaptive(make(False)), run_adaptive(make(True))
        late = b.trace['t'] >= (SETTLE if make is adaptive_speed_task else 1.0)
        e = b.trace['omega_r'] - b.trace['omega_ref']
        ea = a.trace['omega_r'] - a.trace['omega_ref']
        la = a.trace['t'] >= (SETTLE if make is adaptive_speed_task else 1.0)
        rows.append({'run': label, 'trip': b.summary['trip'],
                     'speed_err_max': float(np.max(np.abs(e[late]))),
                     'speed_err_max_sensored': float(np.max(np.abs(ea[la]))),
                     'E_loss_sensored': a.summary['E_loss_J'],
                     'E_loss_sensorless': b.summary['E_loss_J'],
                     'loss_change': b.summary['E_loss_J'] / a.summary['E_loss_J'] - 1.0,
                     'R_s_true': R_S_DRIFT * THESIS_MOTOR.R_s, 'R_s_end': float(s[-1, 5]),
                     'R_R_held': bool(np.all(s[:, 3] == s[0, 3])), 'L_M_end': float(s[-1, 2])})
    return rows


def commissioned_speed_task(motor, estimates, sensorless: bool = True) -> dict:
    """
    Run the thesis speed task (min_loss, 1.5 s) on ``motor`` with ``estimates`` as the model.

    Returns the trip, the speed error max after SETTLE [rad/s] and the losses [J].
    """
    r = simulate(Scenario(task='speed', strategy='min_loss', motor=motor, estimates=estimates,
                          duration=1.5, **sensorless_options(sensorless)))
    late = r.trace['t'] >= SETTLE
    return {'trip': r.summary['trip'], 'err': float(np.max(np.abs(
        r.trace['omega_r'][late] - r.trace['omega_ref'][late]))), 'loss': r.summary['E_loss_J']}


def run_commissioned(draws: int = 6, noise: float = 0.05) -> list:
    """
    Commission first, then run sensorless: motors of the campaign's parameter box.

    Per box motor with σ < 0.15 (:func:`im_studies.commission_study.motors`, the first
    ``draws``): the sensorless speed task with the thesis model, with the file the
    commissioning identified (current noise ``noise`` A, seed = the draw's index here), and
    the sensored drive with the true model.
    """
    rows = []
    for j, (name, m) in enumerate(x for x in motors(draws) if x[0].startswith('box')):
        _, ident, _ = identification_errors(m, noise, seed=j)
        rows.append({'motor': name, 'L_M_over_thesis': m.L_M / THESIS_MOTOR.L_M,
                     'nominal': commissioned_speed_task(m, THESIS_MOTOR),
                     'commissioned': commissioned_speed_task(
                         m, ident.motor(plate_of(m).ratings())),
                     'sensored_true': commissioned_speed_task(m, m, sensorless=False)})
    return rows


def _trip_cause(trip: dict) -> str:
    """Return a trip reason's cause without its values ('|V|' would split a table cell)."""
    return trip['reason'].split(':')[0].split(' |')[0]


def _trip_note(trip) -> str:
    """Return a table row's note of a trip ('' without one)."""
    return '' if trip is None else f' (trip: {_trip_cause(trip)})'


def commissioned_table(rows: list) -> str:
    out = ['| motor | L_M / thesis | sensorless, thesis model | sensorless, commissioned file '
           '| sensored, true model | losses: commissioned / true |',
           '| --- | ---: | --- | --- | --- | ---: |']

    def cell(r):
        if r['trip'] is not None:
            return f"trip at {1e3 * r['trip']['t']:.1f} ms ({_trip_cause(r['trip'])})"
        return f"{r['err']:.3f} rad/s"
    for r in rows:
        change = r['commissioned']['loss'] / r['sensored_true']['loss'] - 1.0
        out.append(f"| {r['motor']} | {r['L_M_over_thesis']:.2f} | {cell(r['nominal'])} "
                   f"| {cell(r['commissioned'])} | {cell(r['sensored_true'])} "
                   f'| {100 * change:+.2f} % |')
    return '\n'.join(out)


def torque_table(rows: list) -> str:
    out = ['| strategy | torque err RMS sensored [N·m] | sensorless [N·m] | ω̂ − ω max [rad/s] '
           '| ω at the end [rad/s] |', '| --- | --- | --- | --- | --- |']
    for r in rows:
        trip = _trip_note(r['trip'])
        out.append(f"| {r['strategy']}{trip} | {r['torque_rms_sensored']:.4f} "
                   f"| {r['torque_rms_sensorless']:.4f} | {r['estimate_err_max']:.3f} "
                   f"| {r['omega_end']:+.1f} |")
    return '\n'.join(out)


def adapter_table(rows: list) -> str:
    out = ['| run (plant R_s × 1.3, adapter on) | speed err max, sensored / sensorless [rad/s] '
           '| E_loss sensored [J] | E_loss sensorless [J] | change | R̂_s at the end (true) [Ω] '
           '| R̂_R held |', '| --- | --- | --- | --- | --- | --- | --- |']
    for r in rows:
        trip = _trip_note(r['trip'])
        out.append(f"| {r['run']}{trip} | {r['speed_err_max_sensored']:.3f} / "
                   f"{r['speed_err_max']:.3f} | {r['E_loss_sensored']:.1f} "
                   f"| {r['E_loss_sensorless']:.1f} | {100 * r['loss_change']:+.2f} % "
                   f"| {r['R_s_end']:.4f} ({r['R_s_true']:.4f}) "
                   f"| {'yes' if r['R_R_held'] else 'no'} |")
    return '\n'.join(out)


def table(rows: list) -> str:
    out = ['| run | motor | strategy | speed err max after 0.1 s [rad/s] | at the end | ω̂ − ω '
           'max '
           '| sensored err max | E_loss sensored [J] | E_loss sensorless [J] | change |',
           '| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |']
    for r in rows:
        trip = _trip_note(r['trip'])
        out.append(f"| {r['run']} | {r['motor']} | {r['strategy']}{trip} | "
                   f"{r['speed_err_max']:.3f} "
                   f"| {r['speed_err_end']:+.3f} | {r['estimate_err_max']:.3f} "
                   f"| {r['speed_err_max_sensored']:.4f} | {r['E_loss_sensored']:.1f} "
                   f"| {r['E_loss_sensorless']:.1f} | {100 * r['loss_change']:+.2f} % |")
    return '\n'.join(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--json', help='write the rows to this file')
    ap.add_argument('--strategy', action='append', choices=COMPARED_STRATEGIES)
    ap.add_argument('--motor', action='append', choices=MOTORS)
    ap.add_argument('--draws', type=int, default=6,
                    help='box motors commissioned, then run sensorless (default 6)')
    a = ap.parse_args(argv)
    rows = run(a.strategy or COMPARED_STRATEGIES, a.motor or MOTORS)
    print(table(rows))
    torque = run_torque(a.strategy or COMPARED_STRATEGIES)
    print()
    print(torque_table(torque))
    adapter = run_adapter()
    print()
    print(adapter_table(adapter))
    commissioned = run_commissioned(a.draws)
    print()
    print(commissioned_table(commissioned))
    if a.json:
        with open(a.json, 'w') as f:
            json.dump({'speed': rows, 'torque': torque, 'adapter': adapter,
                       'commissioned': commissioned}, f, indent=1)
    return 0


if __name__ == '__main__':
    sys.exit(main())
