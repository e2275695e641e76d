"""
Torque-tracking drive controller with flux strategies.

Seed 000 §3.2-3.3, eq. 3.1, 3.13, 3.25-3.31; §4.2, eq. 4.10-4.14 with adapted estimates.

One call of :meth:`DriveController.compute` per control period t_k:

1. Mechanical loop (eq. 3.1): τ* = J θ̈* + b θ̇* + τ_c(θ, ω) − k_v(ω − ω*) − k_p(θ − θ*).
   The feedforward part and the load model are differentiated analytically (trajectory jerk,
   ∂τ_c/∂θ · ω); the PD part passes through a critically damped 2nd-order filter whose states are
   its value and derivative. So dτ*/dt is known without numerical differentiation.
2. Flux strategy → target flux → 2nd-order filter → (φ*, dφ*/dt, d²φ*/dt²) (:mod:`.flux`).
3. Reference model (eq. 3.13 in flux form, :mod:`.reference`) → dq currents, electrical slip ω_sl;
   field angle ρ integrated (trapezoid over the samples) from dρ/dt = v ω_r + ω_sl with the
   *measured* speed (indirect field orientation); αβ reference by eq. 3.26.
4. Voltage: V = V* + ΔV. V* = eq. 3.29 (exact inverse of the stator equation at the measured
   speed), rotated to the middle of the hold interval [t_k, t_k + T_s] when ``hold_compensation``
   (the voltage is held for a period; a rotating vector sampled at t_k lags by T_s/2).
   ΔV = −K₁ (i − i*) + v ω_r θ 𝒥 (φ̂ − φ*)   (eq. 3.30 with measured currents, observed fluxes).
   Sign convention: ΔV = −K₁(i − i*) with K₁ = k₁ I > 0 (the thesis's "k₁ = −40" is this gain
   with the sign of ΔV = K(x̂ − x*)). The flux term cancels the non-skew speed coupling of the
   stator equation, so with exact fluxes ½eᵀDe decreases along the tracking error
   (docs/controller.md); ``flux_coupling='thesis'`` uses the printed K₂ = −(vL_sr/2L_r) ω_r* 𝒥
   in ΔV = K₂(φ̂ − φ*) instead, ``'none'`` drops it.
5. Limits (docs/limits.md): τ* clamped to the torque limit and to the torque the current limit
   allows at the present flux; no torque pushing further beyond the speed limit; the flux target
   capped above base speed so the steady voltage fits the voltage limit (field weakening); the
   voltage vector scaled into the limit with an anti-windup that cannot latch: no controller state
   is ever frozen, and the one integrator (the speed task's θ* = ∫ω*) is back-calculated to the
   shaft while the voltage is limited.

Everything per call is scalar Python.
"""
from __future__ import annotations

import bisect
import copy
import math
from types import SimpleNamespace
from typing import Any, List, Literal, Optional, Tuple

from im_common.compensation import InverterErrorModel
from im_common.delay import MAX_DELAY
from im_common.loads import LOAD_DEFAULTS, make_load, MODEL_KINDS
from im_common.model import stator_flux
from im_common.params import (check_real, estimate_arguments, InvalidParameter, MotorParams, RATED,
                              resolve_rated, THESIS_FLUX_LEVELS, THESIS_MOTOR)
from im_common.validation import BLOCK_CONFIG, block_error, parameter_spec as _node
import numpy as np
from pydantic import BaseModel, Field, field_validator, model_validator, ValidationError

from .baselines.drive import BaselineDrive, check_law_task, gains_model, LAWS
from .flux import FluxStrategy, LOSS_OPTIMAL, LowPass2, Strategy
from .flux_plan import (curve_shape, plan_flux, PLAN_STEP, PlanError, saturation_terms,
                        static_loss_optimal_flux)
from .reference import dq_reference, feedforward_dq, ModelCoefficients, steady_state
from .trajectories import SetpointPosition, SetpointSpeed, SetpointTorque, THESIS_TRAJECTORIES

#: the tasks' names, their one home (the run file's ``task``); :data:`Mode` is their type
MODES = ('position', 'speed', 'torque')
Mode = Literal[MODES]
#: the tasks of the thesis's tables (torque is ours)
THESIS_TASKS = ('position', 'speed')
PROFILES = ('thesis', 'setpoint')
Profile = Literal[PROFILES]
FLUX_COUPLINGS = ('cancel', 'thesis', 'none')
FluxCoupling = Literal[FLUX_COUPLINGS]
Law = Literal[LAWS]
#: the controller's load models (their home: im_common.loads)
LoadKind = Literal[MODEL_KINDS]
DEFAULT_FLUX_PREVIEW = 0.06
# Field weakening keeps the steady stator voltage ω_e (L_s/L_sr) φ below this share of the voltage
# limit; the rest is headroom for the resistive drop, the q-axis leakage drop and the transients.
DEFAULT_VOLTAGE_MARGIN = 0.85
# Under a current limit the optimizing strategies choose no flux whose steady current for the
# demanded torque exceeds this share of the limit; the rest is headroom for the flux rise
# (T_r dφ*/dt on the d axis) and the PD correction (docs/limits.md).
DEFAULT_CURRENT_MARGIN = 0.9
# Fields whose default RATED takes the motor model's rating (im_common.params.default_limits),
# and their value for a motor without that rating (the thesis's; ``from_ratings`` says which).
RATED_FIELDS = {'v_limit': None, 'current_limit': None, **THESIS_FLUX_LEVELS}
# |i_q*| ≤ MAGNETIZING_RATIO · i_d*/√σ: the torque a partly magnetized machine is asked for
MAGNETIZING_RATIO = 2.0
#: the thesis law's own gains: a baseline law (docs/baselines.md) takes its gains from its
#: ``baseline`` block and refuses these
THESIS_LAW_GAINS = ('k1', 'k_p', 'k_v', 'current_gain', 'flux_coupling')
# Reconfigurable while running (ros2 param set on the controller node): gains, strategy, flux
# levels and limits. Everything else (mode, profile, motor model, period) is fixed for a run.
LIVE_FIELDS = ('strategy', 'phi_d', 'phi_min', 'phi_max', 'k1', 'k_p', 'k_v', 'current_gain',
               'flux_coupling', 'v_limit', 'torque_limit', 'current_limit', 'speed_limit',
               'field_weakening', 'voltage_margin', 'current_margin', 'flux_preview',
               'setpoint_duration')

# §3.4.6, decoded: the printed table is three columns (electrical gains | position | speed) read
# row by row: k1, k_e on the electrical side; position k_p = 10, k_v = 1; speed k_p = 1, k_v = 3.
DEFAULT_GAINS = {'position': (10.0, 1.0), 'speed': (1.0, 3.0), 'torque': (0.0, 0.0)}
DEFAULT_LOADS = {'position': 'pendulum', 'speed': 'linear', 'torque': 'none'}


_real = check_real

#: the model's configuration: a bool or a string is no number, a number is finite, no field it
#: does not know; not frozen, as the dataclass it replaces was not: its last validator fills in
#: the defaults that depend on other fields. Nothing else assigns to a field: a change is a new
#: configuration (:meth:`ControllerConfig.replace`), validated as a whole
_CONFIG = {**BLOCK_CONFIG, 'frozen': False, 'arbitrary_types_allowed': True}


#: the field is no parameter of the controller node (the node sets it itself, or has none)
_NOT_A_PARAMETER = {'parameter': None}
_PER_MODE = (-1.0, None, 'per-mode default')
_NONE = (0.0, None, 'none')


def _rated(what: str):
    return (-1.0, RATED, what)


