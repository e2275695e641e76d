"""
The run file: one frozen, validated :class:`Scenario` describes a whole run (ROS-free).

Every way of running takes it — ``ros2 run im_bringup scenario RUN.yaml [--set key=value]``
(in one process or ``--processes``), ``ros2 launch im_bringup drive.launch.py run:=RUN.yaml``,
the test fixture (:mod:`im_bringup.testing`), the ROS-free loop (:func:`im_bringup.offline.
simulate`) and Python. Its keys are the ``scenario`` options' long names with underscores plus
``variation`` (breakpoints of any electrical motor parameter) and ``noise`` (docs/running.md)::

    task: position
    controller: adaptive
    variation:
      R_r:  [{t: 0.5, scale: 2.0, shape: step}]
      L_sr: [{t: 0.0, scale: 1.0}, {t: 2.0, scale: 0.8, shape: ramp}]
    noise: {current: 0.05, speed: 0.05, seed: 1}

:meth:`Scenario.from_file` / :meth:`Scenario.from_mapping` read it (an error is one line naming
the file and the key, e.g. ``run.yaml: variation.R_r[0].shape: must be step or ramp``),
:meth:`Scenario.to_mapping` / :meth:`Scenario.to_yaml` write it back fully resolved (motor, load,
profile, gains inline: what every bag carries as its ``run`` record), and
:meth:`Scenario.node_parameters` gives the four nodes' ROS parameters.
"""
from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
import difflib
import json
import math
import os
from typing import Dict, Mapping, Optional

from im_common.compensation import compensation_from_dict
from im_common.inverter import check_against_motor, Inverter
from im_common.loads import Load, load_file, load_from_dict, load_parameters, make_load
from im_common.node_params import block_parameters
from im_common.params import (CHAPTER4_ESTIMATES, describe_variation, INDUCTANCE_NAMES,
                              InvalidParameter, is_motor_name, load_motor_blocks, load_motor_file,
                              MOTOR_BLOCKS, motor_blocks, motor_from_dict, MotorParams,
                              normalize_variation, ParameterSchedule, RATED, SCHEDULES,
                              shipped_motor, THESIS_MOTOR, variation_schedule,
                              warn_motor_defaults)
from im_common.saturation import SaturatedModel, saturation_from_dict
from im_common.thermal import thermal_from_dict
from im_common.validation import check_choice, one_line
from im_common.yamlio import load_parameters_file, read_yaml_file
from im_controller.baselines.drive import check_law_task, gains_model, LAWS
from im_controller.control_law import ControllerConfig, MODES, steady_start, THESIS_LAW_GAINS
from im_controller.flux import LOSS_SCOPES
from im_controller.profiles import from_setpoints, KINDS, load_profile, MODE_KIND, Profile
from im_controller.trajectories import THESIS_TRAJECTORIES
from im_observer.speed_observer import POSITION_NEEDS_SENSOR
from im_plant.parameters import STEPPING_MODES   # the plant's stepping modes (one home)
from im_plant.sensors import Sensors
import numpy as np
import yaml

TASKS = MODES                                      # the task names' one home: the control law
#: the controllers: the thesis law at nominal estimates, adapted or with certified gains, or a
#: drive industry's baseline law in its place (im_controller.baselines, docs/baselines.md)
CONTROLLERS = ('nominal', 'adaptive_thesis', 'adaptive', 'adaptive_thesis_pair', 'robust',
               'current_vector', 'flux_vector', 'vhz')
# the adaptive controllers: the adapter's law and what the controller and observer take from it
# (im_adapt.adaptation.FEEDS, docs/adaptation.md §7)
ADAPTATION = {'adaptive_thesis': {'law': 'thesis', 'feed': 'thesis_pair'},
              'adaptive': {'law': 'improved', 'feed': 'inverse_gamma'},
              'adaptive_thesis_pair': {'law': 'improved', 'feed': 'thesis_pair'}}

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


def task_load(task: str) -> Load:
    """Return a task's shaft load in the thesis (:data:`TASK_PRESETS`), the run's default."""
    p = TASK_PRESETS[task]
    return make_load(p['load'], mgl=p.get('load_mgl', 10.0), c1=p.get('load_c1', 1.0),
                     c2=p.get('load_c2', 0.001))


TORQUE_NEEDS_PROFILE = ('the torque task needs a profile of effort setpoints '
                        '(--profile FILE with setpoints: [{t: 0.0, effort: ...}, ...])')


def motor_parameters(motor) -> Dict[str, object]:
    """Return the node parameters of a motor (every field ``declare_motor`` declares)."""
    return {k: (int(v) if k == 'pole_pairs' else float(v)) for k, v in motor.as_dict().items()}


CONTROLLER_LIMITS = ('torque_limit', 'current_limit', 'speed_limit', 'field_weakening',
                     'voltage_margin', 'current_margin')
PLANT_PROTECTION = ('inverter_rating', 'current_trip', 'speed_trip')
#: the real plant's blocks (docs/plant.md), as PlantSimulator and the plant node take them
PLANT_BLOCKS = ('inverter', 'sensors', 'saturation', 'thermal')
#: the blocks held as typed models (pydantic; the plant node takes them as <block>.<field>)
TYPED_BLOCKS = ('inverter', 'sensors')

START_MODES = ('rest', 'steady')
DEFAULT_DURATION = {task: p['duration'] for task, p in TASK_PRESETS.items()}
#: limits and trips where 0 means "none" on the command line and in a run file; left out (None),
#: v_limit, current_limit and the trips take the motor's rating (none without one; docs/limits.md)
ZERO_IS_NONE = ('v_limit', 'torque_limit', 'current_limit', 'speed_limit', 'current_trip',
                'speed_trip')


def limit_value(value):
    """Return a limit as the ROS-free models take it: not given → RATED, 0 → None (none)."""
    if value is None:
        return RATED
    return None if value == 0 else value


