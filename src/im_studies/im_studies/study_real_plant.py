"""
``python -m im_studies.study_real_plant [--part P ...] [--json FILE] [--plots DIR]``.

The drive on the real plant (docs/compensation.md), on the ROS-free loop: each shipped motor
(thesis, krause_3hp) on every block of docs/plant.md — the switched inverter (10 kHz, 2 µs dead
time, 1 V / 20 mΩ devices, V_dc for the motor's rating), the motor file's saturation and thermal
blocks, the iron loss acting, a 12-bit current ADC and a 2048-line encoder — beside the same run
on the ideal plant. Parts (default all):

- ``compensation``: a low-speed hold (10 rad/s, half the rated torque), sensored and
  sensorless, the inverter-error compensation off and on;
- ``sensorless``: with compensation, a ±150 rad/s reversal through zero under 2 N·m and a 5 s
  hold at 10 rad/s under the rated torque;
- ``load_step``: a step of half the rated torque at 100 rad/s, sensorless, at rated flux;
- ``losses``: from rest to +100 and a reversal to −100 rad/s under a quarter of the rated
  torque, sensored, min_loss and
  optimal, against the loss floor of the run within the drive's limits (current limit, flux
  cap; :mod:`im_studies.loss_bound`, on the plant's curve):
  the ideal plant, and every block with the drive on the curve (``saturation_model``) and with
  the linear model;
- ``commissioning``: the self-commissioning (docs/commissioning.md) on the ideal plant, behind
  the inverter alone, and on every block, against the motor file's values; the no-load test's
  magnetizing curve against the plant's (its worst L_M(ψ) over the points);
- ``identified``: min_loss on every block (the motor's rated-speed reversal) with the drive's
  model from the motor file and from the file the commissioning wrote: the losses side by side;
- ``thermal``, ``drift``, ``stator_error``, ``start``: the adapter on a 2-minute duty that warms
  the cage by 50 K (the motor file's thermal block; R̂_s, R̂_R at the end, tracking and losses
  against the drive handed the true resistances), on an R_s ramp with a leakage sine, with the
  plant's R_s a constant off the model's, and on the chapter-4 rows with the start flux scaled
  (:mod:`im_studies.study_adaptation`).

Prints a Markdown table per part and the wall time; ``--json`` writes the rows (and ``wall_s``,
``wall_parts_s`` per part, ``real_plant_kernel``: :class:`~im_studies.campaign_pool.WallTime`),
``--plots`` the phase current against its reference. Figures: the current distortion
``|i − i*|`` RMS [A] (the stator-current vector's distance from the controller's reference),
the speed error [rad/s] and the air-gap torque's standard deviation [N·m], over the last
:data:`WINDOW` s of a hold or after the transients; the dip and recovery of a load step
(:mod:`im_common.metrics`).
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import sys

from im_bringup.offline import Scenario, simulate
from im_common.cli import error as cli_error
from im_common.compensation import from_inverter
from im_common.inverter import Inverter
from im_common.loads import ConstantLoad, StepLoad
from im_common.params import load_motor_blocks, load_motor_file, RATING_NAMES, shipped_motors_dir
from im_common.saturation import saturation_from_dict
from im_controller.profiles import Profile
from im_plant.sensors import Sensors
from im_recording.plots import pyplot
import numpy as np

from . import study_adaptation
from .campaign_pool import wall_line, WallTime
from .commission_sim import commission_sim, COMPARED
from .loss_bound import drive_floor
from .study_adaptation import START_FLUXES
from .study_motors import reversal_time, scaled_options, scaled_scenario
from .study_sensorless import USELESS_SPEED_NOISE

MOTORS = ('thesis', 'krause_3hp')
PARTS = ('compensation', 'sensorless', 'load_step', 'losses', 'commissioning', 'identified',
         'thermal', 'drift', 'stator_error', 'start')
#: the parts run on the thesis motor alone (the seed's drift and chapter-4 rows)
THESIS_ONLY = ('drift', 'stator_error', 'start')
#: the inverter of every run: docs/plant.md's, its DC link set for the motor (V_dc_for)
INVERTER = {'pwm_frequency': 10000.0, 'deadtime': 2.0e-6, 'v_on': 1.0, 'r_on': 0.02}
#: the DC link over the motor's rated vector magnitude × √2 (the hexagon's inscribed circle)
DC_MARGIN = 1.1
#: the low-speed hold: speed [rad/s], load as a share of rated torque, duration [s]
HOLD_SPEED, HOLD_LOAD_SHARE, HOLD_DURATION = 10.0, 0.5, 1.5
#: the window the figures are taken over, at the end of each run [s]
WINDOW = 0.5
#: the reversal: ±speed [rad/s] under a constant load [N·m], from 0.2 s
REVERSAL_SPEED, REVERSAL_LOAD = 150.0, 2.0
#: the rated-torque hold: speed [rad/s], duration [s]
RATED_HOLD_SPEED, RATED_HOLD_DURATION = 10.0, 5.0
#: the speed error is judged this long after a transient ends [s]
SETTLE = 0.3
#: the losses part's reversal: ±speed [rad/s] under this share of the rated torque
LOSS_SPEED, LOSS_LOAD_SHARE = 100.0, 0.25
#: the load step: speed [rad/s], share of rated torque before / after, time [s], duration [s]
STEP_SPEED, STEP_BEFORE, STEP_AFTER, STEP_T, STEP_DURATION = 100.0, 1.0 / 6.0, 2.0 / 3.0, 0.5, 1.5


def V_dc_for(motor) -> float:
    """Return the DC link a motor gets: DC_MARGIN × √2 × its rated voltage, in whole volts."""
    return float(math.ceil(DC_MARGIN * math.sqrt(2.0) * motor.rated_voltage))


def real_plant(motor, delay: int = 0) -> dict:
    """
    Return the Scenario keywords of every block of the real plant for a motor file's motor.

    The inverter and sensors as their typed models (:class:`Inverter`, :class:`Sensors`);
    ``delay``: the inverter's computational delay in sampling periods.
    """
    return {'inverter': Inverter.from_block(dict(INVERTER, V_dc=V_dc_for(motor), delay=delay)),
            'saturation': 'motor', 'thermal': 'motor', 'iron_loss': True,
            'sensors': Sensors.from_block({'encoder_lines': 2048, 'adc_bits': 12,
                                           'current_range': float(math.ceil(
                                               3.0 * math.sqrt(2.0) * motor.rated_current))})}


def _scenario(motor_name: str, profile, load, duration: float, sensorless: bool,
              compensation: bool, real: bool, current_limit=None,
              strategy: str = 'min_energy') -> Scenario:
    path = os.path.join(shipped_motors_dir(), f'{motor_name}.yaml')
    m = load_motor_file(path)
    opts = dict(scaled_options(m, 'speed'), sensorless=sensorless)
    if current_limit is not None:
        opts['current_limit'] = current_limit * m.rated_current
    kw = {}
    if real:
        kw.update(real_plant(m))
        if compensation:
            kw['compensation'] = 'inverter'
    return Scenario(task='speed', strategy=strategy, motor=path, profile=profile,
                    load_model=load, duration=duration, v_limit=m.rated_voltage,
                    omega0=profile.setpoints[0][1], controller_options=opts,
                    sensorless=sensorless,
                    speed_noise_std=USELESS_SPEED_NOISE if sensorless else 0.0, **kw)


def hold(motor_name: str, sensorless: bool, compensation: bool, real: bool = True) -> Scenario:
    """Return the low-speed hold of one motor (module doc) on the real or the ideal plant."""
    m = load_motor_file(os.path.join(shipped_motors_dir(), f'{motor_name}.yaml'))
    prof = Profile('speed', ((0.0, HOLD_SPEED, None),), source='low-speed hold')
    return _scenario(motor_name, prof, ConstantLoad(tau=HOLD_LOAD_SHARE * m.rated_torque),
                     HOLD_DURATION, sensorless, compensation, real)


def reversal(motor_name: str, real: bool = True) -> tuple:
    """Return (scenario, end of its ramp [s]): ±REVERSAL_SPEED through zero, sensorless."""
    m = load_motor_file(os.path.join(shipped_motors_dir(), f'{motor_name}.yaml'))
    ramp = reversal_time(m, span=2.0 * REVERSAL_SPEED / m.rated_speed)
    prof = Profile('speed', ((0.0, REVERSAL_SPEED, None), (0.2, -REVERSAL_SPEED, ramp)),
                   source='sensorless reversal')
    return (_scenario(motor_name, prof, ConstantLoad(tau=REVERSAL_LOAD), 0.2 + ramp + 0.8,
                      True, True, real), 0.2 + ramp)


def rated_hold(motor_name: str, real: bool = True) -> Scenario:
    """Return RATED_HOLD_SPEED held for RATED_HOLD_DURATION under the rated torque, sensorless."""
    m = load_motor_file(os.path.join(shipped_motors_dir(), f'{motor_name}.yaml'))
    prof = Profile('speed', ((0.0, RATED_HOLD_SPEED, None),), source='rated-torque hold')
    return _scenario(motor_name, prof, ConstantLoad(tau=m.rated_torque), RATED_HOLD_DURATION,
                     True, True, real)


def load_step(motor_name: str, compensation: bool, real: bool = True) -> Scenario:
    """
    Return the load step of half the rated torque at STEP_SPEED, sensorless (module doc).

    At rated flux (constant_flux: a flux that follows the torque would have to build up first)
    and 1.5 × the rated current.
    """
    m = load_motor_file(os.path.join(shipped_motors_dir(), f'{motor_name}.yaml'))
    prof = Profile('speed', ((0.0, STEP_SPEED, None),), source='load step')
    load = StepLoad(t=STEP_T, tau_before=STEP_BEFORE * m.rated_torque,
                    tau_after=STEP_AFTER * m.rated_torque)
    return _scenario(motor_name, prof, load, STEP_DURATION, True, compensation, real,
                     current_limit=1.5, strategy='constant_flux')


def loss_reversal(motor_name: str, strategy: str, real: bool, on_curve: bool) -> Scenario:
    """Return the ±100 rad/s reversal of the losses part (module doc)."""
    m = load_motor_file(os.path.join(shipped_motors_dir(), f'{motor_name}.yaml'))
    ramp = 2.0 * reversal_time(m, span=2.0 * LOSS_SPEED / m.rated_speed)
    # from a standstill (magnetized): an encoder reads a shaft at rest exactly, so the drive
    # starts the reference the floor assumes (at a speed the M-method's first reading is a
    # count off, and the run follows a slightly different task)
    prof = Profile('speed', ((0.0, 0.0, None), (0.1, LOSS_SPEED, ramp),
                             (0.2 + ramp, -LOSS_SPEED, ramp)), source='loss reversal')
    sc = _scenario(motor_name, prof, ConstantLoad(tau=LOSS_LOAD_SHARE * m.rated_torque),
                   0.2 + 2.0 * ramp + 0.8, False, True, real, strategy=strategy)
    return dataclasses.replace(sc, saturation_model=on_curve)


def run_losses(motors=MOTORS) -> list:
    """Run the losses part: each motor × plant/drive × min_loss, optimal against the floor."""
    rows = []
    for mo in motors:
        for plant, real, curve in (('ideal plant', False, False),
                                   ('real plant, drive on the curve', True, True),
                                   ('real plant, linear drive', True, False)):
            for st in ('min_loss', 'optimal'):
                sc = loss_reversal(mo, st, real, curve)
                floor = drive_floor(sc).loss_J       # within the drive's own limits
                s = simulate(sc).summary
                rows.append({'motor': mo, 'plant': plant, 'strategy': st, 'E_loss_J':
                             s['E_loss_J'], 'floor_J': floor, 'ratio': s['E_loss_J'] / floor,
                             'speed_err_rms': s['speed_err_rms_rad_s'], 'trip': s['trip']})
    return rows


def figures(result, after: float = None) -> dict:
    """Return the figures of a run (module doc): the last WINDOW s, or from ``after`` on."""
    tr = result.trace
    late = tr['t'] >= (tr['t'][-1] - WINDOW if after is None else after)
    ei = np.hypot(tr['i_alpha'][late] - tr['i_alpha_ref'][late],
                  tr['i_beta'][late] - tr['i_beta_ref'][late])
    ew = tr['omega_r'][late] - tr['omega_ref'][late]
    return {'current_distortion_A': float(np.sqrt(np.mean(ei ** 2))),
            'speed_err_rms': float(np.sqrt(np.mean(ew ** 2))),
            'speed_err_max': float(np.max(np.abs(ew))),
            'torque_std': float(np.std(tr['tau_m'][late])),
            'trip': result.summary['trip']}


def _ideal(row: dict, ideal: dict) -> dict:
    row.update({f'ideal_{k}': v for k, v in ideal.items() if k != 'trip'})
    return row


def run_compensation(motors=MOTORS, plots=None) -> list:
    """Run every motor × sensored/sensorless × compensation off/on, and the ideal plant."""
    rows = []
    for mo in motors:
        for sensorless in (False, True):
            ideal = figures(simulate(hold(mo, sensorless, False, real=False)))
            runs = {}
            for comp in (False, True):
                res = simulate(hold(mo, sensorless, comp))
                runs[comp] = res
                rows.append(_ideal({'motor': mo, 'sensorless': sensorless, 'compensation': comp,
                                    **figures(res)}, ideal))
            off, on = rows[-2], rows[-1]
            on['distortion_factor'] = off['current_distortion_A'] / on['current_distortion_A']
            if plots is not None and mo == 'thesis' and not sensorless:
                plot_phase_current(runs, os.path.join(plots, 'compensation_phase_current.png'))
    return rows


def run_sensorless(motors=MOTORS) -> list:
    """Run the reversal and the rated-torque hold of every motor, compensation on."""
    rows = []
    for mo in motors:
        sc, end = reversal(mo)
        ideal_sc, _ = reversal(mo, real=False)
        label = f'±{REVERSAL_SPEED:g} rad/s reversal, {REVERSAL_LOAD:g} N·m'
        rows.append(_ideal({'motor': mo, 'run': label,
                            **figures(simulate(sc, record_every=10), after=end + SETTLE)},
                           figures(simulate(ideal_sc, record_every=10), after=end + SETTLE)))
        label = f'{RATED_HOLD_SPEED:g} rad/s, rated torque, {RATED_HOLD_DURATION:g} s'
        rows.append(_ideal({'motor': mo, 'run': label,
                            **figures(simulate(rated_hold(mo), record_every=10), after=1.0)},
                           figures(simulate(rated_hold(mo, real=False), record_every=10),
                                   after=1.0)))
    return rows


def run_load_step(motors=MOTORS) -> list:
    """Run the load step of every motor: the ideal plant, the real one without and with."""
    rows = []
    for mo in motors:
        for label, sc in (('ideal plant', load_step(mo, False, real=False)),
                          ('real plant', load_step(mo, False)),
                          ('real plant, compensation', load_step(mo, True))):
            s = simulate(sc).summary
            rows.append({'motor': mo, 'plant': label, 'dip': s['speed_dip_rad_s'],
                         'recovery_s': s['speed_recovery_s'], 'trip': s['trip'],
                         'step': f'{sc.plant_load().tau_before:.3g} → '
                                 f'{sc.plant_load().tau_after:.3g} N·m'})
    return rows


def plot_phase_current(runs: dict, path: str) -> None:
    """Phase a current against its reference, and its error, compensation off and on."""
    plt = pyplot()
    fig, axes = plt.subplots(2, 1, figsize=(8, 5.5), sharex=True)
    k = math.sqrt(2.0 / 3.0)            # phase a of a power-invariant αβ vector
    for comp in (False, True):
        tr = runs[comp].trace
        late = tr['t'] >= tr['t'][-1] - 0.2
        t = tr['t'][late]
        label = f"compensation {'on' if comp else 'off'}"
        if comp:
            axes[0].plot(t, k * tr['i_alpha_ref'][late], 'k--', lw=1, label='reference')
        axes[0].plot(t, k * tr['i_alpha'][late], lw=1, label=label)
        axes[1].plot(t, k * (tr['i_alpha'][late] - tr['i_alpha_ref'][late]), lw=1, label=label)
    axes[0].set_ylabel('i_a [A]')
    axes[0].set_title(f'thesis motor, {HOLD_SPEED:g} rad/s, {HOLD_LOAD_SHARE:.0%} rated torque, '
                      '10 kHz inverter with 2 µs dead time')
    axes[1].set_ylabel('i_a − i_a* [A]')
    axes[1].set_xlabel('t [s]')
    for ax in axes:
        ax.grid(True, alpha=0.3)
        ax.legend(loc='upper right')
    fig.tight_layout()
    os.makedirs(os.path.dirname(path) or '.', exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def identify(motor_name: str, blocks: dict):
    """
    Commission a shipped motor behind ``blocks`` (no-load test too); return (Identified, blocks).

    Deterministic, so kept for the process: the commissioning and identified parts share it.
    """
    path = os.path.join(shipped_motors_dir(), f'{motor_name}.yaml')
    kw = dict(blocks)
    for name in ('saturation', 'thermal'):
        if kw.get(name) == 'motor':
            kw[name] = load_motor_blocks(path)[name]
    key = (motor_name, json.dumps(kw, sort_keys=True, default=lambda block: block.describe()))
    if key not in _IDENTIFIED:
        m = load_motor_file(path)
        _IDENTIFIED[key] = commission_sim(m, blocks=kw, magnetizing=True).result()
    return _IDENTIFIED[key], kw


_IDENTIFIED: dict = {}


def commission(motor_name: str, blocks: dict) -> dict:
    """Commission a shipped motor behind ``blocks``; return the errors [%] and the inverter fit."""
    m = load_motor_file(os.path.join(shipped_motors_dir(), f'{motor_name}.yaml'))
    ident, kw = identify(motor_name, blocks)
    truth = dict(m.identifiable(), J=m.J)
    out = {f'{n}_err_pct': 100.0 * (ident.values[n] / truth[n] - 1.0) for n in COMPARED}
    out.update(magnetizing_errors(ident.magnetizing, m, kw.get('saturation')))
    inv = blocks.get('inverter')            # an Inverter (real_plant) or None
    r_on = inv.r_on if inv is not None else 0.0
    out['R_s_r_on_err_pct'] = 100.0 * (ident.values['R_s'] / (truth['R_s'] + r_on) - 1.0)
    v_dead = from_inverter(inv).v_dead if inv is not None else 0.0
    out['v_dead'] = ident.inverter.get('v_dead', 0.0)
    out['v_dead_err_pct'] = 100.0 * (out['v_dead'] / v_dead - 1.0) if v_dead else None
    return out


def magnetizing_errors(points, motor, saturation) -> dict:
    """
    Return the no-load test's points and their worst L_M(ψ) error [%] against the plant's curve.

    The plant's curve: its ``saturation`` block, or the constant L_M0 without one.
    """
    L_M0 = motor.L_sr ** 2 / motor.L_r
    curve = saturation_from_dict(saturation, L_M0) if saturation else None
    errs = []
    for p in points:
        true_i = curve.current(p['psi']) if curve else p['psi'] / L_M0
        errs.append(100.0 * (true_i / p['i_M'] - 1.0))      # L_M = ψ/i_M at the same ψ
    worst = max(errs, key=abs) if errs else None
    return {'L_M_curve_points': len(points), 'L_M_curve_err_max_pct': worst,
            'L_M_curve_psi_max': max((p['psi'] for p in points), default=None)}


def run_commissioning(motors=MOTORS) -> list:
    """Commission every motor on the ideal plant, behind the inverter, and on every block."""
    rows = []
    for mo in motors:
        m = load_motor_file(os.path.join(shipped_motors_dir(), f'{mo}.yaml'))
        full = real_plant(m)
        for label, blocks in (('ideal', {}), ('inverter', {'inverter': full['inverter']}),
                              ('every block', full)):
            rows.append({'motor': mo, 'plant': label, **commission(mo, blocks)})
    return rows


def identified_drive(motor_name: str, ident=None) -> list:
    """
    min_loss on every block, the drive's model from the true file and from the commissioned one.

    The rated-speed reversal of the motor's speed task (:func:`study_motors.scaled_scenario`),
    sensored, compensation on: with the motor file (its compensation from the inverter's
    data) and with the file the commissioning on every block wrote (its parameters, ratings,
    v_dead; k_e = k_h = 0, the core loss is not identified). Returns one row per file.
    """
    path = os.path.join(shipped_motors_dir(), f'{motor_name}.yaml')
    m = load_motor_file(path)
    if ident is None:
        ident, _ = identify(motor_name, real_plant(m))
    est = ident.motor({n: getattr(m, n) for n in RATING_NAMES})
    rows = []
    base = scaled_scenario(m, 'speed', 'min_loss')
    for label, model, comp in (
            ('motor file', None, 'inverter'),
            ('commissioned', est, {'v_dead': ident.inverter['v_dead'],
                                   'current_band': ident.inverter['current_band']})):
        sc = dataclasses.replace(base, motor=path, estimates=model, compensation=comp,
                                 controller_options=scaled_options(model or m, 'speed'),
                                 **real_plant(m))
        res = simulate(sc)
        s = res.summary
        rows.append({'motor': motor_name, 'file': label, 'E_loss_J': s['E_loss_J'],
                     'E_in_J': s['E_in_J'], 'speed_err_rms': s['speed_err_rms_rad_s'],
                     'trip': s['trip']})
    rows[1]['E_loss_vs_file_pct'] = 100.0 * (rows[1]['E_loss_J'] / rows[0]['E_loss_J'] - 1.0)
    return rows


def run_identified(motors=MOTORS) -> list:
    """Run :func:`identified_drive` for every motor."""
    return [r for mo in motors for r in identified_drive(mo)]


def _trip(r) -> str:
    return '' if r['trip'] is None else r['trip']['reason']


def _compensation_table(rows: list) -> list:
    """Return the lines of the compensation part's table."""
    lines = ['| motor | speed | compensation | \\|i − i*\\| RMS [A] (ideal plant) | factor '
             '| speed error RMS [rad/s] (ideal) | torque std [N·m] (ideal) | trip |',
             '| --- | --- | --- | ---: | ---: | ---: | ---: | --- |']
    for r in rows:
        factor = f"{r['distortion_factor']:.1f}×" if 'distortion_factor' in r else ''
        lines.append(
            f"| {r['motor']} | {'sensorless' if r['sensorless'] else 'sensored'} | "
            f"{'on' if r['compensation'] else 'off'} | {r['current_distortion_A']:.4f} "
            f"({r['ideal_current_distortion_A']:.4f}) | {factor} | "
            f"{r['speed_err_rms']:.4f} ({r['ideal_speed_err_rms']:.4f}) | "
            f"{r['torque_std']:.4f} ({r['ideal_torque_std']:.4f}) | {_trip(r)} |")
    return lines


