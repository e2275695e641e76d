"""Offline closed loop: plant + controller + observer stepped in pure Python, in exactly the order
the lock-step ROS graph uses (docs/architecture.md, "Lock-step protocol, startup and shutdown"):

    meas_k = plant.measure()                                  # plant publishes stamped t_k
    V_k    = controller.compute(t_k, meas_k, φ̂_k, p̂_k)        # controller holds all inputs of step k
    plant.step(V_k)                                           # plant integrates [t_k, t_k+1], V held
    x̂_k+1  = observer.step(T_s, V_k, meas_k.i, meas_k.ω)      # observer predicts from the same data
    p̂_k+1  = adapter.step(..., x̂_k)  (optional hook, chapter 4; used from step k+1 on)

So results of the ROS graph and of this loop are comparable sample by sample.

Scenarios (seed 000 §3.4): the position task starts at rest, θ₀ = −π/2, demagnetized (pendulum
hanging, τ_L = 0). The speed task's reference starts at 135 rad/s with a load of 2.49 N·m, which a
demagnetized motor cannot carry; the thesis implies a drive already running, so the speed task
starts in the controller's own steady state at 135 rad/s (flux at the strategy's level, field
angle 0) — plant and observer both start there (``start='steady'``).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from typing import Optional

import numpy as np

from im_common.cli import status_line
from im_common.loads import Load, load_parameters, make_load
from im_common.metrics import energy_figures, tracking_figures
from im_common.model import E_CORE, E_CU_R, E_CU_S, E_IN
from im_common.params import (CHAPTER4_ESTIMATES, InvalidParameter, MotorParams,
                              ParameterSchedule, SCHEDULES, THESIS_MOTOR, estimate_arguments)
from im_common.plant_sim import PlantSimulator
from im_controller.control_law import ControllerConfig, DriveController, steady_start
from im_controller.profiles import Profile
from im_observer.observer import RotorFluxObserver
from im_observer.speed_observer import POSITION_NEEDS_SENSOR, SpeedAdaptiveObserver

from .config import CONTROLLERS, TASK_PRESETS, TASKS, TORQUE_NEEDS_PROFILE  # the one table of tasks

START_MODES = ('rest', 'steady')
DEFAULT_DURATION = {task: p['duration'] for task, p in TASK_PRESETS.items()}


@dataclass
class Scenario:
    """One closed-loop run. Units SI; None picks the task default (see module docstring)."""

    task: str = 'position'
    strategy: str = 'min_energy'
    T_s: float = 1e-4
    duration: Optional[float] = None
    variation: str = 'none'
    controller: str = 'nominal'
    v_limit: Optional[float] = None
    current_gain: Optional[list] = None
    observer_gain: Optional[list] = None
    k_e: Optional[float] = None
    current_noise_std: float = 0.0
    speed_noise_std: float = 0.0
    noise_seed: int = 0
    start: Optional[str] = None
    theta0: Optional[float] = None
    omega0: Optional[float] = None
    core_loss_exponent: float = 2.0
    plant_substep: float = 1e-4
    observer_substep: float = 1e-4
    controller_options: dict = field(default_factory=dict)
    schedule: Optional[ParameterSchedule] = None   # overrides the named ``variation``
    motor: Optional[MotorParams] = None       # the plant's motor (None: the thesis motor)
    estimates: Optional[MotorParams] = None   # the controller/observer model (None: = motor)
    profile: Optional[Profile] = None         # setpoints of one's own (None: thesis profile)
    load_model: Optional[Load] = None         # shaft load (None: the task's thesis load)
    inverter_rating: Optional[float] = None   # plant's inverter limit [V] (None: plant default)
    sensorless: bool = False                  # controller/observer use no measured speed/position
    speed_observer_options: dict = field(default_factory=dict)  # SpeedAdaptiveObserver keywords

    def __post_init__(self):
        if self.task not in TASKS:
            raise InvalidParameter('task', self.task, f'must be one of {", ".join(TASKS)}')
        if self.controller not in CONTROLLERS:
            raise InvalidParameter('controller', self.controller,
                                   f'must be one of {", ".join(CONTROLLERS)} (a label; adaptive '
                                   f'runs pass an adapter to simulate)')
        if self.schedule is None and self.variation not in SCHEDULES:
            raise InvalidParameter('variation', self.variation, f'must be one of {", ".join(SCHEDULES)}')
        if not (math.isfinite(self.T_s) and self.T_s > 0):
            raise InvalidParameter('T_s', self.T_s, 'must be a positive period in seconds')
        if self.sensorless and self.task == 'position':
            raise InvalidParameter('sensorless', True, POSITION_NEEDS_SENSOR)
        if self.task == 'torque' and self.profile is None:
            raise InvalidParameter('profile', None, TORQUE_NEEDS_PROFILE)
        if self.profile is not None and self.profile.mode != self.task:
            raise InvalidParameter('profile', self.profile.source,
                                   f'is a {self.profile.mode} profile; the task is {self.task}')
        if self.duration is None:
            self.duration = (DEFAULT_DURATION[self.task] if self.profile is None
                             else self.profile.end_time + 1.0)
        if not (math.isfinite(self.duration) and self.duration > 0):
            raise InvalidParameter('duration', self.duration, 'must be > 0 s')
        preset = TASK_PRESETS[self.task]
        if self.start is None:
            self.start = preset['start']
        if self.start not in START_MODES:
            raise InvalidParameter('start', self.start, f'must be one of {", ".join(START_MODES)}')
        start_value = self.profile.start_value if self.profile is not None else None
        if self.theta0 is None:
            self.theta0 = (start_value if self.task == 'position' and start_value is not None
                           else preset['theta0'])
        if self.omega0 is None:
            self.omega0 = (start_value if self.task == 'speed' and start_value is not None
                           else preset['omega0'])

    def plant_motor(self) -> MotorParams:
        return self.motor if self.motor is not None else THESIS_MOTOR

    def plant_schedule(self) -> ParameterSchedule:
        if self.schedule is not None:
            return self.schedule
        return SCHEDULES[self.variation](self.plant_motor())

    def model_estimates(self) -> MotorParams:
        """The controller's and observer's motor model: explicit ``estimates``, else the
        chapter-4 estimates under that variation, else the plant's own motor."""
        if self.estimates is not None:
            return self.estimates
        if self.variation == 'chapter4':
            return CHAPTER4_ESTIMATES
        return self.plant_motor()

    def plant_load(self) -> Load:
        if self.load_model is not None:
            return self.load_model
        p = TASK_PRESETS[self.task]
        return make_load(p['load'], mgl=p.get('load_mgl', 10.0), c1=p.get('load_c1', 1.0),
                         c2=p.get('load_c2', 0.001))

    def initial_state(self):
        """(plant x0 or None, observer x̂_0): at rest demagnetized, or ('steady') in the
        controller's own steady state at (θ0, ω0) — plant and observer both start there."""
        if self.start != 'steady':
            return None, (0.0, 0.0, 0.0, 0.0)
        return steady_start(self.controller_config(), self.plant_schedule().params_at(0.0),
                            self.theta0, self.omega0)

    def controller_config(self) -> ControllerConfig:
        opts = dict(self.controller_options)
        opts.setdefault('core_loss_exponent', self.core_loss_exponent)
        opts.setdefault('horizon', self.duration)   # the run's end: the optimal strategy's plan
        if self.profile is not None:
            opts.setdefault('profile', 'setpoint')
            opts.setdefault('setpoints', self.profile.setpoints)
        lp = load_parameters(self.plant_load())
        for key, value in lp.items():
            opts.setdefault(key, value)
        return ControllerConfig(mode=self.task, strategy=self.strategy,
                                params=self.model_estimates(), v_limit=self.v_limit,
                                current_gain=self.current_gain, T_s=self.T_s, **opts)


