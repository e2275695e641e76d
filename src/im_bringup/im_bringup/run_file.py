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
import functools
import json
import math
import os
from typing import (Annotated, Any, Dict, get_args, get_origin, List, Literal, Mapping,
                    Optional, Union)

from im_common.compensation import compensation_from_dict, CompensationBlock
from im_common.inverter import check_against_motor, Inverter
from im_common.loads import (Load, load_file, load_from_dict, LOAD_KINDS, load_parameters,
                             LoadBlock, make_load)
from im_common.motor_file import MotorEstimates, MotorFields
from im_common.node_params import block_parameters, variation_parameters
from im_common.params import (CHAPTER4_ESTIMATES, describe_variation, ELECTRICAL_NAMES,
                              INDUCTANCE_NAMES,
                              InvalidParameter, is_motor_name, load_motor_blocks, load_motor_file,
                              MOTOR_BLOCKS, motor_blocks, motor_from_dict, MotorParams,
                              normalize_variation, ParameterSchedule, RATED, SCHEDULES,
                              shipped_motor, THESIS_MOTOR, variation_block,
                              variation_schedule, warn_motor_defaults)
from im_common.saturation import (SaturatedModel, saturation_block, saturation_from_dict,
                                  SaturationBlock)
from im_common.thermal import Thermal, thermal_from_dict
from im_common.validation import BLOCK_CONFIG, block_error, one_line, value_reason
from im_common.yamlio import load_parameters_file, read_yaml_file
from im_controller.baselines.drive import check_law_task, gains_model, LAWS
from im_controller.control_law import ControllerConfig, MODES, steady_start, THESIS_LAW_GAINS
from im_controller.flux import LOSS_SCOPES, Strategy
from im_controller.profiles import (from_setpoints, KINDS, load_profile, MODE_KIND, Profile,
                                    ProfileBlock)
from im_controller.trajectories import THESIS_TRAJECTORIES
from im_observer.speed_observer import POSITION_NEEDS_SENSOR
from im_plant.parameters import STEPPING_MODES   # the plant's stepping modes (one home)
from im_plant.sensors import Sensors
import numpy as np
from pydantic import BaseModel, Field, ValidationError
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
    p = TASK_PRESETS[task]             # the fields it sets; the others at the model's defaults
    return make_load(p['load'], **{k[len('load_'):]: v for k, v in p.items()
                                   if k.startswith('load_')})


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


# The run file's typed model --------------------------------------------------------------------
# Its keys, their types, bounds and choices, composed of the blocks' own models (Inverter,
# Sensors, SaturationBlock, Thermal, the baselines' gains): the one declaration the run file is
# read through (Scenario.from_mapping, and Scenario's own fields: _check_fields) and its JSON
# Schema is generated from (im_bringup.schemas, share/im_bringup/schema/run.schema.json). The
# rules across keys (a torque task needs a profile, ...) stay in Scenario.
class Noise(BaseModel):
    """The ``noise:`` block: Gaussian measurement noise of the ideal sensors."""

    model_config = BLOCK_CONFIG

    current: float = Field(0.0, ge=0, description='std of the current measurement noise [A]')
    speed: float = Field(0.0, ge=0, description='std of the speed measurement noise [rad/s]')
    seed: int = Field(0, ge=0, description='seed of the noise generator')


_Pair = Annotated[List[float], Field(min_length=2, max_length=2)]


class SaturationTable(BaseModel):
    """A magnetizing curve as points ``{table: [[psi, i_M], ...]}`` (what commissioning writes)."""

    model_config = BLOCK_CONFIG

    table: List[Annotated[List[Annotated[float, Field(gt=0)]],
                          Field(min_length=2, max_length=2)]] = Field(
        min_length=2, description='points [psi [Wb], i_M [A]] past the origin, both rising '
        '(docs/plant.md)')


_FILE = 'a file (relative to the run file)'
_Matrix22 = Annotated[List[_Pair], Field(min_length=2, max_length=2)]
_Matrix42 = Annotated[List[_Pair], Field(min_length=4, max_length=4)]
_NodeValues = Dict[Literal[NODES], Dict[str, Any]]
_Curve = Union[SaturationBlock, SaturationTable]