def limit_parameter(value) -> float:
    """Return a limit as the nodes take it: not given → -1 (the rating), 0 → 0 (none)."""
    return -1.0 if value is None else float(value)


NOISE_KEYS = {'current': 'current_noise_std', 'speed': 'speed_noise_std', 'seed': 'noise_seed'}
NODES = ('plant', 'controller', 'observer', 'adapter')


class RunFileError(ValueError):
    """A run file (or an override) that cannot be used: ``<source>: <key>: <reason>``."""

    def __init__(self, source: str, key: str, reason: str):
        self.source, self.key, self.reason = source, key, reason
        super().__init__(f'{one_line(source)}: {one_line(key)}: {one_line(reason)}')


@dataclass(frozen=True)
class Scenario:
    """
    One closed-loop run. Units SI; None picks the task default (docs/running.md).

    Built from keywords (Python) or a run file (:meth:`from_file`); frozen: derive variants
    with :func:`dataclasses.replace`. ``motor``/``estimates``/``profile``/``load_model`` take the
    object or a file path; ``variation`` is a name of :data:`im_common.params.SCHEDULES` or a
    breakpoint mapping; ``gains`` and ``parameters`` are {node: {parameter: value}}.
    """

    task: str = 'position'
    strategy: str = 'min_energy'
    T_s: float = 1e-4
    duration: Optional[float] = None
    variation: object = 'none'
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
    baseline: Optional[dict] = None           # a baseline controller's gains (its gains model)
    schedule: Optional[ParameterSchedule] = None   # overrides ``variation`` (ROS-free loop only)
    motor: Optional[MotorParams] = None       # the plant's motor (None: the thesis motor)
    estimates: Optional[MotorParams] = None   # the controller/observer model (None: = motor)
    profile: Optional[Profile] = None         # setpoints of one's own (None: thesis profile)
    load_model: Optional[Load] = None         # shaft load (None: the task's thesis load)
    inverter_rating: Optional[float] = None   # plant's inverter limit [V] (None: plant default)
    sensorless: bool = False                  # controller/observer use no measured speed/position
    speed_observer_options: dict = field(default_factory=dict)  # SpeedAdaptiveObserver keywords
    torque_limit: Optional[float] = None      # controller limits (None: none)
    current_limit: Optional[float] = None
    speed_limit: Optional[float] = None
    current_trip: Optional[float] = None      # plant protection (None: off)
    speed_trip: Optional[float] = None
    gains: Optional[dict] = None              # design_gains output {controller: .., observer: ..}
    mode: str = 'lockstep'                    # the plant's stepping (graph runs)
    parameters: Optional[dict] = None         # extra node parameters, merged last (graph runs)
    # the real plant (docs/plant.md; None / False: the ideal plant): the run file's inverter and
    # sensors blocks (an Inverter, a Sensors: a mapping given is parsed once, in __post_init__),
    # the motor's saturation and thermal blocks (a mapping, or 'motor': the motor file's own),
    # and whether the core loss acts
    inverter: Optional[Inverter] = None
    sensors: Optional[Sensors] = None
    saturation: object = None
    thermal: object = None
    iron_loss: bool = False
    # the drive's inverter-error compensation (docs/compensation.md; None: off): 'inverter'
    # (exact, from the inverter block) or {v_dead, r_on, current_band}, resolved to the latter
    compensation: object = None
    # the drive's observer and controller on a magnetizing curve (im_common.saturation.
    # SaturatedModel): true, the plant's ``saturation``; or a curve block of the drive's own
    # ({table: [[psi, i_M], ...]}, what commissioning writes, or {law: power, ...})
    saturation_model: object = False
    # a steady start with the plant's rotor flux this factor times the controller's steady state
    # (the model's steady state is never exactly the motor's; docs/adaptation.md §6)
    start_flux: float = 1.0
    # what the loss-optimizing strategies minimize: the motor's losses, or the drive's (the
    # inverter's conduction and switching losses added, from the inverter block;
    # docs/efficiency.md)
    loss_scope: str = 'motor'

    def __post_init__(self):
        put = object.__setattr__
        if isinstance(self.motor, str):           # the motor file's blocks, where asked for
            self._motor_file_blocks(self.motor)
        for name, read in (('motor', load_motor_file), ('estimates', load_motor_file),
                           ('profile', load_profile), ('load_model', load_file)):
            if isinstance(getattr(self, name), str):
                put(self, name, read(getattr(self, name)))
        for name, cls, what in (('motor', MotorParams, 'a motor file or a mapping of its fields'),
                                ('estimates', MotorParams, 'a motor file or a mapping of values'),
                                ('profile', Profile, 'a file or {setpoints: [...]}'),
                                ('load_model', Load, 'a load file or a mapping with a kind')):
            if getattr(self, name) is not None and not isinstance(getattr(self, name), cls):
                raise InvalidParameter(name, getattr(self, name), f'must be {what}')
        for name in ('sensorless', 'iron_loss'):
            if not isinstance(getattr(self, name), bool):
                raise InvalidParameter(name, getattr(self, name), 'must be true or false')
        for name in ('controller_options', 'speed_observer_options'):
            if not isinstance(getattr(self, name), Mapping):
                raise InvalidParameter(name, getattr(self, name), 'must be a mapping')
        for name, shape in (('current_gain', (2, 2)), ('observer_gain', (4, 2))):
            v = getattr(self, name)
            if v is not None and not _matrix(v, shape):
                raise InvalidParameter(name, v, f'must be a {shape[0]}x{shape[1]} matrix of '
                                       'finite numbers (a list of rows)')
        # the task at once (its presets are read below); the strategy is the controller
        # configuration's to refuse (controller_config(), at the end: ControllerConfig's type)
        check_choice('task', self.task, TASKS)
        check_choice('controller', self.controller, CONTROLLERS)
        check_law_task(self.law, self.task, field='controller')
        if self.baseline is not None:
            if self.law == 'thesis':
                raise InvalidParameter('baseline', self.baseline, 'the gains of a baseline '
                                       f'controller, but the controller is {self.controller!r} '
                                       '(current_vector or vhz take them)')
            put(self, 'baseline', gains_model(self.law).from_block(self.baseline))
        if self.law != 'thesis':        # a baseline law would ignore the thesis law's gains
            given = [f'controller_options.{k}' for k in THESIS_LAW_GAINS
                     if k in self.controller_options] + (['current_gain']
                                                         if self.current_gain is not None else [])
            if given:
                raise InvalidParameter(given[0], self.controller_options.get(
                    given[0].split('.')[-1], self.current_gain), 'is a gain of the thesis law; '
                    f"controller {self.controller} takes its gains from 'baseline:' "
                    '(docs/baselines.md)')
        check_choice('mode', self.mode, STEPPING_MODES)
        if isinstance(self.variation, Mapping):
            put(self, 'variation', normalize_variation(self.variation) or 'none')
        elif self.schedule is None and self.variation not in SCHEDULES:
            raise InvalidParameter('variation', self.variation,
                                   f'must be one of {", ".join(SCHEDULES)} or a mapping '
                                   '{parameter: [breakpoints]}')
        if not _real(self.T_s) or not self.T_s > 0:
            raise InvalidParameter('T_s', self.T_s, 'must be a positive period in seconds')
        for name, low in (('theta0', None), ('omega0', None), ('k_e', 0.0),
                          ('core_loss_exponent', 0.0), ('plant_substep', 0.0),
                          ('observer_substep', 0.0)):
            v = getattr(self, name)     # None: the default of theta0, omega0, k_e (below)
            if (v is not None or name not in ('theta0', 'omega0', 'k_e')) \
                    and (not _real(v) or (low is not None and not v > low)):
                raise InvalidParameter(name, v, 'must be a finite number' if low is None
                                       else f'must be a finite number > {low:g}')
        if self.sensorless and self.task == 'position':
            raise InvalidParameter('sensorless', True, POSITION_NEEDS_SENSOR)
        if self.task == 'torque' and self.profile is None:
            raise InvalidParameter('profile', None, TORQUE_NEEDS_PROFILE)
        if self.profile is not None and self.profile.mode != self.task:
            raise InvalidParameter('profile', self.profile.source,
                                   f'is a {self.profile.mode} profile; the task is {self.task}')
        for name in ('current_noise_std', 'speed_noise_std'):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not v >= 0 \
                    or not math.isfinite(v):
                raise InvalidParameter(name, v, 'must be a standard deviation >= 0')
        for name in ZERO_IS_NONE + ('inverter_rating',):
            v = getattr(self, name)
            low = 0.0 if name in ZERO_IS_NONE else 1e-300      # 0: none
            if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float))
                                  or not (math.isfinite(v) and v >= low)):
                raise InvalidParameter(name, v, 'must be >= 0 (0: none)' if low == 0.0
                                       else 'must be > 0')
        if self.duration is None:
            put(self, 'duration', DEFAULT_DURATION[self.task] if self.profile is None
                else self.profile.end_time + 1.0)
        if not _real(self.duration) or not self.duration > 0:
            raise InvalidParameter('duration', self.duration, 'must be > 0 s')
        preset = TASK_PRESETS[self.task]
        if self.start is None:
            put(self, 'start', preset['start'])
        check_choice('start', self.start, START_MODES)
        start_value = self.profile.start_value if self.profile is not None else None
        if self.theta0 is None:
            put(self, 'theta0', start_value if self.task == 'position' and start_value is not None
                else preset['theta0'])
        if self.omega0 is None:
            put(self, 'omega0', start_value if self.task == 'speed' and start_value is not None
                else preset['omega0'])
        if self.gains:
            self._check_gains()
        for node in (self.parameters or {}):
            if node not in NODES:
                raise InvalidParameter(f'parameters.{node}', self.parameters[node],
                                       f'unknown node (one of {", ".join(NODES)})')
        if isinstance(self.variation, dict):     # the schedule must stay a motor over the run
            self.plant_schedule().validate(self.duration)
        self._check_plant_blocks()
        self.drive_loss()
        # the drive's own checks of the whole run (limits against the motor's magnetizing
        # current, ...): here, naming the key, not when the drive is built (cheap: ~0.1 ms)
        self.controller_config()

    def _motor_file_blocks(self, path: str) -> None:
        wanted = [b for b in MOTOR_BLOCKS if getattr(self, b) == 'motor']
        if not wanted:
            return
        blocks = load_motor_blocks(path)
        for name in wanted:
            if name not in blocks:
                raise InvalidParameter(name, 'motor', f'the motor file {path} has no {name} '
                                                      'block')
            object.__setattr__(self, name, blocks[name])

    def _check_plant_blocks(self) -> None:
        """Validate the real plant's blocks (one line naming the key) and write them resolved."""
        put = object.__setattr__
        motor = self.plant_motor()
        for name in MOTOR_BLOCKS:
            if getattr(self, name) == 'motor':
                raise InvalidParameter(name, 'motor', 'takes the block of a motor file: give the '
                                                      'motor as a file (motor: path)')
        if not isinstance(self.iron_loss, bool):
            raise InvalidParameter('iron_loss', self.iron_loss, 'must be true or false')
        if self.inverter is not None:       # the typed blocks, parsed here once
            put(self, 'inverter', Inverter.from_block(self.inverter))
            check_against_motor(self.inverter, motor.rated_voltage, self.T_s)
        if self.sensors is not None:
            put(self, 'sensors', Sensors.from_block(self.sensors))
        if self.saturation is not None:
            put(self, 'saturation', saturation_from_dict(self.saturation, motor.L_M).describe())
        if self.thermal is not None:
            put(self, 'thermal', thermal_from_dict(self.thermal).describe())
        self._check_real_plant_model()
        model = self.compensation_model()
        put(self, 'compensation', None if model is None else model.describe())
        if (isinstance(self.start_flux, bool) or not isinstance(self.start_flux, (int, float))
                or not (math.isfinite(self.start_flux) and self.start_flux > 0.0)):
            raise InvalidParameter('start_flux', self.start_flux, 'must be a factor > 0')
        if self.start_flux != 1.0 and self.start != 'steady':
            raise InvalidParameter('start_flux', self.start_flux, 'scales the rotor flux of a '
                                   'steady start; this run starts at rest (start: rest)')
        if isinstance(self.saturation_model, Mapping):      # the drive's own curve
            curve = saturation_from_dict(self.saturation_model, self.model_estimates().L_M,
                                         'saturation_model')
            object.__setattr__(self, 'saturation_model', curve.describe())
        elif not isinstance(self.saturation_model, bool):
            raise InvalidParameter('saturation_model', self.saturation_model,
                                   "must be true (the plant's saturation curve), false, or a "
                                   "curve of the drive's own: {table: [[psi, i_M], ...]} or "
                                   '{law: power, beta, S}')
        if self.saturation_model is True and self.saturation is None:
            raise InvalidParameter('saturation_model', True, 'needs the magnetizing curve: give '
                                   'saturation (motor: the block of the motor file)')
        if self.saturation_model and self.controller in ADAPTATION:
            raise InvalidParameter('saturation_model', True, f'with the {self.controller} '
                                   'controller: its adapter tracks L_M itself; choose one')
        if self.saturation_model and self.controller != 'nominal':
            raise InvalidParameter('saturation_model', True, f'with the {self.controller} '
                                   'controller: only the nominal thesis law takes the curve')

    def _check_real_plant_model(self) -> None:
        """
        Refuse what the real plant's model cannot run, here and not when the plant is built.

        im_common.model.RealMotorModel takes no time-varying inductance and an acting iron loss
        only with core_loss_exponent 2: named by the run file's key (variation.L_s, ...).
        """
        blocks = [k for k in PLANT_BLOCKS if getattr(self, k) is not None
                  and (k != 'inverter' or self.inverter.switched)] \
            + (['iron_loss'] if self.iron_loss else [])
        if not blocks:
            return
        real = f'the real plant ({", ".join(blocks)}) takes no time-varying inductance; vary ' \
            'R_s or R_r, or use the ideal plant'
        if self.schedule is not None:
            if not self.schedule.inductances_constant:
                raise InvalidParameter('schedule', self.schedule.name, real)
        elif isinstance(self.variation, dict):
            varied = [n for n in INDUCTANCE_NAMES if n in self.variation]
            if varied:
                raise InvalidParameter(f'variation.{varied[0]}', None, real)
        elif not self.plant_schedule().inductances_constant:
            raise InvalidParameter('variation', self.variation, real)
        if self.iron_loss and self.core_loss_exponent != 2.0:
            raise InvalidParameter('core_loss_exponent', self.core_loss_exponent,
                                   'must be 2 with an acting iron loss (iron_loss: true; a '
                                   'resistance dissipates |psi|^2)')

    def drive_loss(self):
        """Return the inverter's (r, c) the drive's strategies add ((0, 0): loss_scope motor)."""
        check_choice('loss_scope', self.loss_scope, LOSS_SCOPES)
        if self.loss_scope == 'motor':
            return 0.0, 0.0
        if self.inverter is None or not self.inverter.switched:
            raise InvalidParameter('loss_scope', self.loss_scope, "takes the inverter's losses "
                                   "from the run's switched inverter block (V_dc, "
                                   'pwm_frequency, ...), and this run has none')
        return self.inverter.steady_loss_coefficients()

    def saturated_model(self):
        """Return the drive's :class:`~im_common.saturation.SaturatedModel` (None: linear)."""
        if not self.saturation_model:
            return None
        model = self.model_estimates()
        return SaturatedModel(saturation_from_dict(self.drive_curve(), model.L_M), model)

    def drive_curve(self) -> Optional[dict]:
        """Return the curve block the drive runs on: the plant's, or its own (None: linear)."""
        if self.saturation_model is True:
            return self.saturation
        return self.saturation_model or None

    def compensation_model(self):
        """Return the drive's :class:`~im_common.compensation.InverterErrorModel` (None: off)."""
        switched = self.inverter if self.inverter is not None and self.inverter.switched else None
        return compensation_from_dict(self.compensation, switched)

    def plant_blocks(self) -> dict:
        """
        Return the PlantSimulator keywords of the real plant's blocks ({}: the ideal plant).

        The inverter and sensors as their models (:class:`Inverter`, :class:`Sensors`), the
        saturation and thermal blocks as mappings.
        """
        out = {k: getattr(self, k) for k in PLANT_BLOCKS if getattr(self, k) is not None}
        if self.iron_loss:
            out['iron_loss'] = True
        return out

    def _check_gains(self) -> None:
        gain_arguments_from_parameters(self.gains)
        for node in ('controller', 'observer'):
            period = self.gains.get(node, {}).get('gain_period')
            if period is not None and abs(float(period) - self.T_s) > 1e-12:
                raise InvalidParameter(f'gains.{node}.gain_period', period,
                                       f'the gains were designed for another period than '
                                       f'T_s = {self.T_s:g} s')

    # The model of the run ------------------------------------------------------------------
    @property
    def delay(self) -> int:
        """Return the plant's computational delay [control periods] (``inverter.delay``; 0)."""
        return 0 if self.inverter is None else self.inverter.delay

    @property
    def variation_label(self) -> str:
        """Return what the summary and the console header say about the variation."""
        if isinstance(self.variation, dict):
            return describe_variation(self.variation)
        return str(self.variation)

    def plant_motor(self) -> MotorParams:
        return self.motor if self.motor is not None else THESIS_MOTOR

    def plant_schedule(self) -> ParameterSchedule:
        if self.schedule is not None:
            return self.schedule
        if isinstance(self.variation, dict):
            return variation_schedule(self.plant_motor(), self.variation)
        return SCHEDULES[self.variation](self.plant_motor())

    def model_estimates(self) -> MotorParams:
        """
        Return the controller's and observer's motor model.

        Explicit ``estimates``, else the chapter-4 estimates under that named variation,
        else the plant's own motor.
        """
        if self.estimates is not None:
            return self.estimates
        if self.variation == 'chapter4':
            return CHAPTER4_ESTIMATES
        return self.plant_motor()

    def plant_load(self) -> Load:
        return self.load_model if self.load_model is not None else task_load(self.task)

    def limits(self) -> dict:
        """Return the controller limits that are set (torque/current/speed and the margins)."""
        out = {k: getattr(self, k) for k in ('torque_limit', 'current_limit', 'speed_limit')
               if getattr(self, k) is not None}
        out.update({k: v for k, v in self.controller_options.items() if k in CONTROLLER_LIMITS})
        return out

    def gain_arguments(self) -> dict:
        """
        Return current_gain, observer_gain, k_e, controller_options of the ROS-free loop.

        Explicit fields first, then the ``gains`` mapping.
        """
        kw = gain_arguments_from_parameters(self.gains) if self.gains else {}
        out = {'current_gain': self.current_gain if self.current_gain is not None
               else kw.get('current_gain'),
               'observer_gain': self.observer_gain if self.observer_gain is not None
               else kw.get('observer_gain'),
               'k_e': self.k_e if self.k_e is not None else kw.get('k_e')}
        out['controller_options'] = dict(kw.get('controller_options', {}),
                                         **self.controller_options)
        return out

    def initial_state(self):
        """
        Return (plant x0 or None, observer x̂_0).

        At rest demagnetized, or ('steady') in the controller's own steady state at (θ0, ω0) —
        plant and observer both start there.
        """
        if self.start != 'steady':
            return None, (0.0, 0.0, 0.0, 0.0)
        return steady_start(self.controller_config(), self.plant_schedule().params_at(0.0),
                            self.theta0, self.omega0, flux_scale=float(self.start_flux))

    @property
    def law(self) -> str:
        """Return the control law the controller runs: the thesis's, or a baseline's."""
        return self.controller if self.controller in LAWS else 'thesis'

    def controller_config(self) -> ControllerConfig:
        g = self.gain_arguments()
        opts = dict(g['controller_options'])
        opts.setdefault('law', self.law)
        if self.baseline is not None:
            opts.setdefault('baseline', self.baseline)
        opts.setdefault('core_loss_exponent', self.core_loss_exponent)
        opts.setdefault('horizon', self.duration)   # the run's end: the optimal strategy's plan
        opts.setdefault('sensorless', self.sensorless)  # orient on the observed flux
        opts.setdefault('delay', self.delay)    # predict across the plant's delay (0: as printed)
        opts.setdefault('current_limit', limit_value(self.current_limit))
        r_inv, c_inv = self.drive_loss()
        if r_inv or c_inv:
            opts.setdefault('drive_loss_r', r_inv)
            opts.setdefault('drive_loss_c', c_inv)
        for key in ('torque_limit', 'speed_limit'):
            if getattr(self, key) is not None:
                opts.setdefault(key, getattr(self, key) or None)
        if self.profile is not None:
            opts.setdefault('profile', 'setpoint')
            opts.setdefault('setpoints', self.profile.setpoints)
        # the controller feeds forward what it can know of the load: a load of the shaft state,
        # or the torque a load in time starts at (loads.Load.feedforward)
        for key, value in load_parameters(self.plant_load().feedforward()).items():
            opts.setdefault(key, value)
        sat = self.saturated_model()
        return ControllerConfig(mode=self.task, strategy=self.strategy,
                                params=self.model_estimates(), v_limit=limit_value(self.v_limit),
                                current_gain=g['current_gain'], T_s=self.T_s,
                                compensation=self.compensation_model(),
                                magnetizing=None if sat is None else sat.curve, **opts)

    # The graph's parameters ----------------------------------------------------------------
    def node_parameters(self, truth_decimation: int = 10, reference_decimation: int = 10,
                        input_timeout: float = 5.0) -> Dict[str, Dict[str, object]]:
        """
        Return the parameters of the four nodes ({node: {parameter: value}}).

        A ROS 2 parameters file's structure; no ROS import. Without motor, estimates, profile,
        load, limits, noise or gains the thesis scenario of the task.
        """
        if self.schedule is not None:
            raise InvalidParameter('schedule', self.schedule.name,
                                   'a schedule object runs on the ROS-free loop only; write it '
                                   'as a variation mapping for the graph')
        unknown = [k for k in self.controller_options if k not in CONTROLLER_LIMITS
                   and k != 'flux_coupling']
        if unknown:
            raise InvalidParameter(f'controller_options.{unknown[0]}',
                                   self.controller_options[unknown[0]],
                                   'runs on the ROS-free loop only (the graph takes '
                                   f'{", ".join(CONTROLLER_LIMITS)}, flux_coupling)')
        limits = self.limits()
        protection = {k: getattr(self, k) for k in PLANT_PROTECTION
                      if getattr(self, k) is not None}
        common = {'T_s': float(self.T_s), 'duration': float(self.duration),
                  'input_timeout': float(input_timeout)}
        v_limit = limit_parameter(self.v_limit)
        lp = load_parameters(self.plant_load())
        lp_model = load_parameters(self.plant_load().feedforward())     # the controller's
        mine = motor_parameters(self.motor) if self.motor is not None else {}
        model_values = dict(mine)
        if self.estimates is not None:
            model_values = motor_parameters(self.estimates)
        elif self.variation == 'chapter4':
            model_values.update({k: getattr(CHAPTER4_ESTIMATES, k)
                                 for k in ('R_s', 'R_r', 'L_s', 'L_r', 'L_sr')})
        if isinstance(self.variation, dict):
            variation = {'variation': 'schedule',
                         'variation_schedule': json.dumps(self.variation, sort_keys=True)}
        else:
            variation = {'variation': self.variation}
        plant = dict(common, **variation, v_limit=v_limit, truth_decimation=int(truth_decimation),
                     **mine, **lp, theta0=float(self.theta0), omega0=float(self.omega0))
        plant.update({k: float(v) for k, v in protection.items()})
        for key, value in self.plant_blocks().items():      # the real plant (docs/plant.md)
            if key in TYPED_BLOCKS:         # inverter.enabled, inverter.<field>, ...
                plant.update(block_parameters(value, key))
            else:
                plant[key] = value if key == 'iron_loss' else json.dumps(value, sort_keys=True)
        if self.current_noise_std or self.speed_noise_std:
            plant.update(current_noise_std=float(self.current_noise_std),
                         speed_noise_std=float(self.speed_noise_std),
                         noise_seed=int(self.noise_seed))
        if self.mode != 'lockstep':
            plant['mode'] = self.mode
        x0 = obs_x0 = None
        if self.start == 'steady':
            x0, obs_x0 = self.initial_state()
        adaptive = self.controller in ADAPTATION
        ctl = dict(common, mode=self.task, strategy=self.strategy, use_adapter=adaptive,
                   v_limit=v_limit, reference_decimation=int(reference_decimation),
                   load_known=True, **lp_model, **model_values)
        if self.profile is not None:
            ctl.update(self.profile.as_parameters())
        ctl.update({k: (v if isinstance(v, bool) else float(v)) for k, v in limits.items()})
        if 'flux_coupling' in self.controller_options:
            ctl['flux_coupling'] = self.controller_options['flux_coupling']
        if self.law != 'thesis':        # a baseline law in the thesis law's place
            ctl['law'] = self.law
            if self.baseline is not None:
                ctl.update(block_parameters(self.baseline, 'baseline'))
        if self.current_gain is not None:
            ctl['current_gain'] = [float(g) for g in _flat(self.current_gain)]
            ctl['gain_period'] = float(self.T_s)
        if x0 is not None:          # plant and observer start in the controller's steady state
            plant['initial_current'] = [float(obs_x0[0]), float(obs_x0[1])]
            plant['initial_flux'] = [float(x0[2]), float(x0[3])]
        obs = dict(common, use_adapter=adaptive, **model_values)
        if x0 is not None:
            obs['initial_state'] = [float(v) for v in obs_x0]
        if self.observer_gain is not None:
            obs['injection_gain'] = [float(g) for g in _flat(self.observer_gain)]
            obs['gain_period'] = float(self.T_s)
        if self.k_e is not None:
            obs['k_e_injection'] = float(self.k_e)
        adapter = dict(common, enable=adaptive, **model_values)
        if 'thermal' in plant:      # the motor's networks: the adapter's thermal_tracking takes
            adapter['thermal'] = plant['thermal']       # them (docs/adaptation.md §9)
        # controller, observer, adapter: the observer's ω̂ replaces the shaft
        if self.sensorless:
            ctl['sensorless'] = obs['sensorless'] = adapter['sensorless'] = True
            obs['initial_speed'] = float(self.omega0) if self.start == 'steady' else 0.0
        if adaptive:
            adapter.update(ADAPTATION[self.controller])
        if self.saturation_model:   # the drive's observer and controller on the curve
            ctl['saturation_model'] = obs['saturation_model'] = json.dumps(self.drive_curve(),
                                                                           sort_keys=True)
        if self.delay:              # the controller predicts across it; observer and adapter
            ctl['delay'] = obs['delay'] = adapter['delay'] = self.delay     # take what acts
        r_inv, c_inv = self.drive_loss()
        if r_inv or c_inv:          # loss_scope drive: the strategies add the inverter's losses
            ctl.update(drive_loss_r=float(r_inv), drive_loss_c=float(c_inv))
        comp = self.compensation_model()
        if comp is not None:        # the controller adds ê(i); observer and adapter subtract it
            for node in (ctl, obs, adapter):
                node.update(comp.parameters())
        out = {'plant': plant, 'controller': ctl, 'observer': obs, 'adapter': adapter}
        for extra in (self.gains, self.parameters):
            for node, values in (extra or {}).items():
                out[node].update(values)
        return out

    # The run file --------------------------------------------------------------------------
    @classmethod
    def from_mapping(cls, mapping: Mapping, source: str = 'run file',
                     base_dir: Optional[str] = None, overrides: Optional[Mapping] = None,
                     override_source: str = 'command line') -> 'Scenario':
        """
        Return the Scenario of a run file's mapping.

        ``overrides`` are applied over it, dotted keys for nested ones; any error is one
        :class:`RunFileError` naming ``source`` (or ``override_source`` for an override's key)
        and the key. Relative file paths are read from ``base_dir`` (the run file's directory).
        """
        if mapping is None:
            mapping = {}
        if not isinstance(mapping, Mapping):
            raise RunFileError(source, 'run file',
                               'must be a mapping of run keys (docs/running.md)')
        doc = json.loads(json.dumps(dict(mapping), default=str))   # a deep, plain copy
        over = set()
        for key, value in (overrides or {}).items():
            over.add(key.split('.')[0])
            _set_dotted(doc, key, value)
        try:
            return cls(**_fields_from_mapping(doc, base_dir, source))
        except InvalidParameter as exc:
            # 'key: inner' is an error inside a referenced file or block (it names itself); a
            # key of the file's own may hold ':' too (unknown: its text is given back as it is)
            key, _, inner = exc.name.partition(': ')
            top = key.split('.')[0].split('[')[0]
            where = override_source if top in over else source
            reason = exc.reason if exc.value is None or f'{exc.value!r}' in exc.reason \
                else f'{exc.reason} (got {exc.value!r})'
            if inner:
                reason = f'{inner}: {reason}'
            raise RunFileError(where, _key_name(key), reason) from None
        except (TypeError, ValueError) as exc:
            raise RunFileError(source, 'run file', str(exc).splitlines()[0]) from None

    @classmethod
    def from_file(cls, path: str, overrides: Optional[Mapping] = None,
                  override_source: str = 'command line') -> 'Scenario':
        """Read a run file (YAML); ``overrides`` {key: value} as ``--set key=value`` gives them."""

        def error(message):
            return RunFileError(path, 'run file', message)
        doc = read_yaml_file(path, 'run file', error)
        return cls.from_mapping(doc, source=path, base_dir=os.path.dirname(os.path.abspath(path)),
                                overrides=overrides, override_source=override_source)

    def to_mapping(self) -> dict:
        """
        Return the run file of this scenario, fully resolved.

        Motor, estimates, load, profile and gains inline — the defaults too (the thesis motor,
        the task's load and reference trajectory) — so it re-runs without any other file and
        says what ran (:meth:`from_mapping` of it gives an equal Scenario: a default written
        out reads back as the default).
        """
        if self.schedule is not None:
            raise InvalidParameter('schedule', self.schedule.name,
                                   'a schedule object has no run-file '
                                   'form; use a variation mapping')
        out = {'task': self.task, 'strategy': self.strategy, 'controller': self.controller,
               'T_s': float(self.T_s), 'duration': float(self.duration),
               'variation': self.variation}
        derived = replace(self, start=None, theta0=None, omega0=None)
        for name in ('start', 'theta0', 'omega0'):
            if getattr(self, name) != getattr(derived, name):
                out[name] = getattr(self, name)
        out['motor'] = motor_parameters(self.plant_motor())     # the defaults too: resolved
        if self.estimates is not None:
            out['estimates'] = motor_parameters(self.estimates)
        out['load'] = dict(self.plant_load().describe())
        if self.profile is not None:
            key = MODE_KIND[self.profile.mode]
            out['profile'] = {'setpoints': [dict({'t': t, key: v},
                                                 **({} if d is None else {'duration': d}))
                                            for t, v, d in self.profile.setpoints]}
        else:                           # the thesis's reference of the task, its parameters
            out['profile'] = THESIS_TRAJECTORIES[self.task]().describe()
        for name in ZERO_IS_NONE + ('inverter_rating',):
            if getattr(self, name) is not None:
                out[name] = float(getattr(self, name))
        if self.current_noise_std or self.speed_noise_std or self.noise_seed:
            out['noise'] = {'current': float(self.current_noise_std),
                            'speed': float(self.speed_noise_std), 'seed': int(self.noise_seed)}
        if self.sensorless:
            out['sensorless'] = True
        if self.mode != 'lockstep':
            out['mode'] = self.mode
        out.update({k: v.describe() if k in TYPED_BLOCKS else v
                    for k, v in self.plant_blocks().items()})
        if self.compensation is not None:
            out['compensation'] = dict(self.compensation)
        if self.saturation_model:
            out['saturation_model'] = True if self.saturation_model is True \
                else dict(self.saturation_model)
        defaults = {f.name: f.default for f in fields(self)}
        for name in ('current_gain', 'observer_gain', 'k_e', 'gains', 'parameters',
                     'core_loss_exponent', 'plant_substep', 'observer_substep', 'start_flux',
                     'loss_scope'):
            if getattr(self, name) is not None and getattr(self, name) != defaults[name]:
                out[name] = getattr(self, name)
        for name in ('controller_options', 'speed_observer_options'):
            if getattr(self, name):
                out[name] = dict(getattr(self, name))
        return json.loads(json.dumps(out, default=_plain))

    def to_yaml(self) -> str:
        """:meth:`to_mapping` as YAML text (floats exactly, in their shortest repr)."""
        return yaml.safe_dump(self.to_mapping(), sort_keys=False, default_flow_style=None,
                              width=100)