def _sensorless_table(rows: list) -> list:
    """Return the lines of the sensorless part's table."""
    lines = ['| motor | run | speed error max [rad/s] (ideal plant) | RMS (ideal) | '
             '\\|i − i*\\| RMS [A] (ideal) | trip |',
             '| --- | --- | ---: | ---: | ---: | --- |']
    for r in rows:
        lines.append(f"| {r['motor']} | {r['run']} | {r['speed_err_max']:.3f} "
                     f"({r['ideal_speed_err_max']:.3f}) | {r['speed_err_rms']:.3f} "
                     f"({r['ideal_speed_err_rms']:.3f}) | {r['current_distortion_A']:.3f} "
                     f"({r['ideal_current_distortion_A']:.3f}) | {_trip(r)} |")
    return lines


def _commissioning_table(rows: list) -> list:
    """Return the lines of the commissioning part's table."""
    lines = ['| plant | motor | v_dead | R_s (R_s + r_on) | σL_s | L_M | R_R | J | '
             'L_M(ψ): points up to ψ_R [Wb], worst |',
             '|---|---|---:|---:|---:|---:|---:|---:|---:|']
    for r in rows:
        vd = ('~0' if r['v_dead_err_pct'] is None else f"{r['v_dead_err_pct']:+.1f} %")
        lines.append(f"| {r['plant']} | {r['motor']} | {vd} | {r['R_s_err_pct']:+.2f} % "
                     f"({r['R_s_r_on_err_pct']:+.2f} %) | {r['L_sigma_err_pct']:+.2f} % | "
                     f"{r['L_M_err_pct']:+.2f} % | {r['R_R_err_pct']:+.2f} % | "
                     f"{r['J_err_pct']:+.2f} % | {r['L_M_curve_points']} up to "
                     f"{r['L_M_curve_psi_max']:.3f}, {r['L_M_curve_err_max_pct']:+.2f} % |")
    return lines