class ControllerConfig(BaseModel):
    """
    Configuration of :class:`DriveController` (SI units; each field's meaning in its Field).

    Validated on construction and as a whole on every change (:meth:`replace`,
    :meth:`DriveController.reconfigure`); every error is one :class:`InvalidParameter` line
    naming the field (:func:`im_common.validation.block_error`). After validation every default
    is resolved: the RATED fields (:data:`RATED_FIELDS`: v_limit, current_limit and the flux
    levels, RATED by default) hold the motor model's ratings (im_common.params.default_limits:
    phi_min 1/6 of the rated flux), else None or the thesis's 1.2, 0.2, 1.2 Wb
    (``from_ratings`` says which); k_p/k_v/load their task's, flux_preview its strategy's,
    magnetizing_floor 0.1 phi_min. Each field's ``json_schema_extra`` says how the controller
    node declares it (:func:`_node`; im_controller.parameters).
    """

    model_config = _CONFIG

    mode: Mode = Field('position', description='tracking task',
                       json_schema_extra=_node())
    law: Law = Field('thesis', description="control law: the thesis's (seed 000 ch. 3-4), or a "
                     "drive industry's baseline in its place, current_vector (rotor-flux-oriented "
                     'PI current and speed loops), flux_vector (stator flux and torque controlled '
                     'directly) or vhz (observer-based V/Hz, speed only), with the same '
                     'references, flux strategy and limits (docs/baselines.md)',
                     json_schema_extra=_node())
    baseline: Any = Field(None, description="the baseline law's gains, its run-file baseline: "
                          'block (im_controller.baselines: BaselineGains, VHzGains; None: their '
                          'defaults); the node parameters baseline.*',
                          json_schema_extra=_NOT_A_PARAMETER)
    profile: Profile = Field(
        'thesis', description='reference source: the thesis trajectories (seed 000 §3.4.4) or '
        'setpoints (set_setpoint, /im/setpoint, the setpoints field) turned into smooth '
        'references',
        json_schema_extra=_node())
    strategy: Strategy = Field(
        'min_energy', description='flux strategy: min_energy (eq. 3.19/3.25), constant_flux '
        '(phi_d), min_loss, or optimal (the loss-optimal flux trajectory planned over a reference '
        'known ahead, docs/controller.md section 10; else min_loss, and plan_note says so)',
        json_schema_extra=_node())
    phi_d: float = Field(RATED, gt=0, description='constant-flux level [Wb]',
                         json_schema_extra=_node(-1.0, -1.0, 10.0, [_rated(
                             "the motor's rated flux, else the thesis's 1.2")]))
    phi_min: float = Field(RATED, gt=0, description='lower flux bound of min_energy / min_loss '
                           '[Wb] (section 3.4.6)', json_schema_extra=_node(-1.0, -1.0, 10.0, [
                               _rated('1/6 of the rated flux, else 0.2')]))
    phi_max: float = Field(RATED, gt=0, description='upper flux bound (saturation) [Wb], >= '
                           'phi_min', json_schema_extra=_node(-1.0, -1.0, 10.0, [
                               _rated('the rated flux, else 1.2')]))
    k1: float = Field(40.0, gt=0, description='current feedback gain K1 = k1 I [V/A] (Delta V = '
                      '-K1 (i - i*); the thesis\'s "k1 = -40" with the sign of Delta V = K (x - '
                      'x*))', json_schema_extra=_node(lo=1e-6, hi=1e6))
    k_p: Optional[float] = Field(None, ge=0, description='PD position gain of eq. 3.1 [N m/rad], '
                                 '> 0 in position mode; per-mode default: position 10, speed 1, '
                                 'torque unused', json_schema_extra=_node(
                                     -1.0, -1.0, 1e6, [_PER_MODE]))
    k_v: Optional[float] = Field(None, ge=0, description='PD speed gain of eq. 3.1 [N m s/rad], '
                                 '> 0 in speed mode; per-mode default: position 1, speed 3, '
                                 'torque unused', json_schema_extra=_node(
                                     -1.0, -1.0, 1e6, [_PER_MODE]))
    load_known: bool = Field(True, description='feed the load model tau_c forward in eq. 3.1 '
                             '(else tau_c = 0)', json_schema_extra=_node())
    load: Optional[LoadKind] = Field(
        None, description='load model for tau_c (a function of the shaft state; a load in time '
        "is the plant's, docs/running.md); the per-mode default (position pendulum, speed "
        'linear, torque none) when not given', json_schema_extra=_node('pendulum'))
    # the load models' defaults: their one home, im_common.loads
    load_mgl: float = Field(LOAD_DEFAULTS['mgl'], description='pendulum load model m g l [N m] '
                            '(tau = mgl cos theta)', json_schema_extra=_node(lo=-1e4, hi=1e4))
    load_c1: float = Field(LOAD_DEFAULTS['c1'], description='linear load model c1 [N m] (tau = '
                           'c1 + c2 omega)', json_schema_extra=_node(lo=-1e4, hi=1e4))
    load_c2: float = Field(LOAD_DEFAULTS['c2'], description='linear load model c2 [N m s]',
                           json_schema_extra=_node(lo=-1e3, hi=1e3))
    load_tau: float = Field(LOAD_DEFAULTS['tau'], description='constant load model [N m]',
                            json_schema_extra=_node(lo=-1e4, hi=1e4))
    params: MotorParams = Field(default_factory=lambda: THESIS_MOTOR,
                                description="nominal motor parameters (the controller's "
                                'estimates)', json_schema_extra=_NOT_A_PARAMETER)
    v_limit: Optional[float] = Field(
        RATED, gt=0, description='voltage-vector limit with anti-windup [V]',
        json_schema_extra=_node(-1.0, -1.0, 1e5, [
            _NONE, _rated("the motor's rated voltage (line-to-line RMS), none without one")]))
    current_gain: Optional[List[List[float]]] = Field(
        None, description='full 2x2 current gain K1 (Delta V = -K1 (i - i*)), K1 + K1^T '
        'positive definite, overriding k1 I; the node parameter is row-major, from design_gains',
        json_schema_extra=_node([0.0], sentinels=[([0.0], None, 'k1 I')]))
    flux_coupling: FluxCoupling = Field(
        'cancel', description="flux term of the current feedback: 'cancel' (cancels the speed "
        "coupling, docs/controller.md section 5), 'thesis' (K2 of eq. 3.30) or 'none'",
        json_schema_extra=_node())
    T_s: float = Field(1e-4, gt=0, description='control period [s] (hold compensation and the '
                       'first step)', json_schema_extra=_NOT_A_PARAMETER)
    hold_compensation: bool = Field(True, description='rotate the feedforward to the middle of '
                                    'the hold interval', json_schema_extra=_node())
    delay: int = Field(0, ge=0, le=MAX_DELAY, description="the plant's computational delay "
                       "[control periods] (the run file's inverter.delay): the command acts "
                       'delay periods late, so the law predicts across them (docs/plant.md '
                       'section 10)', json_schema_extra=_node(lo=0, hi=MAX_DELAY))
    torque_filter_bandwidth: float = Field(
        1000.0, gt=0, description='bandwidth of the PD-part torque filter [rad/s] (critically '
        'damped)', json_schema_extra=_node(lo=1.0, hi=1e6))
    flux_time_constants: Optional[Tuple[float, float]] = Field(
        None, description='(tau1, tau2) [s] of the flux-reference filter; None: (T_r, 1 ms), the '
        "flux follows its target like the rotor's own response to a d-current step",
        json_schema_extra=_NOT_A_PARAMETER)
    core_loss_exponent: float = Field(
        2.0, description='flux exponent of the core-loss model min_loss minimizes (1 or 2)',
        json_schema_extra=_node(lo=1.0, hi=2.0))
    setpoint_duration: float = Field(
        0.5, gt=0, description='duration of the smooth (quintic) transition to a new setpoint '
        '[s] (torque: a tenth of it)', json_schema_extra=_node(lo=1e-3, hi=100.0))
    flux_preview: Optional[float] = Field(
        None, ge=0, description='look-ahead of the flux target [s]: the strategy sees tau* plus '
        'the change of the reference-path torque over this horizon (0: off; position/speed '
        'profiles only); strategy default: 0.06 s for min_loss and optimal (about 0.6 T_r, the '
        'sweep of docs/controller.md section 6), 0 for the thesis strategies',
        json_schema_extra=_node(-1.0, -1.0, 10.0, [(-1.0, None, 'strategy default')]))
    setpoints: tuple = Field(
        (), description="profile 'setpoint': setpoints the controller applies itself at their "
        't, (t [s], value, transition duration [s] or None: setpoint_duration); the node '
        'parameter is flat triples, duration 0: setpoint_duration (im_controller.profiles '
        'writes them from a profile file)',
        json_schema_extra=_node([0.0], sentinels=[([0.0], (), 'none')]))
    torque_limit: Optional[float] = Field(None, gt=0, description='bound on |tau*| [N m]',
                                          json_schema_extra=_node(0.0, 0.0, 1e7, [_NONE]))
    current_limit: Optional[float] = Field(
        RATED, gt=0, description='stator-current magnitude the torque demand may ask for [A], '
        'above the magnetizing current phi_max/L_sr', json_schema_extra=_node(-1.0, -1.0, 1e6, [
            _NONE, _rated("the motor's rated current (sqrt 3 x line RMS), none without one")]))
    speed_limit: Optional[float] = Field(
        None, gt=0, description='beyond this |omega_r| no torque pushes further [rad/s]',
        json_schema_extra=_node(0.0, 0.0, 1e5, [_NONE]))
    field_weakening: bool = Field(True, description='cap the flux above base speed so the steady '
                                  'voltage fits v_limit (needs v_limit)',
                                  json_schema_extra=_node())
    voltage_margin: float = Field(
        DEFAULT_VOLTAGE_MARGIN, gt=0, le=1, description='share of v_limit the steady voltage may '
        'use under field weakening', json_schema_extra=_node(lo=0.05, hi=1.0))
    current_margin: float = Field(
        DEFAULT_CURRENT_MARGIN, gt=0, le=1, description='share of current_limit the steady '
        'current of min_energy/min_loss may use (their flux moves into the range that fits, '
        'docs/limits.md)', json_schema_extra=_node(lo=0.05, hi=1.0))
    magnetizing_floor: Optional[float] = Field(
        None, gt=0, description='the smallest flux the reference model uses [Wb], <= phi_min (a '
        'smooth floor, C2: the start-up from a demagnetized machine needs no step); None: 0.1 '
        'phi_min', json_schema_extra=_NOT_A_PARAMETER)
    horizon: Optional[float] = Field(
        None, gt=0, description="the run's end on the controller's clock [s]: optimal plans up "
        'to it with the end flux free; None: open-ended (the plan ends on the steady '
        'loss-optimal flux of the final reference)', json_schema_extra=_NOT_A_PARAMETER)
    sensorless: bool = Field(
        False, description="the theta, omega given to compute are the observer's estimates: the "
        'field angle is the observed flux angle (direct field orientation, docs/sensorless.md '
        'section 4) instead of the integral of v omega + omega_sl, which drifts while the '
        'estimate lags', json_schema_extra=_NOT_A_PARAMETER)
    drive_loss_r: float = Field(
        0.0, ge=0, description="the inverter's loss r|i|^2 [ohm] the loss-optimizing strategies "
        "add to the motor's (the run file's loss_scope: drive; 0: the motor's losses alone; "
        'docs/efficiency.md)', json_schema_extra=_node())
    drive_loss_c: float = Field(
        0.0, ge=0, description="the inverter's loss c|i| [W/A] (on-state drops and switching) "
        "the loss-optimizing strategies add to the motor's (loss_scope: drive)",
        json_schema_extra=_node())
    compensation: Optional[InverterErrorModel] = Field(
        None, description="the inverter's voltage error (an InverterErrorModel) added to the "
        'command after the voltage limit, at the measured current (None: off; '
        'docs/compensation.md)', json_schema_extra=_NOT_A_PARAMETER)
    magnetizing: Any = Field(
        None, description="the motor's magnetizing curve (an im_common.saturation.Saturation, "
        "power law): optimal plans on it (docs/controller.md section 10); the drive's model "
        'follows it through the estimates (SaturatedModel, docs/plant.md section 2)',
        json_schema_extra=_NOT_A_PARAMETER)
    from_ratings: Optional[dict] = Field(
        None, description="{field: (value, why)} of the fields the motor model's ratings set "
        '(RATED_FIELDS)', json_schema_extra=_NOT_A_PARAMETER)

    def __init__(self, **values):
        """Validate ``values``; an error is one :class:`InvalidParameter` naming the field."""
        try:
            super().__init__(**values)
        except ValidationError as exc:
            raise block_error(type(self), values, '', exc.errors()) from None

    def fields(self) -> dict:
        """Return {field: value} of every field, as it is (no copy, no dump of the motor)."""
        return {name: getattr(self, name) for name in type(self).model_fields}

    def replace(self, **changes) -> 'ControllerConfig':
        """
        Return a copy with ``changes``, validated as a whole (``dataclasses.replace``'s role).

        The other fields keep their resolved values (a task's gains stay those of the task;
        ``from_ratings`` still names the ratings whose values are kept).
        """
        return type(self)(**dict(self.fields(), **changes))

    @model_validator(mode='before')
    @classmethod
    def _from_ratings(cls, values):
        """Resolve the RATED fields from the motor model's ratings (else their fallbacks)."""
        if not isinstance(values, dict):
            return values
        params = values.get('params', THESIS_MOTOR)
        if not isinstance(params, MotorParams):
            return values                   # refused by the params field
        owner = SimpleNamespace(**{k: values.get(k, RATED) for k in RATED_FIELDS})
        used = resolve_rated(owner, RATED_FIELDS, params, values.get('from_ratings'))
        return dict(values, **vars(owner), from_ratings=used)

    @field_validator('params', mode='before')
    @classmethod
    def _motor(cls, value):
        if not isinstance(value, MotorParams):
            raise ValueError('must be a MotorParams')
        return value

    @field_validator('current_gain', mode='before')
    @classmethod
    def _gain_matrix(cls, g):
        """Return a 2x2 K1 as rows of floats (a nested sequence, a numpy array)."""
        if g is None:
            return None
        try:
            rows = [[_number(x) for x in r] for r in g]
        except (TypeError, ValueError):
            raise ValueError('must be a 2x2 matrix of numbers') from None
        if len(rows) != 2 or any(len(r) != 2 for r in rows) or \
                not all(math.isfinite(x) for r in rows for x in r):
            raise ValueError('must be a 2x2 matrix of finite numbers')
        # ΔV = −K e: the symmetric part of K must be positive definite for the dissipation
        # argument (K + Kᵀ > 0).
        a, b2, c2, d = rows[0][0], rows[0][1], rows[1][0], rows[1][1]
        s12 = 0.5 * (b2 + c2)
        if not (a > 0 and a * d - s12 * s12 > 0):
            raise ValueError('K + K^T must be positive definite (Delta V = -K (i - i*))')
        return rows

    @field_validator('flux_time_constants', mode='before')
    @classmethod
    def _time_constants(cls, tc):
        if tc is None:
            return None
        try:
            tc = tuple(_number(x) for x in tc)
        except (TypeError, ValueError):
            raise ValueError('must be two time constants in seconds') from None
        if len(tc) != 2 or not all(math.isfinite(x) and x > 0 for x in tc):
            raise ValueError('must be two positive, finite time constants in seconds')
        return tc

    @field_validator('core_loss_exponent')
    @classmethod
    def _exponent(cls, m):
        if m not in (1.0, 2.0):
            raise ValueError('must be 1 or 2')
        return m

    @field_validator('setpoints', mode='before')
    @classmethod
    def _setpoint_rows(cls, rows):
        return tuple(rows) if isinstance(rows, (list, tuple)) else (() if rows is None else rows)

    @model_validator(mode='after')
    def _rules(self) -> 'ControllerConfig':
        """Apply the rules across fields and resolve the defaults that depend on other fields."""
        if self.mode == 'torque' and self.profile == 'thesis':
            raise InvalidParameter('profile', self.profile,
                                   'the thesis profiles are position/speed trajectories; '
                                   "mode 'torque' needs profile 'setpoint'")
        if self.law == 'thesis':
            if self.baseline is not None:
                raise InvalidParameter('baseline', self.baseline, 'the gains of a baseline law, '
                                       "but the law is the thesis's: choose one, or leave it out")
        else:
            check_law_task(self.law, self.mode)
            if self.baseline is not None:
                self.baseline = gains_model(self.law).from_block(self.baseline)
        if self.phi_max < self.phi_min:
            raise InvalidParameter('phi_max', self.phi_max,
                                   f'must be >= phi_min = {self.phi_min:g}')
        kp0, kv0 = DEFAULT_GAINS[self.mode]
        if self.k_p is None:
            self.k_p = kp0
        if self.k_v is None:
            self.k_v = kv0
        if self.mode == 'position' and self.k_p <= 0.0:
            raise InvalidParameter('k_p', self.k_p, 'must be > 0 in position mode')
        if self.mode == 'speed' and self.k_v <= 0.0:
            raise InvalidParameter('k_v', self.k_v, 'must be > 0 in speed mode')
        if self.load is None:
            self.load = DEFAULT_LOADS[self.mode]
        if self.flux_preview is None:
            self.flux_preview = DEFAULT_FLUX_PREVIEW if self.strategy in LOSS_OPTIMAL else 0.0
        if self.magnetizing_floor is None:
            self.magnetizing_floor = 0.1 * self.phi_min
        if self.magnetizing_floor > self.phi_min:
            raise InvalidParameter('magnetizing_floor', self.magnetizing_floor,
                                   f'must be <= phi_min = {self.phi_min:g}')
        self.setpoints = _check_setpoints(self.setpoints, self.profile)
        if self.current_limit is not None:
            i_mag = self.phi_max / self.params.L_sr
            if self.current_limit <= i_mag:
                raise InvalidParameter('current_limit', self.current_limit,
                                       f'must exceed the magnetizing current phi_max/L_sr = '
                                       f'{i_mag:.4g} A (no torque would be left)')
        return self