#: controller / observer node parameters a gains file may set, and their Scenario counterparts
GAIN_PARAMETERS = {'controller': ('current_gain', 'gain_period', 'flux_coupling'),
                   'observer': ('injection_gain', 'gain_period', 'k_e_injection')}


def gain_arguments_from_parameters(params: dict) -> dict:
    """Scenario keyword arguments of node-parameter gain overrides (``design_gains --out``,
    :func:`im_controller.design_gains.design_for_scenario`): {'controller': {...}, 'observer':
    {...}} -> current_gain (2×2), observer_gain (4×2), k_e, controller_options. Empty -> the
    thesis's gains. Any other parameter is refused by name (the offline loop would ignore it)."""
    kw: dict = {}
    for node, values in (params or {}).items():
        allowed = GAIN_PARAMETERS.get(node)
        if allowed is None:
            raise InvalidParameter('gains', node, 'only controller and observer gains apply')
        for key in values:
            if key not in allowed:
                raise InvalidParameter(f'{node}.{key}', values[key],
                                       f'not a gain parameter (one of {", ".join(allowed)})')
    c, o = (params or {}).get('controller', {}), (params or {}).get('observer', {})
    if c.get('current_gain') is not None:
        kw['current_gain'] = np.asarray(c['current_gain'], float).reshape(2, 2).tolist()
    if c.get('flux_coupling') is not None:
        kw['controller_options'] = {'flux_coupling': c['flux_coupling']}
    if o.get('injection_gain') is not None:
        kw['observer_gain'] = np.asarray(o['injection_gain'], float).reshape(4, 2).tolist()
    if o.get('k_e_injection'):
        kw['k_e'] = float(o['k_e_injection'])
    return kw