def _losses_table(rows: list) -> list:
    """Return the lines of the losses part's table."""
    lines = ['| motor | plant | strategy | losses [J] | floor [J] | losses / floor | speed '
             'error RMS [rad/s] | trip |',
             '| --- | --- | --- | ---: | ---: | ---: | ---: | --- |']
    for r in rows:
        lines.append(f"| {r['motor']} | {r['plant']} | {r['strategy']} | "
                     f"{r['E_loss_J']:.2f} | {r['floor_J']:.2f} | {r['ratio']:.4f} | "
                     f"{r['speed_err_rms']:.4f} | {_trip(r)} |")
    return lines


def _identified_table(rows: list) -> list:
    """Return the lines of the identified part's table."""
    lines = ['| motor | drive file | motor losses [J] | vs the motor file | speed error '
             'RMS [rad/s] | trip |', '| --- | --- | ---: | ---: | ---: | --- |']
    for r in rows:
        vs = f"{r['E_loss_vs_file_pct']:+.2f} %" if 'E_loss_vs_file_pct' in r else ''
        lines.append(f"| {r['motor']} | {r['file']} | {r['E_loss_J']:.1f} | {vs} | "
                     f"{r['speed_err_rms']:.4f} | {_trip(r)} |")
    return lines


def _thermal_table(rows: list) -> list:
    """Return the lines of the thermal part's table."""
    lines = ['| motor | drive | ΔT cage / stator [K] | R̂_s − R_s | R̂_R − R_R | speed error '
             'RMS [rad/s] | × true-R run | losses vs true-R run | trip |',
             '| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | --- |']
    for r in rows:
        lines.append(f"| {r['motor']} | {r['run']} | {r['dT_rotor_K']:.1f} / "
                     f"{r['dT_stator_K']:.1f} | {100 * r['R_s_err_end']:+.2f} % | "
                     f"{100 * r['R_R_err_end']:+.2f} % | {r['speed_err_rms_rad_s']:.4f} | "
                     f"{r['speed_err_over_true']:.2f} | "
                     f"{100 * (r['E_loss_over_true'] - 1):+.2f} % | {_trip(r)} |")
    return lines


