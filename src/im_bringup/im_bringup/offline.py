"""
Offline closed loop: plant + controller + observer stepped in pure Python.

They step in exactly the order the lock-step ROS graph uses (docs/architecture.md, "Lock-step
protocol, startup and shutdown"):

    meas_k = plant.measure()                             # plant publishes stamped t_k
    V_k    = controller.compute(t_k, meas_k, φ̂_k, p̂_k)   # controller holds all inputs of step k
    plant.step(V_k)                                      # plant integrates [t_k, t_k+1], V held
    x̂_k+1  = observer.step(T_s, V_k, meas_k.i, meas_k.ω) # observer predicts from the same data
    p̂_k+1  = adapter.step(..., x̂_k)  (optional hook, chapter 4; used from step k+1 on)

With the run's computational delay d (``inverter: {delay: d}``, im_common.delay) the plant applies
V_{k−d} over step k, and the observer, the adapter and the traces take that voltage too: the
drive's own line of commands, the one its nodes hold.

So results of the ROS graph and of this loop are comparable sample by sample.

Scenarios (seed 000 §3.4): the position task starts at rest, θ₀ = −π/2, demagnetized (pendulum
hanging, τ_L = 0). The speed task's reference starts at 135 rad/s with a load of 2.49 N·m, which a
demagnetized motor cannot carry; the thesis implies a drive already running, so the speed task
starts in the controller's own steady state at 135 rad/s (flux at the strategy's level, field
angle 0) — plant and observer both start there (``start='steady'``).
"""
from __future__ import annotations

from dataclasses import dataclass, replace
import time

from im_common.cli import status_line
from im_common.delay import CommandDelay
from im_common.metrics import energy_figures, load_step_figures, tracking_figures
from im_common.model import E_CORE, E_CU_R, E_CU_S, E_IN
from im_common.params import (CHAPTER4_ESTIMATES, estimate_arguments,  # noqa: F401 (re-exported)
                              InvalidParameter, SCHEDULES, THESIS_MOTOR)
from im_controller.control_law import DriveController
from im_observer.observer import RotorFluxObserver
from im_observer.speed_observer import SpeedAdaptiveObserver
from im_plant.plant_sim import PlantSimulator
import numpy as np

from .config import ADAPTATION, CONTROLLERS, TASK_PRESETS, TASKS  # noqa: F401 (re-exported)
from .run_file import (DEFAULT_DURATION, gain_arguments_from_parameters,  # noqa: F401
                       GAIN_PARAMETERS, limit_value, Scenario, START_MODES)


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
    """Return (plant, controller, observer) of a scenario, started as the scenario says."""
    cfg = sc.controller_config()
    gains = sc.gain_arguments()
    x0, obs_x0 = sc.initial_state()
    plant = PlantSimulator(sc.plant_schedule(), sc.plant_load(), T_s=sc.T_s,
                           max_substep=sc.plant_substep, v_limit=limit_value(sc.v_limit),
                           current_noise_std=sc.current_noise_std,
                           speed_noise_std=sc.speed_noise_std, noise_seed=sc.noise_seed,
                           theta0=sc.theta0, omega0=sc.omega0, x0=x0,
                           core_loss_exponent=sc.core_loss_exponent,
                           current_trip=limit_value(sc.current_trip),
                           speed_trip=limit_value(sc.speed_trip),
                           **({} if sc.inverter_rating is None
                              else {'inverter_rating': sc.inverter_rating}),
                           **sc.plant_blocks())
    controller = DriveController(cfg)
    if sc.sensorless:
        # the drive's speed estimate starts where the drive is: at rest, or (a drive already
        # running, 'steady') at the speed its controller holds
        observer = SpeedAdaptiveObserver(cfg.params, k_e=gains['k_e'],
                                         max_substep=sc.observer_substep,
                                         x0=obs_x0, omega0=sc.omega0 if sc.start == 'steady'
                                         else 0.0, injection_gain=gains['observer_gain'],
                                         gain_period=sc.T_s if gains['observer_gain'] is not None
                                         else None, inverter_error=cfg.compensation,
                                         **sc.speed_observer_options)
        return plant, controller, observer
    observer = RotorFluxObserver(cfg.params, k_e=gains['k_e'], max_substep=sc.observer_substep,
                                 x0=obs_x0, injection_gain=gains['observer_gain'],
                                 gain_period=(sc.T_s if gains['observer_gain'] is not None
                                              else None), inverter_error=cfg.compensation)
    return plant, controller, observer