#: controller / observer node parameters a gains file may set, and their Scenario counterparts
GAIN_PARAMETERS = {'controller': ('current_gain', 'gain_period', 'flux_coupling'),
                   'observer': ('injection_gain', 'gain_period', 'k_e_injection')}


def gain_arguments_from_parameters(params: dict) -> dict:
    """
    Return the Scenario keyword arguments of node-parameter gain overrides.

    The overrides of ``design_gains --out``
    (:func:`im_controller.design_gains.design_for_scenario`): {'controller': {...}, 'observer':
    {...}} -> current_gain (2×2), observer_gain (4×2), k_e, controller_options. Empty -> the
    thesis's gains. Any other parameter is refused by name (the offline loop would ignore it).
    """
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


#: run-file keys that are not Scenario fields of the same name
RENAMED = {'load': 'load_model'}


def run_keys() -> tuple:
    """Every key a run file may hold."""
    names = [f.name for f in fields(Scenario) if f.name not in ('schedule', 'load_model',
                                                                'current_noise_std',
                                                                'speed_noise_std', 'noise_seed')]
    return tuple(names + ['load', 'noise'])


def _fields_from_mapping(doc: dict, base_dir: Optional[str], source: str = 'run file') -> dict:
    keys = run_keys()
    kw = {}
    inline_blocks = {}

    def path(value):
        return value if base_dir is None or os.path.isabs(value) else os.path.join(base_dir, value)

    for key, value in doc.items():
        if key not in keys:
            near = difflib.get_close_matches(str(key), keys, n=1)
            raise InvalidParameter(str(key), value, f'unknown run-file key; did you mean '
                                   f"'{near[0]}'?" if near else 'unknown run-file key (see '
                                   'docs/running.md)')
        if key in ('motor', 'estimates', 'load', 'profile', 'gains', 'parameters') \
                and value is not None and not isinstance(value, (str, Mapping)):
            raise InvalidParameter(key, value, 'must be a file or a mapping')
        if key == 'noise':
            if not isinstance(value, Mapping):
                raise InvalidParameter('noise', value, 'must be a mapping {current, speed, seed}')
            for k, v in value.items():
                if k not in NOISE_KEYS:
                    raise InvalidParameter(f'noise.{k}', v,
                                           'unknown (current [A], speed [rad/s], seed)')
                if k == 'seed' and (isinstance(v, bool) or not isinstance(v, int) or v < 0):
                    raise InvalidParameter('noise.seed', v, 'must be an integer >= 0')
                if k != 'seed' and (isinstance(v, bool) or not isinstance(v, (int, float))):
                    raise InvalidParameter(f'noise.{k}', v, 'must be a standard deviation >= 0')
                kw[NOISE_KEYS[k]] = v
            continue
        if key == 'motor' and isinstance(value, Mapping):
            inline_blocks = motor_blocks(value, source='motor')
            motor = motor_from_dict(value, source='motor')
            if motor != THESIS_MOTOR:       # the built-in default (a run record's) is no file
                warn_motor_defaults(f'{source}: motor', value, motor)
            value = motor
        elif key in ('motor', 'estimates', 'load', 'profile', 'gains', 'parameters') \
                and isinstance(value, str):
            # a motor by name (motor: krause_3hp): the shipped file, unless a file is so named
            value = (shipped_motor(value, key) if key in ('motor', 'estimates')
                     and is_motor_name(value) and not os.path.isfile(path(value))
                     else path(value))
            if key in ('gains', 'parameters'):
                value = _read_parameters_file(value)
            elif key == 'load':
                value = load_file(value)
        elif key == 'load' and value is not None:
            value = load_from_dict(value, source='load')
        elif key == 'profile' and isinstance(value, Mapping) and 'kind' in value:
            value = _thesis_reference(value, doc.get('task', 'position'))   # None: the default
        elif key == 'profile' and value is not None:
            if not isinstance(value, Mapping) or set(value) != {'setpoints'}:
                raise InvalidParameter('profile', value, 'must be a file or {setpoints: [...]}')
            value = from_setpoints(value['setpoints'], source='profile')
        kw[RENAMED.get(key, key)] = value
    for name in MOTOR_BLOCKS:         # 'motor' with an inline motor: its own block
        if kw.get(name) == 'motor' and name in inline_blocks:
            kw[name] = inline_blocks[name]
    est = kw.get('estimates')
    if isinstance(est, Mapping):      # a partial model: these values over the plant's motor
        motor = kw.get('motor')
        if isinstance(motor, str):
            motor = load_motor_file(motor)
        base = (motor or THESIS_MOTOR).as_dict()
        kw['estimates'] = motor_from_dict(dict(base, **est), source='estimates')
    for key in ('gains', 'parameters'):
        if kw.get(key) is not None and not isinstance(kw[key], Mapping):
            raise InvalidParameter(key, kw[key], 'must be a file or {node: {parameter: value}}')
    # a default written out (a run record is fully resolved) reads back as the default
    if isinstance(kw.get('motor'), MotorParams) and kw['motor'] == THESIS_MOTOR:
        kw['motor'] = None
    task = kw.get('task', 'position')
    if isinstance(kw.get('load_model'), Load) and task in TASK_PRESETS \
            and kw['load_model'] == task_load(task):
        kw['load_model'] = None
    return kw