@dataclass
class RunResult:
    scenario: Scenario
    summary: dict
    trace: dict


TRACE_KEYS = ('t', 'theta_r', 'omega_r', 'theta_ref', 'omega_ref', 'tau_m', 'tau_ref', 'tau_L',
              'v_alpha', 'v_beta', 'i_alpha', 'i_beta', 'i_alpha_ref', 'i_beta_ref',
              'phi_r_alpha', 'phi_r_beta', 'phi_ref_alpha', 'phi_ref_beta', 'phi_hat_alpha',
              'phi_hat_beta', 'phi_d_ref', 'phi_target', 'omega_sl', 'E_in', 'E_loss', 'E_copper',
              'E_core', 'omega_hat')


def build(sc: Scenario):
    """(plant, controller, observer) of a scenario, started as the scenario says."""
    cfg = sc.controller_config()
    x0, obs_x0 = sc.initial_state()
    plant = PlantSimulator(sc.plant_schedule(), sc.plant_load(), T_s=sc.T_s,
                           max_substep=sc.plant_substep, v_limit=sc.v_limit,
                           current_noise_std=sc.current_noise_std,
                           speed_noise_std=sc.speed_noise_std, noise_seed=sc.noise_seed,
                           theta0=sc.theta0, omega0=sc.omega0, x0=x0,
                           core_loss_exponent=sc.core_loss_exponent,
                           **({} if sc.inverter_rating is None
                              else {'inverter_rating': sc.inverter_rating}))
    controller = DriveController(cfg)
    if sc.sensorless:
        # the drive's speed estimate starts where the drive is: at rest, or (a drive already
        # running, 'steady') at the speed its controller holds
        observer = SpeedAdaptiveObserver(cfg.params, k_e=sc.k_e, max_substep=sc.observer_substep,
                                         x0=obs_x0, omega0=sc.omega0 if sc.start == 'steady'
                                         else 0.0, injection_gain=sc.observer_gain,
                                         gain_period=sc.T_s if sc.observer_gain is not None
                                         else None, **sc.speed_observer_options)
        return plant, controller, observer
    observer = RotorFluxObserver(cfg.params, k_e=sc.k_e, max_substep=sc.observer_substep, x0=obs_x0,
                                 injection_gain=sc.observer_gain,
                                 gain_period=sc.T_s if sc.observer_gain is not None else None)
    return plant, controller, observer


def _record(tr: dict, rec: int, plant, controller, x_hat, t: float, v_a: float, v_b: float) -> None:
    """One row of the traces at t_k (true state, references, applied voltage, energy books)."""
    x = plant.x
    _, _, L_s, L_r, L_sr = plant.schedule.values(t)
    i_sa, i_sb, _, _ = plant.state_currents()
    ref = controller.reference
    applied = plant.limit(v_a, v_b)
    vp = plant.params.pole_pairs
    row = tr
    row['t'][rec] = t
    row['theta_r'][rec] = x[4]
    row['omega_r'][rec] = x[5]
    row['theta_ref'][rec] = ref['theta_ref']
    row['omega_ref'][rec] = ref['omega_ref']
    row['tau_m'][rec] = vp * L_sr / L_r * (i_sb * x[2] - i_sa * x[3])
    row['tau_ref'][rec] = ref['tau_ref']
    row['tau_L'][rec] = plant.load.torque(t, x[4], x[5])
    row['v_alpha'][rec] = applied[0]
    row['v_beta'][rec] = applied[1]
    row['i_alpha'][rec] = i_sa
    row['i_beta'][rec] = i_sb
    row['i_alpha_ref'][rec] = ref['i_alpha_ref']
    row['i_beta_ref'][rec] = ref['i_beta_ref']
    row['phi_r_alpha'][rec] = x[2]
    row['phi_r_beta'][rec] = x[3]
    row['phi_ref_alpha'][rec] = ref['phi_alpha_ref']
    row['phi_ref_beta'][rec] = ref['phi_beta_ref']
    row['phi_hat_alpha'][rec] = x_hat[2]
    row['phi_hat_beta'][rec] = x_hat[3]
    row['phi_d_ref'][rec] = ref['phi_d_ref']
    row['phi_target'][rec] = ref['phi_target']
    row['omega_sl'][rec] = ref['omega_sl']
    row['E_in'][rec] = x[E_IN]
    row['E_copper'][rec] = x[E_CU_S] + x[E_CU_R]
    row['E_core'][rec] = x[E_CORE]
    row['E_loss'][rec] = x[E_CU_S] + x[E_CU_R] + x[E_CORE]