def _record(tr: dict, rec: int, plant, controller, x_hat, t: float, v_a: float,
            v_b: float) -> None:
    """Record one row of the traces at t_k (true state, references, applied voltage, energy)."""
    x = plant.x
    _, _, L_s, L_r, L_sr = plant.schedule.values(t)
    i_sa, i_sb = plant.stator_currents()
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
               'variation': sc.variation_label, 'rate_hz': 1.0 / sc.T_s, 'T_s': sc.T_s,
               'duration_s': sc.duration, 'core_loss_exponent': sc.core_loss_exponent}
    summary.update(energy_figures(truth))
    summary.update(tracking_figures(trace, sc.task))
    t_step = sc.plant_load().change_time()
    if t_step is not None and sc.task == 'speed':     # a load step: the speed's figures
        summary['load_step_t'] = t_step
        summary.update(load_step_figures(trace, t_step))
    summary['E_loss_J'] = summary['E_copper_J'] + summary['E_core_J']
    summary['balance_relative'] = (abs(summary['balance_residual_J'])
                                   / max(abs(summary['E_in_J']), 1e-12))
    summary['steps'] = n_steps
    summary['trip'] = None if plant.trip is None else {'t': plant.trip[0], 'reason': plant.trip[1]}
    return summary


def simulate(scenario: Scenario, progress: bool = False, record_every: int = 1,
             adapter=None, timing: bool = False, truth_at=()) -> RunResult:
    """
    Run ``scenario`` in the lock-step order; return figures of merit and traces.

    ``adapter`` (chapter 4): an object with ``step(T_s, t, v_alpha, v_beta, meas,
    x_hat) -> dict`` returning estimates (e.g. {'R_r': ..., 'theta': ...}) for the next step;
    they are passed to the controller (eq. 4.10-4.12) and the observer (eq. 4.13). None with an
    adaptive ``controller`` (``adaptive``, ``adaptive_thesis``, ...): the adapter the run file
    describes, as the graph's adapter node builds it from the same node parameters
    (:meth:`im_adapt.hook.LockstepAdapter.from_node_parameters`). An adapter
    that is a bound (the truth handed to the drive, not a controller) has ``bind(plant)``, called
    once with the plant before the first step.
    ``timing`` adds the mean wall time per ``compute`` and per ``observer.step`` [µs] to the
    summary. ``truth_at`` (times [s]): the plant's whole truth at the step nearest each, in the
    summary's ``truth_at`` (a list in that order): the energy books over a window.
    """
    sc = scenario
    if record_every < 1:
        raise InvalidParameter('record_every', record_every, 'must be >= 1')
    wall0 = time.perf_counter()
    plant, controller, observer = build(sc)
    adapter = _run_adapter(sc, plant, controller, adapter)
    cfg_comp = controller.config.compensation
    line = CommandDelay(plant.delay.d)      # the drive's copy of the plant's delay line
    n_steps = int(round(sc.duration / sc.T_s))
    n_rec = n_steps // record_every + 1
    tr = {k: np.empty(n_rec) for k in TRACE_KEYS}
    T_s = sc.T_s
    saturated = sc.saturated_model()      # the drive on the magnetizing curve (None: linear)
    x_hat = observer.state
    estimates = _initial_estimates(saturated, observer, x_hat)
    rec = 0
    report_every = max(1, n_steps // 20)
    label = f'{sc.task}/{sc.strategy} T_s={sc.T_s:g}'
    clock = time.perf_counter
    t_ctl = t_obs = 0.0
    snap_steps = [min(max(int(round(t / T_s)), 0), n_steps) for t in truth_at]
    snaps = {}
    for k in range(n_steps + 1):
        if k in snap_steps and k not in snaps:
            snaps[k] = plant.truth()
        m = plant.measure()
        if sc.sensorless:   # the shaft is not measured: the observer's ω̂ and θ̂ = ∫ω̂ instead
            m = replace(m, theta_r=observer.theta_hat, omega_r=observer.omega_hat)
        if timing:
            c0 = clock()
        v_a, v_b = controller.compute(m.t, m.i_alpha, m.i_beta, m.theta_r, m.omega_r,
                                      x_hat[2], x_hat[3], estimates)
        if timing:
            t_ctl += clock() - c0
        v_act = line.push(v_a, v_b) if line.d else (v_a, v_b)    # what acts over step k
        if k % record_every == 0 and rec < n_rec:
            _record(tr, rec, plant, controller, x_hat, m.t, *v_act)
            tr['omega_hat'][rec] = m.omega_r     # the speed the controller used
            rec += 1
        if k == n_steps:
            break
        plant.step(v_a, v_b)
        if timing:
            c0 = clock()
        x_hat_k = x_hat
        if sc.sensorless:
            x_hat = observer.step(T_s, *v_act, m.i_alpha, m.i_beta)   # ω̂ from V and i only
        else:
            x_hat = observer.step(T_s, *v_act, m.i_alpha, m.i_beta, m.omega_r)   # uses p̂_k
        if timing:
            t_obs += clock() - c0
        if saturated is not None:   # the next step's models at the flux the observer now has
            estimates = saturated.estimates(x_hat[2], x_hat[3])
            observer.set_estimates(**estimates)
        if adapter is not None:
            estimates = _adapter_step(adapter, cfg_comp, observer, T_s, m, v_act, x_hat_k)
        if progress and k % report_every == 0:
            status_line(f'{label}: {100.0 * k / n_steps:5.1f} %')
    if progress:
        status_line(f'{label}: done in {time.perf_counter() - wall0:.1f} s', done=True)
    return _result(sc, plant, {k: v[:rec] for k, v in tr.items()}, n_steps,
                   [snaps[k] for k in snap_steps] if snap_steps else None,
                   (t_ctl, t_obs) if timing else None, wall0)


def _run_adapter(sc: Scenario, plant, controller, adapter):
    """Return the run's adapter (``adapter``, else the run file's own), bound to ``plant``."""
    if adapter is None and sc.controller in ADAPTATION:    # the run's own adapter, not none
        from im_adapt.hook import LockstepAdapter      # im_adapt only where a run adapts
        adapter = LockstepAdapter.from_node_parameters(
            controller.config.params, sc.node_parameters()['adapter'], record_every=0)
    if adapter is not None and hasattr(adapter, 'bind'):
        adapter.bind(plant)     # a bound, not a controller, may read the plant's truth
    return adapter


def _initial_estimates(saturated, observer, x_hat):
    """Return the curve's models at the initial flux, set in ``observer`` (None: linear)."""
    if saturated is None:
        return None
    estimates = saturated.estimates(x_hat[2], x_hat[3])   # from the start: the initial flux
    observer.set_estimates(**estimates)
    return estimates


def _adapter_step(adapter, cfg_comp, observer, T_s: float, m, v_act, x_hat_k):
    """Return the adapter node's step k: V_k, i_k, ω_k and the observer's x̂_k in, p̂_k+1 out."""
    # with compensation, the voltage the motor got (the adapter node's too)
    v_m = v_act if cfg_comp is None else \
        cfg_comp.motor_voltage(*v_act, m.i_alpha, m.i_beta)
    estimates = adapter.step(T_s, m.t, v_m[0], v_m[1], m, x_hat_k)
    if estimates:
        observer.set_estimates(**estimate_arguments(estimates))
    return estimates


def _result(sc: Scenario, plant, trace: dict, n_steps: int, truth_at, times,
            wall0: float) -> RunResult:
    """Return the run's result: ``truth_at`` and the loop's ``times`` (None: none), wall time."""
    summary = _summary(sc, plant, trace, n_steps)
    if truth_at is not None:
        summary['truth_at'] = truth_at
    if times is not None:
        summary['us_per_compute'] = 1e6 * times[0] / (n_steps + 1)
        summary['us_per_observer_step'] = 1e6 * times[1] / max(n_steps, 1)
    summary['wall_s'] = time.perf_counter() - wall0
    return RunResult(sc, summary, trace)