def _number(x) -> float:
    """Return ``x`` as a float; a bool or a string is no number (ValueError)."""
    if isinstance(x, (bool, str, bytes)):
        raise ValueError(x)
    return float(x)


def _check_setpoints(setpoints, profile: str) -> tuple:
    """Return ((t, value, duration|None), ...) sorted by t; clear errors naming the entry."""
    out = []
    for k, entry in enumerate(setpoints or ()):
        try:
            t, value, duration = entry
        except (TypeError, ValueError):
            raise InvalidParameter(f'setpoints[{k}]', entry,
                                   'must be (t, value, duration)') from None
        t = _real(f'setpoints[{k}].t', t, 0.0)
        value = _real(f'setpoints[{k}].value', value)
        duration = _real(f'setpoints[{k}].duration', duration, 0.0, lo_open=True, allow_none=True)
        out.append((t, value, duration))
    if out and profile != 'setpoint':
        raise InvalidParameter('setpoints', setpoints, "need profile 'setpoint'")
    if any(b[0] < a[0] for a, b in zip(out, out[1:])):
        raise InvalidParameter('setpoints', setpoints, 'times must not decrease')
    return tuple(out)


def smooth_floor(phi: float, dphi: float, ddphi: float, eps: float):
    """
    Return (f, df/dt, d²f/dt²) of f(φ) = φ for φ ≥ 3ε and ε + φ²/(3ε) − φ³/(27ε²) below.

    f(0) = ε, f'(0) = 0, and f, f', f'' continuous at 3ε. So a flux reference rising from zero
    keeps φ* ≥ ε > 0 (eq. 3.13 divides by it) without a step in dφ*/dt or d²φ*/dt² — the
    start-up needs no voltage beyond the magnetizing ramp (docs/limits.md).
    """
    p1 = 3.0 * eps
    x = abs(phi)
    if x >= p1:
        return phi, dphi, ddphi
    f = eps + x * x / p1 - x ** 3 / (3.0 * p1 * p1)
    f1 = 2.0 * x / p1 - x * x / (p1 * p1)
    f2 = 2.0 / p1 - 2.0 * x / (p1 * p1)
    s = 1.0 if phi >= 0.0 else -1.0
    return f, f1 * s * dphi, f2 * dphi * dphi + f1 * s * ddphi