def _left_out(text: str) -> dict:
    """Return a field's ``json_schema_extra``: what a key left out means (docs/running.md)."""
    return {'left_out': text}


def _limit(what: str, left_out: str = "the motor's rating (none without one)"):
    return Field(None, ge=0, description=f'{what} (0: none; docs/limits.md)',
                 json_schema_extra=_left_out(left_out))


class RunFile(BaseModel):
    """
    A run file (docs/running.md): every key optional, left out = its default.

    Motor, estimates, load, profile, gains and parameters take a file path or the mapping inline.
    A key that takes null (left out) is typed Optional; the others refuse it. The descriptions
    are the run file's documentation: docs/running.md's table of keys is generated from them.
    """

    model_config = dict(BLOCK_CONFIG, title='IM drive run file')

    task: Literal[TASKS] = Field(None, description='what the drive tracks: `position`, `speed` '
                                 'or `torque` (torque needs a `profile`)')
    strategy: Strategy = Field(None, description='the flux strategy: `min_energy`, '
                               '`constant_flux`, `min_loss`, `optimal` (docs/strategies.md)')
    controller: Literal[CONTROLLERS] = Field(
        None, description='`nominal`, `adaptive` (improved law), `adaptive_thesis`, '
        "`adaptive_thesis_pair`, `robust`; or a drive industry's law in the thesis law's place: "
        '`current_vector`, `flux_vector`, `vhz` (speed only; docs/baselines.md)')
    baseline: Optional[Dict[str, float]] = Field(
        None, description="the baseline law's gains: `current_vector` `{alpha_c, alpha_i, "
        'alpha_s, alpha_p, k_comp, feedforward}`, `flux_vector` `{alpha_psi, alpha_tau, '
        'alpha_i, alpha_s, alpha_p, k_comp, k_u, k_b, feedforward}`, `vhz` `{alpha_psi, '
        'alpha_tau, alpha_f, alpha_i, slew_rate, k_comp, k_u, k_b}` (docs/baselines.md, '
        'docs/parameters.md)', json_schema_extra=_left_out("the law's defaults"))
    T_s: float = Field(None, gt=0, description='control period [s]')
    duration: Optional[float] = Field(None, gt=0, description='simulated seconds',
                                      json_schema_extra=_left_out(
                                          "the task's (2.0 / 1.5 / 1.0 s); a profile's end "
                                          '+ 1 s'))
    motor: Optional[Union[str, MotorFields]] = Field(
        None, description="the plant's motor: a motor file path, a shipped motor by name "
        '(`thesis`, `krause_3hp`, `krause_50hp`: share/im_common/config/motors/; a file of that '
        'name beside the run file wins), or an inline mapping of its fields',
        json_schema_extra=_left_out('the thesis motor'))
    estimates: Optional[Union[str, MotorEstimates]] = Field(
        None, description="the controller's, observer's and adapter's model: a motor file, or a "
        'mapping of values over `motor` (e.g. `{R_r: 0.9}`)',
        json_schema_extra=_left_out('= `motor`'))
    load: Optional[Union[str, LoadBlock]] = Field(
        None, description='a load file or `{kind: ' + '|'.join(LOAD_KINDS) + ', ...}` '
        '("Loads" below)', json_schema_extra=_left_out("the task's load"))
    profile: Optional[Union[str, ProfileBlock, Dict[str, Any]]] = Field(
        None, description='setpoints: a file (YAML/CSV) or `{setpoints: [{t: 0.0, velocity: '
        '100.0}, ...]}`; a run record writes the thesis profile as `{kind: '
        'thesis_position|thesis_speed, ...}` with its parameters (fixed)',
        json_schema_extra=_left_out('the thesis profile'))
    v_limit: Optional[float] = _limit('inverter voltage-vector limit [V], plant and controller')
    torque_limit: Optional[float] = _limit('controller torque limit [N m]', 'none')
    current_limit: Optional[float] = _limit('controller current limit [A]')
    speed_limit: Optional[float] = _limit('controller speed limit [rad/s]', 'none')
    current_trip: Optional[float] = _limit('plant protection: overcurrent trip [A]')
    speed_trip: Optional[float] = _limit('plant protection: overspeed trip [rad/s]')
    inverter_rating: Optional[float] = Field(None, gt=0, description="the inverter's own limit "
                                             '[V]; a larger command trips the plant',
                                             json_schema_extra=_left_out('1000 V'))
    sensorless: bool = Field(None, description='controller, observer and adapter use the '
                             "observer's speed (docs/sensorless.md)")
    gains: Optional[Union[str, _NodeValues]] = Field(
        None, description='`design_gains` output: a file or `{controller: {...}, observer: '
        '{...}}`; its `gain_period` must equal `T_s`', json_schema_extra=_left_out("the thesis's"))
    mode: Literal[STEPPING_MODES] = Field(None, description="the plant's stepping on the graph: "
                                          '`lockstep` or `free_run`')
    variation: Union[Literal[tuple(SCHEDULES)],
                     Dict[Literal[ELECTRICAL_NAMES], List[Dict[str, Any]]]] = Field(
        None, description="the true motor's parameters in time: a name (`none`, `chapter4`) or "
        'breakpoints `{parameter: [{t, scale|value, shape}, {sine, frequency, phase}]}` '
        '(below)')
    noise: Noise = Field(None, description='`{current: sigma_i [A], speed: sigma_w [rad/s], '
                         'seed: n}`: Gaussian measurement noise of the ideal sensors',
                         json_schema_extra=_left_out('off'))
    parameters: Optional[Union[str, _NodeValues]] = Field(
        None, description='extra node parameters `{plant|controller|observer|adapter: '
        '{name: value}}` (or a ROS 2 parameters file), merged last; graph runs only',
        json_schema_extra=_left_out('none'))
    inverter: Optional[Inverter] = Field(
        None, description='the switched inverter `{V_dc, pwm_frequency, deadtime, update, v_on, '
        'r_on, e_sw, v_sw, i_sw, C_dc, R_source, V_chopper, R_chopper, V_trip}` (docs/plant.md; '
        '`e_sw` at `v_sw`, `i_sw`: the switching losses, §1), and `delay`: the computational '
        'delay in control periods, 0-2 (`{delay: 1}` alone: the ideal voltage source one period '
        'late; docs/plant.md §10)', json_schema_extra=_left_out('the ideal voltage source'))
    sensors: Optional[Sensors] = Field(
        None, description='`{encoder_lines, speed_window, adc_bits, current_range, '
        'current_offset, current_gain, vdc_range}` (docs/plant.md)',
        json_schema_extra=_left_out('the true state'))
    saturation: Optional[Union[Literal['motor'], _Curve]] = Field(
        None, description="the plant's magnetizing curve: `{law: power, beta, S}`, `{table: "
        "[[psi, i_M], ...]}`, or `motor` for the motor file's own block (docs/plant.md §2)",
        json_schema_extra=_left_out('none (linear)'))
    thermal: Optional[Union[Literal['motor'], Thermal]] = Field(
        None, description="the motor's winding temperatures: a block, or `motor` for the motor "
        "file's own (docs/plant.md); the adapter gets it too, for its `thermal_tracking` "
        '(docs/adaptation.md §9)', json_schema_extra=_left_out('none'))
    iron_loss: bool = Field(None, description='the core loss acts (an iron-loss branch '
                            'dissipating the k_e, k_h loss; docs/plant.md)')
    loss_scope: Literal[LOSS_SCOPES] = Field(
        None, description="what `min_loss` and `optimal`'s causal target minimize: `motor` (the "
        "motor's losses) or `drive` (the inverter's conduction and switching losses added, from "
        'the `inverter` block; docs/efficiency.md)')
    compensation: Optional[Union[bool, Literal['inverter'], CompensationBlock]] = Field(
        None, description="the drive's inverter-error compensation: `inverter` (exact, from the "
        '`inverter` block) or `{v_dead, r_on, current_band}` as commissioned '
        '(docs/compensation.md)', json_schema_extra=_left_out('off'))
    saturation_model: Union[bool, _Curve] = Field(
        None, description="the drive's observer and controller on a magnetizing curve: `true`, "
        "the plant's `saturation`; or a curve of the drive's own, `{table: [[psi, i_M], ...]}` "
        "(a commissioned file's block) or `{law: power, beta, S}`, while the plant keeps "
        '`saturation` (docs/plant.md §2)')
    start: Optional[Literal[START_MODES]] = Field(
        None, description="`rest` (demagnetized) or `steady` (the controller's steady state at "
        '`theta0`, `omega0`)', json_schema_extra=_left_out("the task's"))
    theta0: Optional[float] = Field(None, description='initial shaft position [rad]',
                                    json_schema_extra=_left_out("the task's"))
    omega0: Optional[float] = Field(None, description='initial shaft speed [rad/s]',
                                    json_schema_extra=_left_out("the task's"))
    start_flux: float = Field(None, gt=0, description="a steady start with the plant's rotor "
                              "flux this factor times the controller's steady state (a model "
                              "whose steady state is not exactly the motor's; "
                              'docs/adaptation.md §6)')
    current_gain: Optional[_Matrix22] = Field(None, description='current-loop gain, 2x2 rows',
                                              json_schema_extra=_left_out("the thesis's"))
    observer_gain: Optional[_Matrix42] = Field(None, description='observer injection gain, '
                                               '4x2 rows',
                                               json_schema_extra=_left_out("the thesis's"))
    k_e: Optional[float] = Field(None, gt=0, description='observer current-error injection gain',
                                 json_schema_extra=_left_out('1/sigma'))
    core_loss_exponent: float = Field(None, gt=0, description='the core loss grows as |psi|^m')
    plant_substep: float = Field(None, gt=0, description='longest RK4 sub-step of the ideal '
                                 'plant [s]')
    observer_substep: float = Field(None, gt=0, description='longest RK4 sub-step of the '
                                    'observer [s]')
    controller_options: Dict[str, Any] = Field(
        None, description="the thesis law's limits and options (docs/limits.md); the ROS-free "
        'loop and Python', json_schema_extra=_left_out('none'))
    speed_observer_options: Dict[str, Any] = Field(
        None, description="the sensorless speed observer's options (docs/sensorless.md); the "
        'ROS-free loop and Python', json_schema_extra=_left_out('none'))


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
        # every key's type, bound and choice: the run file's model (the task at once: its
        # presets are read below)
        self._check_fields()
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
        if isinstance(self.variation, Mapping):
            put(self, 'variation', normalize_variation(self.variation) or 'none')
        elif self.schedule is None and self.variation not in SCHEDULES:
            raise InvalidParameter('variation', self.variation,
                                   f'must be one of {", ".join(SCHEDULES)} or a mapping '
                                   '{parameter: [breakpoints]}')
        if self.sensorless and self.task == 'position':
            raise InvalidParameter('sensorless', True, POSITION_NEEDS_SENSOR)
        if self.task == 'torque' and self.profile is None:
            raise InvalidParameter('profile', None, TORQUE_NEEDS_PROFILE)
        if self.profile is not None and self.profile.mode != self.task:
            raise InvalidParameter('profile', self.profile.source,
                                   f'is a {self.profile.mode} profile; the task is {self.task}')
        if self.duration is None:
            put(self, 'duration', DEFAULT_DURATION[self.task] if self.profile is None
                else self.profile.end_time + 1.0)
        preset = TASK_PRESETS[self.task]
        if self.start is None:
            put(self, 'start', preset['start'])
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

    def _check_fields(self) -> None:
        """
        Refuse a field of a type, bound or choice the run file's model refuses (one line).

        The fields a run file gives as they are (plain values; motor, load, profile and the
        blocks are checked by their own models when they are read).
        """
        values = {k: getattr(self, k) for k in _PLAIN_FIELDS}
        values['noise'] = {k: getattr(self, f) for k, f in NOISE_KEYS.items()}
        values = json.loads(json.dumps(values, default=_plain))     # as a run file writes them
        try:
            RunFile.model_validate(values)
        except ValidationError as exc:
            errors = exc.errors()
            inside = [e for e in errors if _nested(e['loc'])]
            raise (_nested_error(inside[0]) if inside else _key_error(errors, values)) from None

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
        self._refuse_loop_only()
        common = {'T_s': float(self.T_s), 'duration': float(self.duration),
                  'input_timeout': float(input_timeout)}
        v_limit = limit_parameter(self.v_limit)
        model_values = self._model_values()
        plant = self._plant_parameters(common, v_limit, truth_decimation)
        x0 = obs_x0 = None
        if self.start == 'steady':
            x0, obs_x0 = self.initial_state()
        if x0 is not None:          # plant and observer start in the controller's steady state
            plant['initial_current'] = [float(obs_x0[0]), float(obs_x0[1])]
            plant['initial_flux'] = [float(x0[2]), float(x0[3])]
        ctl = self._controller_parameters(common, v_limit, model_values, reference_decimation)
        obs = self._observer_parameters(common, model_values, obs_x0 if x0 is not None else None)
        adapter = self._adapter_parameters(common, model_values, plant)
        self._add_shared_parameters(ctl, obs, adapter)
        out = {'plant': plant, 'controller': ctl, 'observer': obs, 'adapter': adapter}
        for extra in (self.gains, self.parameters):     # merged last
            for node, values in (extra or {}).items():
                out[node].update(values)
        return out

    def _refuse_loop_only(self) -> None:
        """Refuse what only the ROS-free loop takes (a schedule object, controller options)."""
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

    def _model_values(self) -> dict:
        """Return the drive's model parameters (controller, observer, adapter): the estimates."""
        if self.estimates is not None:
            return motor_parameters(self.estimates)
        model_values = motor_parameters(self.motor) if self.motor is not None else {}
        if self.variation == 'chapter4':
            model_values.update({k: getattr(CHAPTER4_ESTIMATES, k)
                                 for k in ('R_s', 'R_r', 'L_s', 'L_r', 'L_sr')})
        return model_values

    def _plant_parameters(self, common: dict, v_limit: float, truth_decimation: int) -> dict:
        """Return the plant's parameters (without the steady start's initial state)."""
        protection = {k: getattr(self, k) for k in PLANT_PROTECTION
                      if getattr(self, k) is not None}
        lp = load_parameters(self.plant_load())
        mine = motor_parameters(self.motor) if self.motor is not None else {}
        if isinstance(self.variation, dict):    # variation.<parameter>.* (breakpoints, sines)
            variation = {'variation': 'schedule',
                         **variation_parameters(variation_block(self.variation))}
        else:
            variation = {'variation': self.variation}
        plant = dict(common, **variation, v_limit=v_limit, truth_decimation=int(truth_decimation),
                     **mine, **lp, theta0=float(self.theta0), omega0=float(self.omega0))
        plant.update({k: float(v) for k, v in protection.items()})
        plant.update(self._real_plant_parameters())
        if self.current_noise_std or self.speed_noise_std:
            plant.update(current_noise_std=float(self.current_noise_std),
                         speed_noise_std=float(self.speed_noise_std),
                         noise_seed=int(self.noise_seed))
        if self.mode != 'lockstep':
            plant['mode'] = self.mode
        return plant

    def _real_plant_parameters(self) -> dict:
        """Return the plant's parameters of the real plant's blocks (docs/plant.md)."""
        plant: dict = {}
        for key, value in self.plant_blocks().items():
            if key in TYPED_BLOCKS:         # inverter.enabled, inverter.<field>, ...
                plant.update(block_parameters(value, key))
            elif key == 'iron_loss':
                plant[key] = value
            else:                           # the motor's blocks: saturation.*, thermal.*
                block = saturation_block(value) if key == 'saturation' \
                    else thermal_from_dict(value)
                plant.update(block_parameters(block, key))
        return plant

    def _controller_parameters(self, common: dict, v_limit: float, model_values: dict,
                               reference_decimation: int) -> dict:
        """Return the controller's parameters (without the shared additions)."""
        limits = self.limits()
        lp_model = load_parameters(self.plant_load().feedforward())     # the controller's
        ctl = dict(common, mode=self.task, strategy=self.strategy,
                   use_adapter=self.controller in ADAPTATION, v_limit=v_limit,
                   reference_decimation=int(reference_decimation), load_known=True, **lp_model,
                   **model_values)
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
        return ctl

    def _observer_parameters(self, common: dict, model_values: dict, x0) -> dict:
        """Return the observer's parameters; ``x0``: its steady start (None: at rest)."""
        obs = dict(common, use_adapter=self.controller in ADAPTATION, **model_values)
        if x0 is not None:
            obs['initial_state'] = [float(v) for v in x0]
        if self.observer_gain is not None:
            obs['injection_gain'] = [float(g) for g in _flat(self.observer_gain)]
            obs['gain_period'] = float(self.T_s)
        if self.k_e is not None:
            obs['k_e_injection'] = float(self.k_e)
        return obs

    def _adapter_parameters(self, common: dict, model_values: dict, plant: dict) -> dict:
        """Return the adapter's parameters (without the shared additions and its law)."""
        adapter = dict(common, enable=self.controller in ADAPTATION, **model_values)
        # the motor's networks, thermal.*: the adapter's thermal_tracking takes them
        adapter.update({k: v for k, v in plant.items() if k.startswith('thermal.')})  # §9
        return adapter

    def _add_shared_parameters(self, ctl: dict, obs: dict, adapter: dict) -> None:
        """Add what the drive's nodes share: sensorless, adaptation, curve, delay, compensation."""
        # controller, observer, adapter: the observer's ω̂ replaces the shaft
        if self.sensorless:
            ctl['sensorless'] = obs['sensorless'] = adapter['sensorless'] = True
            obs['initial_speed'] = float(self.omega0) if self.start == 'steady' else 0.0
        if self.controller in ADAPTATION:
            adapter.update(ADAPTATION[self.controller])
        if self.saturation_model:   # the drive's observer and controller on the curve
            curve = block_parameters(saturation_block(self.drive_curve()), 'saturation_model')
            ctl.update(curve)
            obs.update(curve)
        if self.delay:              # the controller predicts across it; observer and adapter
            ctl['delay'] = obs['delay'] = adapter['delay'] = self.delay     # take what acts
        r_inv, c_inv = self.drive_loss()
        if r_inv or c_inv:          # loss_scope drive: the strategies add the inverter's losses
            ctl.update(drive_loss_r=float(r_inv), drive_loss_c=float(c_inv))
        comp = self.compensation_model()
        if comp is not None:        # the controller adds ê(i); observer and adapter subtract it
            for node in (ctl, obs, adapter):
                node.update(comp.parameters())

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
            refused = _refused_by_model(doc)
            run = cls(**_fields_from_mapping(doc, base_dir, source))
            if refused is not None:     # what the blocks' own parsers took: the model decides
                raise refused
            return run
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
    """Every key a run file may hold: the run file's model's (:class:`RunFile`)."""
    return tuple(RunFile.model_fields)