def _thesis_reference(value: Mapping, task: str) -> None:
    """
    Read the thesis's reference trajectory as a run record writes it: the task's default (None).

    Its parameters are the thesis's (setpoints of one's own go in ``{setpoints: [...]}``).
    """
    kind = value.get('kind')
    tasks = {cls().describe()['kind']: t for t, cls in THESIS_TRAJECTORIES.items()}
    if kind not in tasks:
        raise InvalidParameter('profile.kind', kind, f'must be one of {", ".join(tasks)} (or '
                               'give {setpoints: [...]})')
    if tasks[kind] != task:
        raise InvalidParameter('profile', kind, f'is the thesis {tasks[kind]} reference; the '
                               f'task is {task}')
    if dict(value) != THESIS_TRAJECTORIES[task]().describe():
        raise InvalidParameter('profile', dict(value), f'the {kind} reference has the '
                               "thesis's parameters only; setpoints of your own go in "
                               '{setpoints: [...]}')
    return None


def _read_parameters_file(path: str) -> dict:
    return {node: dict(values) for node, values in
            load_parameters_file(path, nodes={n: {} for n in NODES}).items()}


def _real(value) -> bool:
    """Return whether ``value`` is a finite real number as a run file writes one (no bool)."""
    return (isinstance(value, (int, float)) and not isinstance(value, bool)
            and math.isfinite(value))


def _matrix(value, shape) -> bool:
    """Return whether ``value`` is a matrix of ``shape`` (rows) of finite real numbers."""
    rows = value.tolist() if isinstance(value, np.ndarray) else value
    return (isinstance(rows, (list, tuple)) and len(rows) == shape[0]
            and all(isinstance(r, (list, tuple)) and len(r) == shape[1]
                    and all(_real(x) for x in r) for r in rows))


def _set_dotted(doc: dict, key: str, value) -> None:
    parts = key.split('.')
    d = doc
    for p in parts[:-1]:
        if not isinstance(d.get(p), dict):
            d[p] = {}
        d = d[p]
    d[parts[-1]] = value


def _key_name(key: str) -> str:
    return {'load_model': 'load', 'current_noise_std': 'noise.current',
            'speed_noise_std': 'noise.speed', 'noise_seed': 'noise.seed'}.get(key, key)


def _flat(gain):
    return np.asarray(gain, float).ravel().tolist()


def _plain(value):
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, tuple):
        return list(value)
    raise TypeError(f'{value!r} has no run-file form')


__all__ = ['Scenario', 'RunFileError', 'run_keys', 'KINDS']
