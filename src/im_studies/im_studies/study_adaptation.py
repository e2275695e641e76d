"""
The adapter on a warming motor and on drifts it never saw (docs/adaptation.md §9).

Four parts, each a table ``python -m im_studies.study_real_plant --part NAME`` prints:

``thermal``
    A 2-minute duty on each shipped motor with its ``thermal`` block: the speed task repeated
    (:data:`DUTY_HIGH` rad/s for 3 s, down to :data:`DUTY_LOW` rad/s for 3 s, back; 2 s
    transitions, 4 s on krause_3hp; 2 minutes) under a constant load that warms the cage by 40 K or
    more. The drive runs min_loss with its current limit at 2.5 × the rated current. Sensored: the
    drive handed the plant's true R_s and R_R every step (:class:`TrueResistances`, the bound), the
    nominal drive (the motor file's cold resistances), the sensored adapter estimating R_s with
    R_R, L_M, L_σ (alone, then carried between its updates by the motor's thermal networks
    re-anchored at each, :mod:`im_adapt.thermal_tracking`, then by networks whose thermal
    resistances are 20 % off); and sensorless the same three, the adapter there taking R_s and
    R_R from the windings' temperatures (the least squares held), once more with the cage's
    thermal resistance 20 % off. Reported: R̂_s and R̂_R against the plant's at the
    end, speed error RMS over the run against the true-resistance run's (same sensing), losses
    against its.
``drift``
    The plant's R_s ramping to 1.3× over 2 s with a ±15 % sine on both leakages (speed task,
    min_energy, thesis motor): nominal against the adapter without and with R_s.
``stator_error``
    The drift part's task with the plant's R_s a constant 0 … 30 % above the model's, every
    strategy: the nominal drive against the adapter that takes R_s from the model.
``start``
    The chapter-4 rows of ``make reproduce`` (adaptive) with the speed task's start flux scaled
    by 0.98 … 1.02 (``start_flux``); the position task starts at rest, demagnetised, where there
    is no start flux to scale.
"""
from __future__ import annotations

import math
import os
import sys

from im_adapt.adaptation import AdaptationGains
from im_adapt.hook import LockstepAdapter
from im_bringup.offline import Scenario, simulate
from im_common.loads import ConstantLoad
from im_common.params import (constant, load_motor_file, ParameterSchedule, ramp,
                              shipped_motors_dir, sinusoid, THESIS_MOTOR)
from im_controller.control_law import THESIS_TASKS
from im_controller.flux import COMPARED_STRATEGIES
from im_controller.profiles import Profile
from im_recording.plots import pyplot
import numpy as np

from .study_ch4 import gains_for, run_case
from .study_motors import scaled_options
from .study_sensorless import USELESS_SPEED_NOISE

#: the duty: high and low speed [rad/s], their holds [s], the transition [s], cycles
DUTY_HIGH, DUTY_LOW, DUTY_HOLD_HIGH, DUTY_HOLD_LOW = 150.0, 20.0, 3.0, 3.0
#: the duty's length [s]
DUTY_DURATION = 120.0
#: per motor: the load over its rated torque (the cage warms >= 40 K in 2 min) and the
#: transitions [s] (the load plus J dω/dt within the current limit)
DUTY_LOAD = {'thesis': 14.0 / 12.0, 'krause_3hp': 1.4}
DUTY_RAMP = {'thesis': 2.0, 'krause_3hp': 4.0}
#: the duty's current limit over the rated current (the load plus the transitions' J dω/dt)
DUTY_CURRENT = 2.5
#: the duty's runs, sensored then sensorless: the drive handed the true resistances (the bound),
#: the nominal drive, the adapter (sensored: the least squares with R_s alone, then carried by
#: the motor's thermal networks, then by networks whose block is off; ``_networks``: R_s from the
#: networks alone, R_R from the least squares re-anchoring the cage's); sensorless also the adapter
#: whose thermal block is off. Off: the cage's R_th × THERMAL_OFF, its C / THERMAL_OFF (the same
#: time constant, 20 % more rise); sensored the stator's too (R_s is what the least squares
#: learn least often)
DUTY_RUNS = ('true_resistances', 'nominal', 'adaptive', 'adaptive_thermal',
             'adaptive_thermal_off', 'adaptive_networks', 'adaptive_networks_off',
             'true_resistances_sensorless', 'nominal_sensorless', 'adaptive_sensorless',
             'adaptive_sensorless_off')
THERMAL_OFF = 1.2
#: the start fluxes of the ``start`` part
START_FLUXES = (0.98, 0.99, 1.0, 1.01, 1.02)


def duty_period(motor_name: str) -> float:
    """Return one cycle of a motor's duty [s]."""
    return DUTY_HOLD_HIGH + DUTY_HOLD_LOW + 2.0 * DUTY_RAMP[motor_name]


