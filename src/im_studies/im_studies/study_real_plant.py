"""
``python -m im_studies.study_real_plant [--part compensation] [--json FILE] [--plots DIR]``.

The drive on the real plant (docs/compensation.md), on the ROS-free loop: each shipped motor
(thesis, krause_3hp) fed by the switched inverter of docs/plant.md (10 kHz, 2 µs dead time,
1 V / 20 mΩ devices, V_dc for the motor's rating), held at a low speed against half its rated
torque, sensored and sensorless, with the inverter-error compensation off and on. Beside each
figure the same run on the ideal plant. Prints a Markdown table; ``--json`` writes the rows,
``--plots`` the phase current against its reference.

Figures over the last :data:`WINDOW` s of each run (steady state): the current distortion
``|i − i*|`` RMS [A] (the stator-current vector's distance from the controller's reference), the
speed error RMS [rad/s] and the air-gap torque's standard deviation [N·m].
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys

from im_bringup.offline import Scenario, simulate
from im_common.cli import error as cli_error
from im_common.loads import ConstantLoad
from im_common.params import load_motor_file, shipped_motors_dir
from im_controller.profiles import Profile
import numpy as np

from .study_motors import scaled_options
from .study_sensorless import USELESS_SPEED_NOISE

MOTORS = ('thesis', 'krause_3hp')
#: the inverter of every run: docs/plant.md's, its DC link set for the motor (V_dc_for)
INVERTER = {'pwm_frequency': 10000.0, 'deadtime': 2.0e-6, 'v_on': 1.0, 'r_on': 0.02}
#: the DC link over the motor's rated vector magnitude × √2 (the hexagon's inscribed circle)
DC_MARGIN = 1.1
#: the low-speed hold: speed [rad/s], load as a share of rated torque, duration [s]
HOLD_SPEED, HOLD_LOAD_SHARE, HOLD_DURATION = 10.0, 0.5, 1.5
#: the window the figures are taken over, at the end of each run [s]
WINDOW = 0.5
#: the load where a motor file gives no rating [N·m]
FALLBACK_LOAD = 4.0


def V_dc_for(motor) -> float:
    """Return the DC link a motor gets: DC_MARGIN × √2 × its rated voltage, in whole volts."""
    return float(math.ceil(DC_MARGIN * math.sqrt(2.0) * motor.rated_voltage))


def hold(motor_name: str, sensorless: bool, compensation: bool, real: bool = True) -> Scenario:
    """Return the low-speed hold of one motor (module doc) on the real or the ideal plant."""
    path = os.path.join(shipped_motors_dir(), f'{motor_name}.yaml')
    m = load_motor_file(path)
    load = HOLD_LOAD_SHARE * m.rated_torque if m.rated_torque > 0 else FALLBACK_LOAD
    prof = Profile('speed', ((0.0, HOLD_SPEED, None),), source='low-speed hold')
    opts = dict(scaled_options(m, 'speed'), sensorless=sensorless)
    kw = {}
    if real:
        kw['inverter'] = dict(INVERTER, V_dc=V_dc_for(m))
        if compensation:
            kw['compensation'] = 'inverter'
    return Scenario(task='speed', strategy='min_energy', motor=path, profile=prof,
                    load_model=ConstantLoad(tau=load), duration=HOLD_DURATION,
                    v_limit=m.rated_voltage, controller_options=opts, sensorless=sensorless,
                    speed_noise_std=USELESS_SPEED_NOISE if sensorless else 0.0, **kw)


def figures(result) -> dict:
    """Return the steady-state figures of a run (module doc)."""
    tr = result.trace
    late = tr['t'] >= tr['t'][-1] - WINDOW
    ei = np.hypot(tr['i_alpha'][late] - tr['i_alpha_ref'][late],
                  tr['i_beta'][late] - tr['i_beta_ref'][late])
    ew = tr['omega_r'][late] - tr['omega_ref'][late]
    return {'current_distortion_A': float(np.sqrt(np.mean(ei ** 2))),
            'speed_err_rms': float(np.sqrt(np.mean(ew ** 2))),
            'torque_std': float(np.std(tr['tau_m'][late])),
            'trip': result.summary['trip']}


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
                row = {'motor': mo, 'sensorless': sensorless, 'compensation': comp,
                       **figures(res)}
                row.update({f'ideal_{k}': v for k, v in ideal.items() if k != 'trip'})
                rows.append(row)
            off, on = rows[-2], rows[-1]
            on['distortion_factor'] = off['current_distortion_A'] / on['current_distortion_A']
            if plots is not None and mo == 'thesis' and not sensorless:
                plot_phase_current(runs, os.path.join(plots, 'compensation_phase_current.png'))
    return rows


def plot_phase_current(runs: dict, path: str) -> None:
    """Phase a current against its reference, and its error, compensation off and on."""
    from im_recording.plots import pyplot
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


def markdown(rows: list) -> str:
    """Return the rows as a Markdown table, each real-plant figure beside the ideal plant's."""
    lines = ['| motor | speed | compensation | \\|i − i*\\| RMS [A] (ideal plant) | factor | '
             'speed error RMS [rad/s] (ideal) | torque std [N·m] (ideal) | trip |',
             '| --- | --- | --- | ---: | ---: | ---: | ---: | --- |']
    for r in rows:
        factor = f"{r['distortion_factor']:.1f}×" if 'distortion_factor' in r else ''
        trip = '' if r['trip'] is None else r['trip']['reason']
        lines.append(
            f"| {r['motor']} | {'sensorless' if r['sensorless'] else 'sensored'} | "
            f"{'on' if r['compensation'] else 'off'} | {r['current_distortion_A']:.4f} "
            f"({r['ideal_current_distortion_A']:.4f}) | {factor} | "
            f"{r['speed_err_rms']:.4f} ({r['ideal_speed_err_rms']:.4f}) | "
            f"{r['torque_std']:.4f} ({r['ideal_torque_std']:.4f}) | {trip} |")
    return '\n'.join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog='study_real_plant', description=__doc__.split('\n\n')[1])
    ap.add_argument('--part', choices=('compensation',), default='compensation')
    ap.add_argument('--json', metavar='FILE', help='write the rows as JSON')
    ap.add_argument('--plots', metavar='DIR', help='write the plots here')
    a = ap.parse_args(argv)
    print(f'{a.part}: {len(MOTORS)} motors x sensored/sensorless x compensation off/on, '
          f'{HOLD_DURATION:g} s each', file=sys.stderr, flush=True)
    rows = run_compensation(plots=a.plots)
    print(markdown(rows))
    if a.json:
        try:
            os.makedirs(os.path.dirname(a.json) or '.', exist_ok=True)
            with open(a.json, 'w') as f:
                json.dump(rows, f, indent=2)
        except OSError as exc:
            return cli_error('study_real_plant', f'{a.json}: {exc.strerror or exc}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