def _fields_from_mapping(doc: dict, base_dir: Optional[str], source: str = 'run file') -> dict:
    kw = {}
    inline_blocks = {}

    def path(value):
        return value if base_dir is None or os.path.isabs(value) else os.path.join(base_dir, value)

    for key, value in doc.items():      # the keys, their types and bounds: RunFile's, checked
        if value is None:               # left out, as a key not written
            continue
        if key == 'noise':
            kw.update({NOISE_KEYS[k]: v for k, v in value.items()})
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


#: the Scenario fields a run file gives under their own name as plain values (checked by the
#: run file's model, :meth:`Scenario._check_fields`)
_PLAIN_FIELDS = ('task', 'strategy', 'controller', 'T_s', 'duration', 'start', 'theta0',
                 'omega0', 'start_flux', 'inverter_rating', 'sensorless', 'current_gain',
                 'observer_gain', 'k_e', 'controller_options', 'speed_observer_options',
                 'core_loss_exponent', 'plant_substep', 'observer_substep', 'mode', 'iron_loss',
                 'loss_scope') + ZERO_IS_NONE


#: a location's parts that name a member of a union, not a key (pydantic's "str",
#: "literal['motor']", a model's name)
_UNION_TAGS = ('str', 'bool', 'int', 'float', 'list', 'dict')


