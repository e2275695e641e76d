"""Scenario → node parameters: the one mapping used by the scenario runner, the launch YAML,
the benchmarks and the tests (seed 000 §3.4: motor, tasks, loads, gains).

``node_parameters(...)`` returns ``{node: {parameter: value}}``, the structure of a ROS 2
parameters YAML (``ros__parameters`` added by :func:`to_yaml`).
"""
from __future__ import annotations

import math
from typing import Dict, Optional, Sequence

from im_controller.control_law import MODES as TASKS  # the one home of the task names
from im_controller.flux import STRATEGIES  # the one home of the flux-strategy names

CONTROLLERS = ('nominal', 'adaptive_thesis', 'adaptive', 'adaptive_thesis_pair', 'robust')
# the adaptive controllers: the adapter's law and what the controller and observer take from it
# (im_adapt.adaptation.FEEDS, docs/adaptation.md §7)
ADAPTATION = {'adaptive_thesis': {'law': 'thesis', 'feed': 'thesis_pair'},
              'adaptive': {'law': 'improved', 'feed': 'inverse_gamma'},
              'adaptive_thesis_pair': {'law': 'improved', 'feed': 'thesis_pair'}}
VARIATIONS = ('none', 'chapter4')

# Seed 000 §3.4.4-3.4.5: each task's load, initial shaft state and length.
# The position task starts at rest, demagnetized, pendulum hanging (τ_L = 0). The speed task's
# reference starts at 135 rad/s with 2.49 N·m of load that a demagnetized motor cannot carry, so
# it starts in the controller's own steady state there ('steady', see im_bringup.offline).
TASK_PRESETS = {
    'position': {'load': 'pendulum', 'load_mgl': 10.0, 'theta0': -math.pi / 2, 'omega0': 0.0,
                 'start': 'rest', 'duration': 2.0},
    'speed': {'load': 'linear', 'load_c1': 1.0, 'load_c2': 0.001, 'theta0': 0.0, 'omega0': 135.0,
              'start': 'steady', 'duration': 1.5},
    # beyond the thesis: torque tracking of an effort profile (needs one), from rest, unloaded
    'torque': {'load': 'none', 'theta0': 0.0, 'omega0': 0.0, 'start': 'rest', 'duration': 1.0},
}
TORQUE_NEEDS_PROFILE = ("the torque task needs a profile of effort setpoints "
                        "(--profile FILE with setpoints: [{t: 0.0, effort: ...}, ...])")


def _from_file(value, kind: type, read, what: str):
    """``value`` as given when it is already a ``kind`` (or None), else read from its file path."""
    if value is None or isinstance(value, kind):
        return value
    if isinstance(value, str):
        return read(value)
    raise ValueError(f'invalid {what} {value!r}: a {what} file path or {kind.__name__}')


def motor_parameters(motor) -> Dict[str, object]:
    """The node parameters of a motor (every field ``declare_motor`` declares)."""
    return {k: (int(v) if k == 'pole_pairs' else float(v)) for k, v in motor.as_dict().items()}


CONTROLLER_LIMITS = ('torque_limit', 'current_limit', 'speed_limit', 'field_weakening',
                     'voltage_margin', 'current_margin')
PLANT_PROTECTION = ('inverter_rating', 'current_trip', 'speed_trip')