def _drift_table(rows: list) -> list:
    """Return the lines of the drift part's table."""
    lines = ['| drive | speed error RMS [rad/s] | R̂_s at the end (true) [Ω] | L̂_M error at '
             'the end | trip |', '| --- | ---: | ---: | ---: | --- |']
    for r in rows:
        rs = f"{r['R_s_end']:.4f} ({r['R_s_true_end']:.4f})" if 'R_s_end' in r else ''
        lm = f"{100 * r['L_M_err_end']:+.1f} %" if 'L_M_err_end' in r else ''
        lines.append(f"| {r['run']} | {r['speed_err_rms_rad_s']:.4f} | {rs} | {lm} | "
                     f'{_trip(r)} |')
    return lines


def _stator_error_table(rows: list) -> list:
    """Return the lines of the stator_error part's table."""
    lines = ['| strategy | plant R_s over the model | nominal: speed error RMS [rad/s] | '
             'adaptive | × nominal | R̂_R error at the end | L̂_M error at the end | trip |',
             '| --- | ---: | ---: | ---: | ---: | ---: | ---: | --- |']
    for r in rows:
        trip = r['nominal_trip'] or r['adaptive_trip'] or ''
        nom, ad = r['nominal_speed_err_rms_rad_s'], r['adaptive_speed_err_rms_rad_s']
        lines.append(f"| {r['strategy']} | {1.0 + r['R_s_error']:.2f} | {nom:.5f} | "
                     f"{ad:.5f} | {ad / nom:.2f} | {100 * r['R_R_err_end']:+.2f} % | "
                     f"{100 * r['L_M_err_end']:+.2f} % | {trip} |")
    return lines