def sample_path(traj, schedule, times, setpoint_duration: float):
    """
    Return (θ*, ω*, a*) of a reference generator at rising ``times``, its setpoints applied.

    ``schedule``: (t, value, duration) rows, consumed as their times come (pass a copy).
    """
    theta, omega, acc = (np.empty(len(times)) for _ in range(3))
    for j, t in enumerate(times):
        while schedule and schedule[0][0] <= t:
            t_i, value, duration = schedule.pop(0)
            traj.set(value, t_i, duration or setpoint_duration)
        theta[j], omega[j], acc[j], _ = traj.sample(t)
    return theta, omega, acc


class DriveController:
    """Stateful controller: call :meth:`compute` once per period with increasing t."""

    def __init__(self, config: ControllerConfig | None = None):
        self.config = config if config is not None else ControllerConfig()
        self._c_nominal = ModelCoefficients.from_params(self.config.params)
        self._c = self._c_nominal
        self._est_key = None
        self._apply_config(self.config)
        tc = self.config.flux_time_constants or (self._c_nominal.T_r, 1e-3)
        self._flux_tc = tc
        self.reset()

    def _apply_config(self, cfg: ControllerConfig) -> None:
        """Build the derived objects of the reconfigurable fields (no run state touched)."""
        self.config = cfg
        curve = None
        if cfg.magnetizing is not None and cfg.core_loss_exponent == 2.0:
            c0 = ModelCoefficients.from_params(cfg.params)
            curve = (c0, curve_shape(c0, cfg.magnetizing))
        self._strategy = FluxStrategy(
            cfg.strategy, cfg.phi_d, cfg.phi_min, cfg.phi_max, cfg.params.k_e, cfg.params.k_h,
            cfg.core_loss_exponent,
            i_max=None if cfg.current_limit is None else cfg.current_margin * cfg.current_limit,
            curve=curve, inverter=(cfg.drive_loss_r, cfg.drive_loss_c))
        self._load = make_load(cfg.load if cfg.load_known else 'none', mgl=cfg.load_mgl,
                               c1=cfg.load_c1, c2=cfg.load_c2, tau=cfg.load_tau)
        if cfg.current_gain is None:
            self._K = (cfg.k1, 0.0, 0.0, cfg.k1)
        else:
            g = cfg.current_gain
            self._K = (g[0][0], g[0][1], g[1][0], g[1][1])

    # ------------------------------------------------------------------------------------------
    def reset(self) -> None:
        """Forget the run: the next ``compute`` re-initializes from its inputs."""
        cfg = self.config
        wb = cfg.torque_filter_bandwidth
        self._pd = LowPass2(1.0 / wb, 1.0 / wb)
        self._flux = LowPass2(self._flux_tc[0], self._flux_tc[1])
        self._t_prev = None
        self._rho = 0.0
        self._rho_dot = 0.0
        self._theta_offset = 0.0
        self._limited = False
        self._sent = []              # delay: the feedback parts ΔV of the commands not yet acting
        self._traj = None
        self._torque_sp = None
        self._schedule = list(cfg.setpoints)
        self.reference = {}
        self._plan = None            # optimal: the planned flux trajectory (flux_plan.FluxPlan)
        self._plan_tried = False
        self._live_setpoint = False  # a setpoint not in the configured profile: not known ahead
        self.plan_note = ''          # optimal: what the flux reference follows, and why
        if cfg.profile == 'thesis':
            self._traj = THESIS_TRAJECTORIES[cfg.mode]()
        # a baseline law makes the voltage in the thesis law's place (docs/baselines.md)
        self._baseline = None if cfg.law == 'thesis' else BaselineDrive(
            cfg.law, cfg.params, cfg.T_s, cfg.baseline, delay=cfg.delay, mode=cfg.mode,
            phi_max=cfg.phi_max, v_limit=cfg.v_limit, current_limit=cfg.current_limit,
            torque_limit=cfg.torque_limit, speed_limit=cfg.speed_limit)

    def reconfigure(self, changes: dict) -> None:
        """
        Change live fields (:data:`LIVE_FIELDS`) while running.

        The whole new configuration is validated first (ValueError naming the field; the
        old one stays in force); then it is applied keeping every run state (filters, field
        angle, reference generator, estimates), so the next step continues from where this
        one left off.
        """
        bad = [k for k in changes if k not in LIVE_FIELDS]
        if bad:
            raise InvalidParameter(bad[0], changes[bad[0]],
                                   f'cannot change while running (live: {", ".join(LIVE_FIELDS)})')
        values = dict(changes)
        if 'phi_min' in values and self.config.magnetizing_floor == 0.1 * self.config.phi_min:
            values['magnetizing_floor'] = None     # the default floor follows phi_min
        cfg = self.config.replace(**values)        # validated as a whole, by the same rules
        self._apply_config(cfg)

    @property
    def coefficients(self) -> ModelCoefficients:
        return self._c

    @property
    def pd_filter(self) -> LowPass2:
        """Return the torque filter of the PD demand u_pd (its input ``u``, output ``y``)."""
        return self._pd

    def set_setpoint(self, kind: str, value: float, t: float,
                     duration: float | None = None) -> None:
        """
        Set a new setpoint ('position' rad | 'speed' rad/s | 'torque' N·m), reached smoothly.

        Quintic over ``duration`` (default ``setpoint_duration``; torque over a tenth of it),
        taking effect at the first step at or after its stamp ``t``.

        A stamp at or before the last computed step (0 included: ``ros2 topic pub`` leaves the
        header unset) means *now*: the transition starts at the next step from where the reference
        is then, so θ*, ω* (and a*) stay continuous — the past is never rebuilt. A future stamp
        waits in the schedule; the reference keeps moving as it was until then.
        """
        cfg = self.config
        if cfg.profile != 'setpoint':
            raise ValueError("set_setpoint needs profile 'setpoint' (the thesis profile is fixed)")
        if kind != cfg.mode:
            raise ValueError(f'setpoint kind {kind!r} does not match '
                             f'the controller mode {cfg.mode!r}')
        value = _real('value', value)
        t = _real('t', t)
        # a setpoint not in the configured profile: the reference is not known ahead
        self._live_setpoint = True
        # in stamp order; equal stamps in arrival order (insort_right)
        bisect.insort(self._schedule, (t, value, duration), key=lambda s: s[0])

    def _start_transition(self, value: float, t_i: float, duration: float | None,
                          t: float) -> None:
        """
        Start the transition of a setpoint stamped t_i at the step t (t_i <= t).

        Stamped after the last computed step (within this period), it starts at its stamp —
        joining the reference C² there; stamped at or before it (the past), it starts now,
        at t.
        """
        cfg = self.config
        start = t_i if t_i > self._t_prev else t
        if cfg.mode == 'torque':
            self._torque_sp.set(value, start, duration or 0.1 * cfg.setpoint_duration)
        else:
            self._traj.set(value, start, duration or cfg.setpoint_duration)

    def _set_estimates(self, estimates) -> None:
        """
        Set the adapted estimates.

        The inverse-Γ set when it carries ``L_sigma`` (the improved law, truth-fed runs:
        every coefficient follows), else the thesis's ``R_r``/``theta``.
        """
        args = estimate_arguments(estimates)
        key = tuple(args.items())
        if key != self._est_key:
            self._c = ModelCoefficients.from_params(self.config.params, **args)
            self._est_key = key

    def _init_run(self, t, theta_r, omega_r, phi_a, phi_b) -> None:
        cfg = self.config
        if cfg.profile == 'setpoint':
            if cfg.mode == 'position':
                self._traj = SetpointPosition(theta_r)
            elif cfg.mode == 'speed':
                self._traj = SetpointSpeed(omega_r, theta_r)
            else:
                self._torque_sp = SetpointTorque(0.0)
        elif cfg.mode == 'speed':
            # the speed task's position reference is ∫ω*, anchored at the measured position
            self._theta_offset = theta_r - self._traj.sample(t)[0]
        mag = math.hypot(phi_a, phi_b)
        self._flux.reset(mag)
        self._rho = math.atan2(phi_b, phi_a) if mag > 1e-9 else 0.0
        self._t_prev = t

    def _apply_schedule(self, t: float) -> None:
        """
        Start the setpoints whose time has come, in stamp order.

        Those of the configured profile and of ``set_setpoint``. Called at step t before
        ``_t_prev`` moves on (the first step: after ``_init_run``, with ``_t_prev`` = t).
        """
        sched = self._schedule
        while sched and sched[0][0] <= t:
            t_i, value, duration = sched.pop(0)
            self._start_transition(value, t_i, duration, t)

    def _path_torque(self, t: float, c: ModelCoefficients) -> float:
        """Return the torque to follow the reference exactly at t (feedforward + load model)."""
        theta, omega, acc, _ = self._traj.sample(t)
        return c.J * acc + c.b * omega + self._load.torque(t, theta + self._theta_offset, omega)

    # Stage 1 ----------------------------------------------------------------------------------
    def _mechanical(self, t, theta_r, omega_r, c):
        """Return eq. 3.1's (θ*, ω*, feedforward + load torque, its rate, PD input u_pd)."""
        cfg = self.config
        if cfg.mode == 'torque':
            tau_ff, dtau_ff = self._torque_sp.sample(t)
            return theta_r, omega_r, tau_ff, dtau_ff, 0.0
        theta_ref, omega_ref, acc_ref, jerk_ref = self._traj.sample(t)
        theta_ref += self._theta_offset
        load = self._load
        tau = c.J * acc_ref + c.b * omega_ref + load.torque(t, theta_r, omega_r)
        # the load's rate along the motion: measured position/speed, reference acceleration
        dtau = c.J * jerk_ref + c.b * acc_ref + load.rate(t, theta_r, omega_r, acc_ref)
        u_pd = -cfg.k_v * (omega_r - omega_ref) - cfg.k_p * (theta_r - theta_ref)
        return theta_ref, omega_ref, tau, dtau, u_pd

    # Stage 2 ----------------------------------------------------------------------------------
    def _flux_reference(self, t, tau, omega_r, c):
        """Return the target flux (strategy, capped above base speed) → filter → smooth floor."""
        cfg = self.config
        if cfg.strategy == 'optimal':
            planned = self._planned(t, c)
            if planned is not None:
                phi_p, dphi_p, ddphi_p = planned
                self._flux.reset(phi_p, dphi_p)   # a fallback continues from the plan
                phi, dphi, ddphi = smooth_floor(phi_p, dphi_p, ddphi_p, cfg.magnetizing_floor)
                return phi_p, phi, dphi, ddphi
        tau_tgt = tau
        if cfg.flux_preview > 0.0 and cfg.mode != 'torque':
            tau_tgt += self._path_torque(t + cfg.flux_preview, c) - self._path_torque(t, c)
        phi_tgt = self._strategy.target(c, tau_tgt, omega_r)
        cap = self.flux_cap(omega_r)
        if phi_tgt > cap:
            phi_tgt = cap
        flt = self._flux
        flt.set_input(phi_tgt)
        phi, dphi, ddphi = smooth_floor(flt.y, flt.dy, flt.accel, cfg.magnetizing_floor)
        return phi_tgt, phi, dphi, ddphi

    def _planned(self, t: float, c: ModelCoefficients):
        """
        Return the optimal plan's (φ, φ̇, φ̈) at t, or None where the causal fallback rules.

        None: no plan (the reason is in ``plan_note``), a live setpoint, or past the plan's end.
        """
        if not self._plan_tried:
            self._plan_tried = True
            self._make_plan(t, c)
        plan = self._plan
        if plan is None:
            return None
        if self._live_setpoint:
            self._plan = None
            self.plan_note = (f'optimal: a live setpoint at t = {t:.4f} s changed the reference '
                              f'the plan was made for: min_loss from here on')
            return None
        if t > plan.end:
            self._plan = None
            self.plan_note = (f"optimal: past the plan's end ({plan.end:g} s): "
                              'min_loss from here on')
            return None
        return plan.sample(t)

    def _make_plan(self, t0: float, c: ModelCoefficients) -> None:
        """
        Plan the loss-optimal flux trajectory over the reference known ahead.

        From the present flux reference (docs/controller.md §10), with the drive's limits as
        constraints.
        """
        cfg = self.config
        if cfg.mode == 'torque':
            self.plan_note = ("optimal: the torque task's speed is not known ahead: min_loss "
                              '(the best causal plan)')
            return
        if self._live_setpoint or (cfg.profile == 'setpoint' and not self._schedule):
            self.plan_note = ('optimal: setpoints arrive live, the reference is not known ahead: '
                              'min_loss (the best causal plan)')
            return
        traj, sched = copy.deepcopy(self._traj), list(self._schedule)
        if cfg.horizon is not None:
            t1 = cfg.horizon
        elif cfg.profile == 'thesis':
            t1 = traj.t0 + 3.0            # the thesis profiles settle within 1.7 s of t0
        else:
            t1 = max(s_[0] + (s_[2] or cfg.setpoint_duration) for s_ in sched) + 3.0 * c.T_r
        if t1 - t0 < 2.0 * PLAN_STEP:
            self.plan_note = 'optimal: the run ends now: min_loss'
            return
        n = max(2, int(math.ceil((t1 - t0) / PLAN_STEP - 1e-9)))
        times = np.linspace(t0, t1, 2 * n + 1)      # nodes (even) and midpoints (odd)
        theta, omega, acc = sample_path(traj, sched, times, cfg.setpoint_duration)
        tau = np.array([c.J * a + c.b * w + self._load.torque(t, th + self._theta_offset, w)
                        for t, th, w, a in zip(times, theta, omega, acc)])
        if cfg.torque_limit is not None:
            np.clip(tau, -cfg.torque_limit, cfg.torque_limit, out=tau)
        cap = np.array([min(cfg.phi_max, self.flux_cap(w)) for w in omega[::2]])
        i_max = None if cfg.current_limit is None else cfg.current_margin * cfg.current_limit
        phi_end = None
        if cfg.horizon is None:
            phi_end = min(static_loss_optimal_flux(c, tau[-1], omega[-1], cfg.params.k_e,
                                                   cfg.params.k_h), cap[-1])
        phi0 = max(self._flux.y, 0.0)
        sat = None
        if cfg.magnetizing is not None:     # on the curve: from the unsaturated model
            c = self._c_nominal
            sat = saturation_terms(c, cfg.magnetizing)
        try:
            plan = plan_flux(c, times[::2], tau[1::2], omega[1::2], phi0, k_e=cfg.params.k_e,
                             k_h=cfg.params.k_h, phi_end=phi_end, phi_cap=cap, i_max=i_max,
                             sat=sat)
        except PlanError as exc:
            self.plan_note = f'optimal: {exc}: min_loss (the best causal plan)'
            return
        self._plan = plan
        limits = [name for name, on in (
            ('current limit', plan.current_limit_active),
            ('flux cap', plan.flux_cap_active)) if on]
        self.plan_note = (f'optimal: planned the flux over [{t0:g}, {t1:g}] s ({n} intervals) in '
                          f'{plan.solve_s:.2f} s, predicted losses {plan.loss_J:.2f} J'
                          + (f', bound by the {" and ".join(limits)}' if limits else '')
                          + (f'; the limits leave {plan.torque_shortfall:.3g} N·m·s of the torque '
                             f'undelivered' if plan.torque_shortfall > 1e-9 else ''))

    def reference_preview(self, times, theta_r: float = 0.0, omega_r: float = 0.0):
        """
        Return (θ*, ω*, a*) at ``times`` of the reference this controller will follow.

        From a start at (θ_r, ω_r) at times[0], the configured profile and its setpoints (θ*
        with the speed task's anchor, as the load sees it); no run state of this controller is
        touched (a copy runs). The torque task has no reference path: ValueError.
        """
        if self.config.mode == 'torque':
            raise ValueError('the torque task has no reference path (its speed is not known '
                             'ahead)')
        ctl = copy.deepcopy(self)
        ctl.reset()
        ctl._init_run(float(times[0]), theta_r, omega_r, 0.0, 0.0)
        theta, omega, acc = sample_path(ctl._traj, ctl._schedule, times,
                                        self.config.setpoint_duration)
        return theta + ctl._theta_offset, omega, acc

    def flux_cap(self, omega_r: float) -> float:
        """
        Return the field-weakening flux cap.

        The largest flux whose steady voltage ω_e (L_s/L_sr) φ stays within
        ``voltage_margin`` · v_limit at the speed ω_r (ω_e ≈ v ω_r); ∞ without a voltage
        limit.
        """
        cfg = self.config
        if cfg.v_limit is None or not cfg.field_weakening:
            return math.inf
        c = self._c
        w_e = c.v * abs(omega_r)
        if w_e <= 0.0:
            return math.inf
        return cfg.voltage_margin * cfg.v_limit * c.L_sr / (c.L_s * w_e)

    # Stage 1b: limits of the torque demand -----------------------------------------------------
    def _limit_torque(self, tau, dtau, phi, dphi, omega_r, c):
        """
        Limit τ* by the torque limit, the current limit at the present flux and the speed limit.

        dτ*/dt = 0 while a bound holds (the bound is what is demanded then).
        """
        cfg = self.config
        hi = math.inf if cfg.torque_limit is None else cfg.torque_limit
        i_d = (phi + c.T_r * dphi) / c.L_sr
        if i_d > 0.0:
            # torque grows with the flux: τ* ≤ v (L_sr/L_r)(φ* − ε) κ i_d*, κ = 2/√σ (twice the
            # min-energy ratio i_q/i_d = 1/√σ, eq. 3.19), zero at the floor ε: a torque demand
            # on a demagnetized machine does not step the q-current at start-up (docs/limits.md)
            hi = min(hi, c.v * c.L_sr * (phi - cfg.magnetizing_floor) * i_d * MAGNETIZING_RATIO
                     / (c.L_r * math.sqrt(c.sigma)))
        if cfg.current_limit is not None:
            room = cfg.current_limit * cfg.current_limit - i_d * i_d
            i_q_max = math.sqrt(room) if room > 0.0 else 0.0
            hi = min(hi, c.v * c.L_sr * phi * i_q_max / c.L_r)
        lo = -hi
        if cfg.speed_limit is not None:
            if omega_r > cfg.speed_limit:
                hi = min(hi, 0.0)
            elif omega_r < -cfg.speed_limit:
                lo = max(lo, 0.0)
        if tau > hi:
            return hi, 0.0, True
        if tau < lo:
            return lo, 0.0, True
        return tau, dtau, False

    # Stage 4 ----------------------------------------------------------------------------------
    def _voltage(self, c, i_ds, i_qs, di_ds, di_qs, phi, rho, rho_dot, dt, omega_r, omega_ref,
                 i_alpha, i_beta, phi_alpha_hat, phi_beta_hat):
        """Return feedforward eq. 3.29 rotated to the hold interval + feedback eq. 3.30-3.31."""
        cfg = self.config
        v = c.v
        cr, sr = math.cos(rho), math.sin(rho)
        i_a_ref = cr * i_ds - sr * i_qs
        i_b_ref = sr * i_ds + cr * i_qs
        p_a_ref = cr * phi
        p_b_ref = sr * phi
        v_d, v_q = feedforward_dq(c, i_ds, i_qs, di_ds, di_qs, phi, rho_dot, omega_r)
        T = dt if dt > 0.0 else cfg.T_s
        d = cfg.delay
        if cfg.hold_compensation:       # the middle of the period the command acts over
            rm = rho + (d + 0.5) * T * rho_dot
            cm, sm = math.cos(rm), math.sin(rm)
        else:
            cm, sm = cr, sr
        v_a_ff = cm * v_d - sm * v_q
        v_b_ff = sm * v_d + cm * v_q
        ea = i_alpha - i_a_ref
        eb = i_beta - i_b_ref
        fa = phi_alpha_hat - p_a_ref
        fb = phi_beta_hat - p_b_ref
        if d:
            ea, eb, fa, fb = self._predicted_errors(c, T, d * T * rho_dot, ea, eb, fa, fb)
        K11, K12, K21, K22 = self._K
        dva = -(K11 * ea + K12 * eb)
        dvb = -(K21 * ea + K22 * eb)
        coupling = cfg.flux_coupling
        if coupling == 'cancel':
            g = v * omega_r * c.theta          # + g 𝒥 (φ̂ − φ*)
            dva -= g * fb
            dvb += g * fa
        elif coupling == 'thesis':
            g = -0.5 * v * c.theta * omega_ref   # K₂ = g 𝒥, ΔV = K₂ (φ̂ − φ*)
            dva -= g * fb
            dvb += g * fa
        refs = (i_a_ref, i_b_ref, p_a_ref, p_b_ref, v_a_ff, v_b_ff)
        return v_a_ff + dva, v_b_ff + dvb, refs

    def _predicted_errors(self, c, T, turn, ea, eb, fa, fb):
        """
        Return the current and flux errors predicted to when the command acts (delay d).

        The current error e_{k+d} of the nominal sampled model, e_{j+1} = a₀ e_j + b₀ ΔV_{j-d}
        (a₀ = e^{−R_eq T/σL_s}, b₀ = (1 − a₀)/R_eq; ΔV the feedback parts of the commands sent
        but not yet acting: the feedforward is aimed at their periods), and the flux error
        turned by ρ̇ d T. With ΔV_k = −K ê_{k+d} the nominal loop's poles are a₀ − b₀K and d
        zeros: the undelayed loop's (docs/plant.md §10).
        """
        a0 = math.exp(-c.R_eq * T / c.sigma_L_s)
        b0 = (1.0 - a0) / c.R_eq
        # the first step: what acts until the line moves is this step's own command, not known yet
        for dva, dvb in self._sent or [(0.0, 0.0)] * self.config.delay:
            ea, eb = a0 * ea + b0 * dva, a0 * eb + b0 * dvb
        ct, st = math.cos(turn), math.sin(turn)
        return ea, eb, ct * fa - st * fb, st * fa + ct * fb

    def _observed_angle(self, rho: float, phi_a: float, phi_b: float) -> float:
        """
        Return the sensorless field angle: the observer's flux angle ∠φ̂.

        Unwrapped next to the integrated ρ, once |φ̂| is above the magnetizing floor; below it (a
        demagnetized machine, no angle to observe) the integrated ρ. Direct orientation: the
        angle does not integrate ω̂, so a lagging speed estimate does not rotate the current away
        from the flux.
        """
        if math.hypot(phi_a, phi_b) < self.config.magnetizing_floor:
            return rho
        d = math.atan2(phi_b, phi_a) - rho
        return rho + (d + math.pi) % (2.0 * math.pi) - math.pi

    # ------------------------------------------------------------------------------------------
    @staticmethod
    def _check_inputs(t, i_alpha, i_beta, theta_r, omega_r, phi_alpha_hat, phi_beta_hat) -> None:
        """Raise ValueError naming every input of :meth:`compute` that is not finite."""
        if not (math.isfinite(t) and math.isfinite(i_alpha) and math.isfinite(i_beta)
                and math.isfinite(theta_r) and math.isfinite(omega_r)
                and math.isfinite(phi_alpha_hat) and math.isfinite(phi_beta_hat)):
            names = ('t', 'i_alpha', 'i_beta', 'theta_r', 'omega_r', 'phi_alpha_hat',
                     'phi_beta_hat')
            vals = (t, i_alpha, i_beta, theta_r, omega_r, phi_alpha_hat, phi_beta_hat)
            bad = [n for n, v in zip(names, vals) if not math.isfinite(v)]
            raise ValueError(f'controller input(s) not finite: {", ".join(bad)}')

    def _advance_time(self, t, first, theta_r, omega_r, phi_alpha_hat, phi_beta_hat) -> float:
        """
        Return the step dt since the last :meth:`compute` and advance the filters over it.

        The first call starts the run from its inputs instead (dt = 0); raises ValueError when
        time went backwards.
        """
        if first:
            self._init_run(t, theta_r, omega_r, phi_alpha_hat, phi_beta_hat)
            return 0.0
        dt = t - self._t_prev
        if dt < 0.0:
            raise ValueError(f'time went backwards: t = {t!r} after {self._t_prev!r}')
        self._pd.advance(dt)
        self._flux.advance(dt)
        if self._limited and self.config.mode == 'speed':
            # back-calculation: while the voltage is limited, θ* = ∫ω* follows the shaft
            self._theta_offset += dt * (omega_r - self.reference['omega_ref'])
        return dt

    def _limit_voltage(self, v_a: float, v_b: float):
        """Return (V_α, V_β, saturated): the voltage scaled onto the ``v_limit`` circle."""
        v_limit = self.config.v_limit
        if v_limit is not None:
            mag = math.hypot(v_a, v_b)
            if mag > v_limit:
                s = v_limit / mag
                return v_a * s, v_b * s, True
        return v_a, v_b, False

    def _remember_feedback(self, dv: tuple) -> None:
        """Push the feedback part ``dv`` of the command into the drive's copy of the delay line."""
        if not self._sent:              # the plant's line starts with the first command
            self._sent = [dv] * self.config.delay
        self._sent.append(dv)
        del self._sent[0]

    def compute(self, t: float, i_alpha: float, i_beta: float, theta_r: float, omega_r: float,
                phi_alpha_hat: float, phi_beta_hat: float, estimates: dict | None = None):
        """Return the stator voltage (V_α, V_β) to hold on [t, t + T_s]; set ``self.reference``."""
        self._check_inputs(t, i_alpha, i_beta, theta_r, omega_r, phi_alpha_hat, phi_beta_hat)
        cfg = self.config
        if estimates:
            self._set_estimates(estimates)
        c = self._c
        first = self._t_prev is None
        dt = self._advance_time(t, first, theta_r, omega_r, phi_alpha_hat, phi_beta_hat)
        if self._schedule:
            self._apply_schedule(t)
        if self._baseline is not None:
            return self._compute_baseline(t, first, i_alpha, i_beta, theta_r, omega_r,
                                          phi_alpha_hat, phi_beta_hat)

        # 1. mechanical loop, eq. 3.1
        theta_ref, omega_ref, tau_fc, dtau_fc, u_pd = self._mechanical(t, theta_r, omega_r, c)
        if first:
            self._pd.reset(u_pd)
        tau = tau_fc + self._pd.y
        dtau = dtau_fc + self._pd.dy
        # 2. flux reference (strategy, field weakening, smooth floor)
        phi_tgt, phi, dphi, ddphi = self._flux_reference(t, tau, omega_r, c)
        # 1b. torque, current and speed limits on τ*
        tau, dtau, tau_limited = self._limit_torque(tau, dtau, phi, dphi, omega_r, c)
        # 3. reference model, eq. 3.13 / 3.26
        i_ds, i_qs, di_ds, di_qs, _, _, w_sl = dq_reference(c, tau, dtau, phi, dphi, ddphi)
        rho_dot = c.v * omega_r + w_sl
        rho = self._rho if first else self._rho + 0.5 * dt * (self._rho_dot + rho_dot)
        if cfg.sensorless:
            rho = self._observed_angle(rho, phi_alpha_hat, phi_beta_hat)
        # 4. feedforward + feedback
        v_a, v_b, refs = self._voltage(c, i_ds, i_qs, di_ds, di_qs, phi, rho, rho_dot, dt, omega_r,
                                       omega_ref, i_alpha, i_beta, phi_alpha_hat, phi_beta_hat)
        # 5. voltage limit; the PD filter always takes its input (no frozen state, no latch)
        v_a, v_b, saturated = self._limit_voltage(v_a, v_b)
        self._limited = saturated or tau_limited
        if cfg.delay:       # the feedback part of what the motor will get, for the prediction
            self._remember_feedback((v_a - refs[4], v_b - refs[5]))
        self._pd.set_input(u_pd)
        if cfg.compensation is not None:    # what the inverter loses, added (compensation.md)
            v_a, v_b = cfg.compensation.command(v_a, v_b, i_alpha, i_beta)

        self._t_prev = t
        self._rho = rho
        self._rho_dot = rho_dot
        i_a_ref, i_b_ref, p_a_ref, p_b_ref, v_a_ff, v_b_ff = refs
        self.reference = {
            't': t, 'theta_ref': theta_ref, 'omega_ref': omega_ref, 'tau_ref': tau,
            'dtau_ref': dtau, 'i_alpha_ref': i_a_ref, 'i_beta_ref': i_b_ref,
            'phi_alpha_ref': p_a_ref, 'phi_beta_ref': p_b_ref, 'phi_d_ref': phi,
            'phi_target': phi_tgt, 'i_d_ref': i_ds, 'i_q_ref': i_qs, 'omega_sl': w_sl,
            'rho': rho, 'v_alpha_ff': v_a_ff, 'v_beta_ff': v_b_ff, 'saturated': saturated,
            'torque_limited': tau_limited,
        }
        return v_a, v_b

    def _compute_baseline(self, t, first, i_alpha, i_beta, theta_r, omega_r, phi_alpha_hat,
                          phi_beta_hat):
        """
        Return a baseline law's voltage (docs/baselines.md): the drive's references, its law.

        The references and their feedforward torque (stage 1 without the PD: the law has its
        own loops), the strategy's flux for the torque the law asked for (stage 2), then the
        law; the compensation after its voltage limit, as the thesis law's.
        """
        cfg, c, b = self.config, self._c, self._baseline
        theta_ref, omega_ref, tau_ff, dtau_ff, _ = self._mechanical(t, theta_r, omega_r, c)
        phi_tgt, phi, _, _ = self._flux_reference(t, tau_ff if first else b.torque, omega_r, c)
        i_s = complex(i_alpha, i_beta)
        if first:       # from the drive's state: the observer's rotor flux, ψ_R = θ φ̂
            b.preset(cfg.params.theta * complex(phi_alpha_hat, phi_beta_hat), i_s, theta_r,
                     omega_r, theta_ref, omega_ref, tau_ff)
        v_a, v_b = b.voltage(t, i_s, theta_r, omega_r, theta_ref, omega_ref, tau_ff, phi)
        saturated = cfg.v_limit is not None and math.hypot(v_a, v_b) >= cfg.v_limit * (1 - 1e-12)
        if cfg.compensation is not None:    # what the inverter loses, added (compensation.md)
            v_a, v_b = cfg.compensation.command(v_a, v_b, i_alpha, i_beta)
        self._t_prev = t
        refs = b.references()
        self._rho = refs['rho']
        self.reference = dict(
            refs, t=t, theta_ref=theta_ref, omega_ref=omega_ref, tau_ref=b.torque,
            dtau_ref=dtau_ff, phi_d_ref=phi, phi_target=phi_tgt, v_alpha_ff=0.0,
            v_beta_ff=0.0, saturated=saturated, torque_limited=False)
        return v_a, v_b