def duty_profile(motor_name: str, cycles: int) -> Profile:
    """Return the duty's speed setpoints: high, down to low, back up, ``cycles`` times."""
    ramp, period = DUTY_RAMP[motor_name], duty_period(motor_name)
    pts = [(0.0, DUTY_HIGH, None)]
    for k in range(cycles):
        t0 = k * period
        pts.append((t0 + DUTY_HOLD_HIGH, DUTY_LOW, ramp))
        pts.append((t0 + DUTY_HOLD_HIGH + ramp + DUTY_HOLD_LOW, DUTY_HIGH, ramp))
    return Profile('speed', tuple(pts), source='thermal duty')


def duty(motor_name: str, sensorless: bool = False, duration: float = None,
         cycles: int = None) -> Scenario:
    """
    Return the duty of one shipped motor (module doc): its thermal block, min_loss.

    ``cycles`` (default: as many as :data:`DUTY_DURATION` holds) sets the profile, ``duration``
    (default: :data:`DUTY_DURATION`, or ``cycles`` whole cycles) the run.
    """
    path = os.path.join(shipped_motors_dir(), f'{motor_name}.yaml')
    m = load_motor_file(path)
    period = duty_period(motor_name)
    if duration is None:
        duration = DUTY_DURATION if cycles is None else cycles * period
    if cycles is None:
        cycles = math.ceil(duration / period)
    opts = dict(scaled_options(m, 'speed'), sensorless=sensorless,
                current_limit=DUTY_CURRENT * m.rated_current)
    return Scenario(task='speed', strategy='min_loss', motor=path,
                    profile=duty_profile(motor_name, cycles),
                    load_model=ConstantLoad(tau=DUTY_LOAD[motor_name] * m.rated_torque),
                    duration=duration, v_limit=m.rated_voltage, omega0=DUTY_HIGH,
                    controller_options=opts, sensorless=sensorless, thermal='motor',
                    speed_noise_std=USELESS_SPEED_NOISE if sensorless else 0.0)


class TrueResistances:
    """
    Hand the drive the plant's R_s and R_R of the present winding temperatures (a bound).

    The model's L_σ and L_M stay the motor file's: the run a perfect resistance adapter would
    give. ``bind`` is given the plant by the ROS-free loop.
    """

    def __init__(self, model):
        self.model = model
        self.plant = None

    def bind(self, plant) -> None:
        self.plant = plant

    def truth(self) -> tuple:
        """Return the plant's (R_s, R_R) now."""
        mdl = self.plant.real.model
        return self.model.R_s * mdl.fs, self.model.R_R * mdl.fr

    def step(self, T_s, t, v_alpha, v_beta, meas, x_hat) -> dict:
        R_s, R_R = self.truth()
        m = self.model
        return {'R_s': R_s, 'L_sigma': m.L_sigma, 'L_M': m.L_M, 'R_R': R_R}


class Truth:
    """
    Follow the plant's true R_s and R_R beside an adapter (``bind`` as above).

    ``truth.truth()`` gives them now; ``series`` holds, every ``series_every`` steps, (t, R̂_s,
    R_s, R̂_R, R_R) with the estimates the adapter hands the drive.
    """

    def __init__(self, hook, model, series_every: int = 10000):
        self.hook, self.model = hook, model
        self.truth = TrueResistances(model)
        self.series_every = series_every
        self.k = 0
        self.series = []

    def bind(self, plant) -> None:
        self.truth.bind(plant)

    def step(self, T_s, t, v_alpha, v_beta, meas, x_hat) -> dict:
        self.k += 1
        est = self.hook.step(T_s, t, v_alpha, v_beta, meas, x_hat)
        if self.k % self.series_every == 0:
            R_s, R_R = self.truth.truth()
            self.series.append((t + T_s, est.get('R_s', self.model.R_s), R_s,
                                est.get('R_R', self.model.R_R), R_R))
        return est