def node_parameters(task: str = 'position', strategy: str = 'min_energy',
                    controller: str = 'nominal', variation: str = 'none', T_s: float = 1e-4,
                    duration: Optional[float] = None, v_limit: float = 0.0,
                    current_gain: Optional[Sequence[float]] = None,
                    injection_gain: Optional[Sequence[float]] = None,
                    truth_decimation: int = 10, reference_decimation: int = 10,
                    input_timeout: float = 5.0, *, motor=None, estimates=None, profile=None,
                    load=None, limits: Optional[dict] = None,
                    protection: Optional[dict] = None,
                    sensorless: bool = False) -> Dict[str, Dict[str, object]]:
    """Parameters of the four nodes for one scenario (validated names, no ROS import).

    ``motor``: the plant's motor (file path or MotorParams; every node's model defaults to it),
    ``estimates``: a different model for controller, observer and adapter (a mismatch set
    explicitly), ``profile``: setpoints of one's own (file or :class:`Profile`; the task must
    match its kind), ``load``: shaft load (file or Load; plant and the controller's load model),
    ``limits``: controller limits (:data:`CONTROLLER_LIMITS`), ``protection``: plant inverter
    rating and trips (:data:`PLANT_PROTECTION`), ``sensorless``: controller, observer and adapter
    use the observer's speed estimate, not the measured shaft (docs/sensorless.md). Without them
    the thesis scenario is unchanged.
    """
    if task not in TASKS:
        raise ValueError(f"invalid task {task!r}: one of {', '.join(TASKS)}")
    if strategy not in STRATEGIES:
        raise ValueError(f"invalid strategy {strategy!r}: one of {', '.join(STRATEGIES)}")
    if controller not in CONTROLLERS:
        raise ValueError(f"invalid controller {controller!r}: one of {', '.join(CONTROLLERS)}")
    if variation not in VARIATIONS:
        raise ValueError(f"invalid variation {variation!r}: one of {', '.join(VARIATIONS)}")
    from im_common.loads import load_parameters
    from im_common.params import CHAPTER4_ESTIMATES, SCHEDULES, THESIS_MOTOR
    from im_controller.control_law import ControllerConfig, steady_start
    from im_common.loads import Load, load_file
    from im_common.params import MotorParams, load_motor_file
    from im_controller.profiles import Profile, load_profile
    motor = _from_file(motor, MotorParams, load_motor_file, 'motor')
    estimates = _from_file(estimates, MotorParams, load_motor_file, 'estimates')
    profile = _from_file(profile, Profile, load_profile, 'profile')
    load = _from_file(load, Load, load_file, 'load')
    limits = dict(limits or {})
    protection = dict(protection or {})
    for key in limits:
        if key not in CONTROLLER_LIMITS:
            raise ValueError(f"invalid limit {key!r}: one of {', '.join(CONTROLLER_LIMITS)}")
    for key in protection:
        if key not in PLANT_PROTECTION:
            raise ValueError(f"invalid protection {key!r}: one of {', '.join(PLANT_PROTECTION)}")
    if task == 'torque' and profile is None:
        raise ValueError(TORQUE_NEEDS_PROFILE)
    if sensorless and task == 'position':
        from im_observer.speed_observer import POSITION_NEEDS_SENSOR
        raise ValueError(f'invalid option sensorless: {POSITION_NEEDS_SENSOR}')
    if profile is not None and profile.mode != task:
        raise ValueError(f'invalid profile {profile.source}: a {profile.mode} profile for the '
                         f'{task} task')
    preset = dict(TASK_PRESETS[task])
    if load is not None:
        for key in ('load', 'load_mgl', 'load_c1', 'load_c2', 'load_tau'):
            preset.pop(key, None)
        preset.update(load_parameters(load))
    if profile is not None and profile.start_value is not None:
        preset['theta0' if task == 'position' else 'omega0'] = profile.start_value
    if duration is None:
        duration = preset['duration'] if profile is None else profile.end_time + 1.0
    common = {'T_s': float(T_s), 'duration': float(duration), 'input_timeout': float(input_timeout)}
    plant_motor = motor if motor is not None else THESIS_MOTOR
    model = (estimates if estimates is not None
             else CHAPTER4_ESTIMATES if variation == 'chapter4' else plant_motor)
    mine = {}
    if motor is not None:
        mine = motor_parameters(motor)
    model_values = dict(mine)
    if estimates is not None:
        model_values = motor_parameters(estimates)
    elif variation == 'chapter4':
        model_values.update({k: getattr(CHAPTER4_ESTIMATES, k)
                             for k in ('R_s', 'R_r', 'L_s', 'L_r', 'L_sr')})
    plant = dict(common, variation=variation, v_limit=float(v_limit),
                 truth_decimation=int(truth_decimation), **mine,
                 **{k: v for k, v in preset.items() if k not in ('duration', 'start')})
    plant.update({k: float(v) for k, v in protection.items()})
    load_keys = [k for k in ('load_mgl', 'load_c1', 'load_c2', 'load_tau') if k in preset]
    ctl_load = {'load': preset['load'], **{k: preset[k] for k in load_keys}}
    cfg = ControllerConfig(mode=task, strategy=strategy, params=model, v_limit=v_limit or None,
                           T_s=T_s, **ctl_load,
                           **({} if profile is None else {'profile': 'setpoint',
                                                            'setpoints': profile.setpoints}),
                           **{k: v for k, v in limits.items()})
    x0 = obs_x0 = None
    if preset['start'] == 'steady':
        x0, obs_x0 = steady_start(cfg, SCHEDULES[variation](plant_motor).params_at(0.0),
                                  preset['theta0'], preset['omega0'])
    adaptive = controller in ADAPTATION
    ctl = dict(common, mode=task, strategy=strategy, use_adapter=adaptive,
               v_limit=float(v_limit), reference_decimation=int(reference_decimation),
               load_known=True, **ctl_load, **model_values)
    if profile is not None:
        ctl.update(profile.as_parameters())
    ctl.update({k: (v if isinstance(v, bool) else float(v)) for k, v in limits.items()})
    if current_gain is not None:
        ctl['current_gain'] = [float(g) for g in current_gain]
        ctl['gain_period'] = float(T_s)
    if x0 is not None:          # plant and observer start in the controller's steady state
        plant['initial_current'] = [float(obs_x0[0]), float(obs_x0[1])]
        plant['initial_flux'] = [float(x0[2]), float(x0[3])]
    obs = dict(common, use_adapter=adaptive, **model_values)
    if x0 is not None:
        obs['initial_state'] = [float(v) for v in obs_x0]
    if injection_gain is not None:
        obs['injection_gain'] = [float(g) for g in injection_gain]
        obs['gain_period'] = float(T_s)
    adapter = dict(common, enable=adaptive, **model_values)
    if sensorless:      # controller, observer, adapter: the observer's ω̂ replaces the shaft
        ctl['sensorless'] = obs['sensorless'] = adapter['sensorless'] = True
        obs['initial_speed'] = float(preset['omega0']) if preset['start'] == 'steady' else 0.0
    if adaptive:
        adapter.update(ADAPTATION[controller])
    return {'plant': plant, 'controller': ctl, 'observer': obs, 'adapter': adapter}


def to_yaml(parameters: Dict[str, Dict[str, object]], use_sim_time: bool = True) -> str:
    """A ROS 2 parameters file (``--params-file``) for the given node parameters."""
    from im_common.yamlio import parameters_yaml
    doc = {}
    for node, values in parameters.items():
        vals = dict(values)
        if use_sim_time and node != 'plant':
            vals['use_sim_time'] = True
        doc[node] = vals
    return parameters_yaml(doc)