@functools.lru_cache(maxsize=1)
def _model_names() -> frozenset:
    """Return the names of the models the run file's is composed of (a union's member tags)."""
    return frozenset(RunFile.model_json_schema().get('$defs', {}))


def _key_path(loc) -> str:
    """Return the run-file key path of a pydantic error location (``inverter.deadtime``)."""
    out = ''
    for part in loc:
        if isinstance(part, int):
            out += f'[{part}]'
        elif part in _UNION_TAGS or '[' in part or part in _model_names():
            continue
        else:
            out += f'.{part}' if out else part
    return out


def _refused_by_model(doc: dict) -> Optional[InvalidParameter]:
    """
    Check a run file's mapping against :class:`RunFile`; raise a key's own error at once.

    Valid, the typed blocks (:data:`TYPED_BLOCKS`) in ``doc`` are replaced by their models, which
    the Scenario takes as they are: the inverter block is parsed once.

    An error inside a value another parser reads (:data:`_READ_BY_THEIR_OWN`: a motor, a
    variation, ...) is returned (None: none): that parser names it more closely when the value is
    read, and the caller raises this one if it did not.
    """
    try:
        model = RunFile.model_validate(doc)
    except ValidationError as exc:
        errors = exc.errors()
        # a value of the right kind with an error inside (a union's other kinds refuse it too)
        nested = [e for e in errors if _nested(e['loc']) or (
            e['type'] == 'value_error' and e['loc'][0] in _READ_BY_THEIR_OWN)]
        inside = {e['loc'][0] for e in nested}
        own = [e for e in errors if e['loc'][0] not in inside]
        if own:
            raise _key_error(own, doc) from None
        mine = [e for e in nested if e['loc'][0] not in _READ_BY_THEIR_OWN]
        if mine:
            raise _nested_error(mine[0]) from None
        return _nested_error(nested[0])
    for key in TYPED_BLOCKS:            # parsed once: the Scenario takes the model's
        if doc.get(key) is not None:
            doc[key] = getattr(model, key)
    return None