def _summary(sc: Scenario, plant, trace: dict, n_steps: int) -> dict:
    truth = plant.truth()
    summary = {'task': sc.task, 'strategy': sc.strategy, 'controller': sc.controller,
               'variation': sc.variation, 'rate_hz': 1.0 / sc.T_s, 'T_s': sc.T_s,
               'duration_s': sc.duration, 'core_loss_exponent': sc.core_loss_exponent}
    summary.update(energy_figures(truth))
    summary.update(tracking_figures(trace, sc.task))
    summary['E_loss_J'] = summary['E_copper_J'] + summary['E_core_J']
    summary['balance_relative'] = abs(summary['balance_residual_J']) / max(abs(summary['E_in_J']), 1e-12)
    summary['steps'] = n_steps
    summary['trip'] = None if plant.trip is None else {'t': plant.trip[0], 'reason': plant.trip[1]}
    return summary


def simulate(scenario: Scenario, progress: bool = False, record_every: int = 1,
             adapter=None, timing: bool = False) -> RunResult:
    """Run ``scenario`` in the lock-step order; returns figures of merit and traces.

    ``adapter`` (optional, chapter 4): an object with ``step(T_s, t, v_alpha, v_beta, meas,
    x_hat) -> dict`` returning estimates (e.g. {'R_r': ..., 'theta': ...}) for the next step;
    they are passed to the controller (eq. 4.10-4.12) and the observer (eq. 4.13).
    ``timing`` adds the mean wall time per ``compute`` and per ``observer.step`` [µs] to the summary.
    """
    sc = scenario
    if record_every < 1:
        raise InvalidParameter('record_every', record_every, 'must be >= 1')
    wall0 = time.perf_counter()
    plant, controller, observer = build(sc)
    n_steps = int(round(sc.duration / sc.T_s))
    n_rec = n_steps // record_every + 1
    tr = {k: np.empty(n_rec) for k in TRACE_KEYS}
    T_s = sc.T_s
    estimates = None
    x_hat = observer.state
    rec = 0
    report_every = max(1, n_steps // 20)
    label = f'{sc.task}/{sc.strategy} T_s={sc.T_s:g}'
    clock = time.perf_counter
    t_ctl = t_obs = 0.0
    for k in range(n_steps + 1):
        m = plant.measure()
        if sc.sensorless:   # the shaft is not measured: the observer's ω̂ and θ̂ = ∫ω̂ instead
            m = replace(m, theta_r=observer.theta_hat, omega_r=observer.omega_hat)
        if timing:
            c0 = clock()
        v_a, v_b = controller.compute(m.t, m.i_alpha, m.i_beta, m.theta_r, m.omega_r,
                                      x_hat[2], x_hat[3], estimates)
        if timing:
            t_ctl += clock() - c0
        if k % record_every == 0 and rec < n_rec:
            _record(tr, rec, plant, controller, x_hat, m.t, v_a, v_b)
            tr['omega_hat'][rec] = m.omega_r     # the speed the controller used
            rec += 1
        if k == n_steps:
            break
        plant.step(v_a, v_b)
        if timing:
            c0 = clock()
        x_hat_k = x_hat
        if sc.sensorless:
            x_hat = observer.step(T_s, v_a, v_b, m.i_alpha, m.i_beta)   # ω̂ from V and i only
        else:
            x_hat = observer.step(T_s, v_a, v_b, m.i_alpha, m.i_beta, m.omega_r)   # uses p̂_k
        if timing:
            t_obs += clock() - c0
        if adapter is not None:
            # the adapter node's step k: V_k, i_k, ω_k and the observer's x̂_k in, p̂_k+1 out
            estimates = adapter.step(T_s, m.t, v_a, v_b, m, x_hat_k)
            if estimates:
                observer.set_estimates(**estimate_arguments(estimates))
        if progress and k % report_every == 0:
            status_line(f'{label}: {100.0 * k / n_steps:5.1f} %')
    if progress:
        status_line(f'{label}: done in {time.perf_counter() - wall0:.1f} s', done=True)
    trace = {k: v[:rec] for k, v in tr.items()}
    summary = _summary(sc, plant, trace, n_steps)
    if timing:
        summary['us_per_compute'] = 1e6 * t_ctl / (n_steps + 1)
        summary['us_per_observer_step'] = 1e6 * t_obs / max(n_steps, 1)
    summary['wall_s'] = time.perf_counter() - wall0
    return RunResult(sc, summary, trace)