def duty_run(motor_name: str, run: str, duration: float = None,
             cycles: int = None, progress: bool = False) -> dict:
    """Run one of :data:`DUTY_RUNS` on one motor; return its figures."""
    sensorless = run.endswith('_sensorless') or '_sensorless_' in run
    sc = duty(motor_name, sensorless, duration, cycles)
    model = sc.model_estimates()
    if run.startswith('true_resistances'):
        hook = TrueResistances(model)
    elif run.startswith('nominal'):
        hook = Truth(_Nominal(), model)
    elif sensorless:            # R_s, R_R from the windings' temperatures, L_σ and L_M held
        hook = Truth(LockstepAdapter.build(model, AdaptationGains(freeze=True), sensorless=True,
                                           thermal=_block(sc, run, ('r',)), record_every=0),
                     model)
    else:                       # the least squares (carried by the networks: '_thermal'; R_s
        #                         the networks' alone: '_networks')
        gains = AdaptationGains(estimate_stator_resistance='_networks' not in run)
        thermal = (_block(sc, run, ('s', 'r')) if '_thermal' in run or '_networks' in run
                   else None)
        hook = Truth(LockstepAdapter.build(model, gains, thermal=thermal, record_every=0),
                     model)
    res = simulate(sc, adapter=hook, record_every=100, progress=progress)
    tr = res.trace
    e = tr['omega_r'] - tr['omega_ref']
    real = (hook.plant if isinstance(hook, TrueResistances) else hook.truth.plant).real
    t_amb = real.thermal.T_ambient
    out = {'motor': motor_name, 'run': run, 'trip': res.summary.get('trip'),
           'speed_err_rms_rad_s': float(np.sqrt(np.mean(e ** 2))),
           'E_loss_J': res.summary['E_loss_J'], 'duration_s': sc.duration,
           'dT_stator_K': real.temps[0] - t_amb, 'dT_rotor_K': real.temps[1] - t_amb,
           'wall_s': res.summary['wall_s']}
    if isinstance(hook, TrueResistances):
        R_s, R_R = hook.truth()
        out.update(R_s_end=R_s, R_R_end=R_R, R_s_true_end=R_s, R_R_true_end=R_R)
    else:
        R_s_true, R_R_true = hook.truth.truth()
        est = ({'R_R': model.R_R, 'R_s': model.R_s} if run.startswith('nominal')
               else hook.hook.adapter.estimates())
        out.update(R_s_end=est.get('R_s', model.R_s), R_R_end=est['R_R'],
                   R_s_true_end=R_s_true, R_R_true_end=R_R_true)
    if isinstance(hook, Truth):
        out['series'] = [list(row) for row in hook.series]
    out['R_s_err_end'] = out['R_s_end'] / out['R_s_true_end'] - 1.0
    out['R_R_err_end'] = out['R_R_end'] / out['R_R_true_end'] - 1.0
    return out


def _block(sc: Scenario, run: str, windings) -> dict:
    """Return the plant's thermal block as the drive gets it: off (``_off``) in ``windings``."""
    thermal = dict(sc.plant_blocks()['thermal'])
    if run.endswith('_off'):
        for w in windings:
            thermal.update({f'R_th_{w}': THERMAL_OFF * thermal[f'R_th_{w}'],
                            f'C_{w}': thermal[f'C_{w}'] / THERMAL_OFF})
    return thermal


class _Nominal:
    """No adaptation: the drive keeps the motor file's values."""

    def step(self, T_s, t, v_alpha, v_beta, meas, x_hat) -> dict:
        return {}


def run_thermal(motors=('thesis', 'krause_3hp'), runs=DUTY_RUNS, duration: float = None,
                plots: str = None) -> list:
    """Return every duty run of every motor beside its true-resistance run (same sensing)."""
    rows = []
    for motor in motors:
        base = {}
        for k, run in enumerate(runs, 1):
            print(f'  {motor}: {run} ({k}/{len(runs)})', file=sys.stderr, flush=True)
            r = duty_run(motor, run, duration, progress=True)
            sensing = 'sensorless' if 'sensorless' in run else 'sensored'
            if run.startswith('true_resistances'):
                base[sensing] = r
            b = base[sensing]
            r['speed_err_over_true'] = r['speed_err_rms_rad_s'] / b['speed_err_rms_rad_s']
            r['E_loss_over_true'] = r['E_loss_J'] / b['E_loss_J']
            rows.append(r)
    if plots:
        os.makedirs(plots, exist_ok=True)
        plot_thermal(rows, os.path.join(plots, 'thermal_duty.png'))
    return rows


def drift_schedule(motor=THESIS_MOTOR, duration: float = 2.0) -> ParameterSchedule:
    """R_s ramping to 1.3× over ``duration``, both leakages ±15 % in a 0.5 Hz sine."""
    ls, lr = motor.L_s - motor.L_sr, motor.L_r - motor.L_sr
    return ParameterSchedule(motor, {
        'R_s': ramp(motor.R_s, 0.3 * motor.R_s / duration),
        'L_s': sinusoid(motor.L_s, 0.15 * ls, math.pi),
        'L_r': sinusoid(motor.L_r, 0.15 * lr, math.pi)}, name='R_s ramp + leakage sine')


#: the drift part's runs: the nominal drive, the adapter without and with R_s
DRIFT_RUNS = ('nominal', 'adaptive', 'adaptive_R_s')