def _start_table(rows: list) -> list:
    """Return the lines of the start part's table."""
    lines = ['| task | strategy | ' + ' | '.join(f'start flux ×{f:g}' for f in START_FLUXES)
             + ' | target | met |', '| --- | --- |' + ' ---: |' * len(START_FLUXES)
             + ' ---: | --- |']
    for r in rows:
        errs = {float(f): e for f, e in r['errors'].items()}     # JSON keys are text
        cells = [f'{errs[f]:.4f}' if f in errs else '(at rest)' for f in START_FLUXES]
        lines.append(f"| {r['task']} | {r['strategy']} | {' | '.join(cells)} | "
                     f"{r['target']} | {'yes' if r['met'] else 'no'} |")
    return lines


def _load_step_table(rows: list) -> list:
    """Return the lines of the load-step part's table (every other part)."""
    lines = ['| motor | step | plant | dip [rad/s] | back within 2 rad/s after [s] | trip |',
             '| --- | --- | --- | ---: | ---: | --- |']
    for r in rows:
        rec = 'not within the run' if not math.isfinite(r['recovery_s']) else \
            f"{r['recovery_s']:.3f}"
        lines.append(f"| {r['motor']} | {r['step']} | {r['plant']} | {r['dip']:.2f} | "
                     f'{rec} | {_trip(r)} |')
    return lines