def steady_operating_point(config: ControllerConfig, t0: float, theta0: float,
                           omega0: float) -> dict:
    """
    Return the electrical state the controller holds at t0, the shaft on its reference.

    The shaft is exactly on its reference at constant speed: torque from eq. 3.1 with zero
    tracking error, flux at the strategy's target, field angle 0. Used to start the speed task
    in steady state.
    """
    ctl = DriveController(config)
    c = ctl.coefficients
    if config.mode == 'torque':
        tau = 0.0
    else:
        _, w_ref, a_ref, _ = (ctl._traj.sample(t0) if ctl._traj is not None
                              else (theta0, omega0, 0.0, 0.0))
        if config.profile == 'setpoint':
            w_ref, a_ref = omega0, 0.0
        tau = c.J * a_ref + c.b * w_ref
        tau += ctl._load.torque(t0, theta0, omega0)
    phi = min(ctl._strategy.target(c, tau, omega0), ctl.flux_cap(omega0))
    out = steady_state(c, tau, phi, omega0, 0.0)
    out.update({'tau': tau, 'phi': phi})
    return out


def steady_start(config: ControllerConfig, plant: MotorParams, theta0: float, omega0: float,
                 flux_scale: float = 1.0):
    """
    Return (plant x₀, observer x̂₀) of a run started in the controller's steady state (θ₀, ω₀).

    The plant in the physical state that steady state is — the reference stator currents and
    the same inverse-Γ rotor flux ψ_R = θφ_r (θ = L_sr/L_r) — written in the plant's gauge (φ_r
    scaled by θ_model/θ_plant, ψ_s from the plant's inductances); the observer on the
    reference, in the model's gauge. A model written in another rotor gauge (same inverse-Γ
    set, docs/commissioning.md §1) thus starts the plant in the same state. ``flux_scale``
    scales the plant's rotor flux (its stator flux follows; the currents and the observer stay):
    a drive whose model's steady state is not exactly the motor's.
    """
    op = steady_operating_point(config, 0.0, theta0, omega0)
    gauge = flux_scale * config.params.theta / plant.theta
    phi_a, phi_b = gauge * op['phi_alpha'], gauge * op['phi_beta']
    psi_a, psi_b = stator_flux(op['i_alpha'], op['i_beta'], phi_a, phi_b,
                               plant.L_s, plant.L_r, plant.L_sr)
    x0 = (psi_a, psi_b, phi_a, phi_b, float(theta0), float(omega0))
    return x0, (op['i_alpha'], op['i_beta'], op['phi_alpha'], op['phi_beta'])