def drift_run(run: str, strategy: str = 'min_energy', duration: float = 2.0,
              schedule: ParameterSchedule = None) -> dict:
    """
    Run the R_s-ramp-and-leakage drift (module doc) with one of :data:`DRIFT_RUNS`.

    ``schedule`` replaces the drift (another plant under the same task).
    """
    sched = schedule if schedule is not None else drift_schedule(THESIS_MOTOR, duration)
    sc = Scenario(task='speed', strategy=strategy, schedule=sched, duration=duration,
                  controller='nominal' if run == 'nominal' else 'adaptive')
    hook = None
    if run != 'nominal':
        gains = AdaptationGains(estimate_stator_resistance=run == 'adaptive_R_s')
        hook = LockstepAdapter.build(sc.model_estimates(), gains)
    res = simulate(sc, adapter=hook, record_every=10)
    truth = sched.params_at(duration)
    out = {'run': run, 'strategy': strategy, 'trip': res.summary.get('trip'),
           'speed_err_rms_rad_s': res.summary['speed_err_rms_rad_s'],
           'R_s_true_end': truth.R_s, 'L_M_true_end': truth.L_M}
    if hook is not None:
        est = hook.adapter.estimates()
        out.update(R_s_end=est.get('R_s', THESIS_MOTOR.R_s), L_M_end=est['L_M'],
                   R_R_end=est['R_R'], R_R_true_end=truth.R_R)
        out['L_M_err_end'] = est['L_M'] / truth.L_M - 1.0
    return out


def run_drift() -> list:
    return [drift_run(r) for r in DRIFT_RUNS]


#: the ``stator_error`` part's plant R_s over the model's, minus one
STATOR_ERRORS = (0.0, 0.02, 0.05, 0.1, 0.3)


def run_stator_error(strategies=COMPARED_STRATEGIES, errors=STATOR_ERRORS,
                     duration: float = 2.0) -> list:
    """
    Return the drift part's speed task with the plant's R_s off by a constant, per strategy.

    The nominal drive against the sensored adapter (default gains, R_s the model's): what the
    adapter's rotor estimates owe to R_s (docs/adaptation.md §9).
    """
    rows = []
    for st in strategies:
        for err in errors:
            sched = ParameterSchedule(THESIS_MOTOR,
                                      {'R_s': constant((1.0 + err) * THESIS_MOTOR.R_s)},
                                      name=f'R_s {1.0 + err:g} x')
            row = {'strategy': st, 'R_s_error': err}
            for run in ('nominal', 'adaptive'):
                r = drift_run(run, st, duration, schedule=sched)
                row[f'{run}_speed_err_rms_rad_s'] = r['speed_err_rms_rad_s']
                row[f'{run}_trip'] = r['trip']
            row['R_R_err_end'] = r['R_R_end'] / r['R_R_true_end'] - 1.0
            row['L_M_err_end'] = r['L_M_err_end']
            rows.append(row)
    return rows


#: the chapter-4 targets of make reproduce: position RMS [rad], speed RMS [rad/s]
CH4_TARGETS = {'position': 0.015, 'speed': 0.1}


def run_start(strategies=COMPARED_STRATEGIES) -> list:
    """Return the chapter-4 adaptive rows, the speed task's at every start flux."""
    rows = []
    for task in THESIS_TASKS:
        for st in strategies:
            key = 'pos_err_rms_rad' if task == 'position' else 'speed_err_rms_rad_s'
            fluxes = START_FLUXES if task == 'speed' else (1.0,)
            errs = {f: run_case(task, st, 'adaptive', 'chapter4', gains=gains_for('adaptive'),
                                start_flux=f)[key] for f in fluxes}
            rows.append({'task': task, 'strategy': st, 'errors': errs,
                         'target': CH4_TARGETS[task],
                         'met': all(e <= CH4_TARGETS[task] for e in errs.values())})
    return rows


def plot_thermal(rows: list, path: str) -> None:
    """Plot R̂_s and R̂_R against the plant's through each motor's duty (the adapter's runs)."""
    plt = pyplot()
    motors = sorted({r['motor'] for r in rows})
    fig, axes = plt.subplots(2, len(motors), figsize=(6 * len(motors), 6), squeeze=False)
    for j, motor in enumerate(motors):
        for r in rows:
            if r['motor'] != motor or not r.get('series') or r['run'].startswith('nominal'):
                continue
            s = np.asarray(r['series'])
            for i, (hat, true, name) in enumerate(((1, 2, 'R_s'), (3, 4, 'R_R'))):
                ax = axes[i][j]
                if r['run'] == 'adaptive':
                    ax.plot(s[:, 0], s[:, true], 'k-', lw=2, label='plant')
                ax.plot(s[:, 0], s[:, hat], '--', label=r['run'])
                ax.set_ylabel(f'{name} [Ω]')
                ax.set_title(f'{motor}: {name}')
        axes[1][j].set_xlabel('t [s]')
        axes[0][j].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