#: each part's table (a part not here: the load step's)
_TABLES = {
    'compensation': _compensation_table,
    'sensorless': _sensorless_table,
    'commissioning': _commissioning_table,
    'losses': _losses_table,
    'identified': _identified_table,
    'thermal': _thermal_table,
    'drift': _drift_table,
    'stator_error': _stator_error_table,
    'start': _start_table,
}


def markdown(part: str, rows: list) -> str:
    """Return a part's rows as a Markdown table, real-plant figures beside the ideal plant's."""
    return '\n'.join(_TABLES.get(part, _load_step_table)(rows))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog='study_real_plant', description=__doc__.split('\n\n')[1])
    ap.add_argument('--part', choices=PARTS, action='append',
                    help='run only this part (repeatable; default: every part)')
    ap.add_argument('--json', metavar='FILE', help='write the rows as JSON')
    ap.add_argument('--plots', metavar='DIR', help='write the plots here')
    a = ap.parse_args(argv)
    clock = WallTime()
    out = {}
    runs = {'compensation': lambda: run_compensation(plots=a.plots),
            'sensorless': run_sensorless, 'load_step': run_load_step, 'losses': run_losses,
            'commissioning': run_commissioning, 'identified': run_identified,
            'thermal': lambda: study_adaptation.run_thermal(plots=a.plots),
            'drift': study_adaptation.run_drift,
            'stator_error': study_adaptation.run_stator_error,
            'start': study_adaptation.run_start}
    for k, part in enumerate(a.part or PARTS, 1):
        motors = ('thesis',) if part in THESIS_ONLY else MOTORS
        print(f'[{k}/{len(a.part or PARTS)}] {part}: {", ".join(motors)}', file=sys.stderr,
              flush=True)
        with clock.part(part):
            out[part] = runs[part]()
        print(f'\n## {part}\n\n{markdown(part, out[part])}', flush=True)
    out.update(clock.figures())
    print(f'\n{wall_line(out)}', flush=True)
    if a.json:
        try:
            os.makedirs(os.path.dirname(a.json) or '.', exist_ok=True)
            with open(a.json, 'w') as f:
                json.dump(out, f, indent=2)
        except OSError as exc:
            return cli_error('study_real_plant', f'{a.json}: {exc.strerror or exc}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