#: run-file keys whose values a parser of their own reads (the file, the block, the schedule)
_READ_BY_THEIR_OWN = ('motor', 'estimates', 'load', 'profile', 'gains', 'parameters',
                      'variation', 'inverter', 'sensors', 'saturation', 'thermal',
                      'saturation_model', 'compensation', 'baseline')
_KINDS = {str: 'a file (a string)', bool: 'true or false', dict: 'a mapping', list: 'a list',
          float: 'a real number', int: 'a whole number'}


def _kinds(annotation) -> str:
    """Say what a union of kinds a run-file key takes is (``a file (a string) or a mapping``)."""
    out = []
    for a in get_args(annotation):
        if a is type(None):
            continue
        if get_origin(a) is Literal:
            out.append(' or '.join(map(str, get_args(a))))
        elif get_origin(a) is Union:
            out.append(_kinds(a))
        else:
            base = get_origin(a) or a
            out.append(_KINDS.get(base, 'a mapping'))
    return ' or '.join(dict.fromkeys(out))


def _nested(loc) -> bool:
    """Tell whether a pydantic error location is inside a key's value (``inverter.delay``)."""
    path = _key_path(loc)
    return '.' in path or '[' in path


def _key_error(errors, doc: dict) -> InvalidParameter:
    """Return the error of a run-file key itself (unknown, of a wrong kind, out of bounds)."""
    union = [e for e in errors if len(e['loc']) > 1]
    err = block_error(RunFile, doc, '', [e for e in errors if len(e['loc']) == 1] or errors)
    if err.reason.startswith('unknown key'):
        near = difflib.get_close_matches(str(err.name), run_keys(), n=1)
        return InvalidParameter(err.name, err.value, 'unknown run-file key; did you mean '
                                f"'{near[0]}'?" if near else 'unknown run-file key (see '
                                'docs/running.md)')
    if union and not any(len(e['loc']) == 1 for e in errors):
        key = union[0]['loc'][0]
        return InvalidParameter(key, doc.get(key), 'must be '
                                + _kinds(RunFile.model_fields[key].annotation))
    return err


def _nested_error(err) -> InvalidParameter:
    """Return the error inside a run-file key's value, named by its key path."""
    kind, ctx = err['type'], err.get('ctx') or {}
    rule = ctx.get('error')
    if kind == 'value_error' and isinstance(rule, InvalidParameter):    # a block's own rule
        path = _key_path(err['loc'])
        return InvalidParameter(f'{path}.{rule.name}' if rule.name else path, rule.value,
                                rule.reason)
    reason = {'extra_forbidden': 'unknown key', 'missing': 'is missing'}.get(kind) \
        or value_reason(err)
    return InvalidParameter(_key_path(err['loc']), None if kind == 'missing'
                            else err.get('input'), reason)


__all__ = ['Scenario', 'RunFileError', 'run_keys', 'KINDS']
