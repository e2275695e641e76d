"""
The adapter node's parameters ↔ :class:`AdapterConfig`.

Every adaptation gain is a field of one pydantic model, declared once with its type, description,
range and sentinel (its default is :class:`~im_adapt.adaptation.AdaptationGains`'s, the
adaptation's own); the node's parameters are generated from it
(:func:`im_common.node_params.declare_model`, as the controller's are from
:class:`im_controller.control_law.ControllerConfig`) and parsed back through it, so an invalid
value is refused in one line naming the parameter. Nothing here imports rclpy: a stand-in with
``param`` works too.
"""
from __future__ import annotations

from dataclasses import fields
from typing import Literal, Optional

from im_common.node_params import declare_model, model_arguments
from im_common.params import MotorParams
from im_common.validation import BLOCK_CONFIG, block_error, parameter_spec as _node
from pydantic import BaseModel, create_model, Field, model_validator, ValidationError

from .adaptation import AdaptationGains, FEEDS, LAWS, ParameterAdapter, START_OFFSETS

#: the adaptation's defaults as its dataclass declares them (their one home; 'auto' unresolved)
_DEFAULT = {f.name: f.default for f in fields(AdaptationGains)}


def _gain(name: str, description: str, lo, hi, sentinel: str = ''):
    """
    Return the Field of a gain: its dataclass default, ``description`` and range [lo, hi].

    ``sentinel``: what the parameter's 0 stands for (the field's None: derived from the motor).
    """
    spec = _node(0.0, lo, hi, [(0.0, None, sentinel)]) if sentinel else _node(lo=lo, hi=hi)
    return Field(_DEFAULT[name], description=description, json_schema_extra=spec)


class AdapterConfig(BaseModel):
    """
    The adapter node's adaptation parameters (SI units; each field's meaning in its Field).

    A bound whose default is None (R_r_min, R_r_max, L_M_min, L_M_max) is derived from the
    motor: :meth:`for_motor` gives the model whose defaults are the motor's, the one the node
    declares. Invalid values, and values :class:`~im_adapt.adaptation.AdaptationGains` refuses
    together, are one :class:`~im_common.validation.InvalidParameter` line naming the parameter.
    """

    model_config = BLOCK_CONFIG

    law: Literal[LAWS] = Field(_DEFAULT['law'], description='adaptation law',
                               json_schema_extra=_node())
    feed: Literal[FEEDS] = Field(
        _DEFAULT['feed'], description='what the controller and observer take: inverse_gamma '
        '(L_sigma, L_M, R_R) or thesis_pair (R_r, theta); auto = inverse_gamma for the improved '
        'law, thesis_pair for the thesis law', json_schema_extra=_node())
    freeze: bool = Field(_DEFAULT['freeze'], description='hold the estimates (signals keep '
                         'running)', json_schema_extra=_node())
    estimate_leakage: bool = Field(_DEFAULT['estimate_leakage'], description='improved law: '
                                   'estimate sigma*L_s too (else hold L_sigma)',
                                   json_schema_extra=_node())
    estimate_stator_resistance: bool = Field(
        _DEFAULT['estimate_stator_resistance'], description='improved law, sensored: estimate '
        'R_s too (learnt below 100 rad/s stator frequency, where L_M is held; sensorless always '
        'estimates it)', json_schema_extra=_node())
    start_offset: Literal[START_OFFSETS] = Field(
        _DEFAULT['start_offset'], description='improved law: estimate the start offset of the '
        'voltage-model flux of a drive started magnetised; auto = unless R_s is estimated',
        json_schema_extra=_node())
    decimation: int = Field(_DEFAULT['decimation'], description='update the estimates every N '
                            'control periods', json_schema_extra=_node(lo=1, hi=100000))
    gamma_t: float = _gain('gamma_t', 'thesis law: gain gamma_t of eq. 4.4 for theta '
                           '[1/(N m A s)]', 0.0, 1e3)
    gamma_r: float = _gain('gamma_r', 'thesis law: gain gamma_r of eq. 4.9 for R_r [1/s]',
                           0.0, 1e4)
    epsilon: float = _gain('epsilon', 'thesis law: epsilon of eq. 4.9 [A^2]', 1e-9, 1e6)
    flux_corner: float = _gain('flux_corner', 'corner [rad/s] below which the stator flux of '
                               'eq. 4.3 follows the current model (drift removal; 0 = pure '
                               'integral); the upper bound of the frequency-following corner',
                               0.0, 1e3)
    flux_corner_ratio: float = _gain('flux_corner_ratio', 'corner / stator frequency: the flux '
                                     'corner follows kappa*abs(omega_e) between flux_corner_min '
                                     'and flux_corner (0 = fixed at flux_corner)', 0.0, 100.0)
    flux_corner_min: float = _gain('flux_corner_min', 'lower bound [rad/s] of the '
                                   'frequency-following flux corner', 0.0, 1e3)
    filter_corner: float = _gain('filter_corner', 'improved law: corner [rad/s] of the '
                                 'regression filter', 1.0, 1e5)
    memory: float = _gain('memory', 'improved law: forgetting time constant of the least squares '
                          'for R_R, L_M [s]', 1e-4, 1e3)
    leakage_memory: float = _gain('leakage_memory', 'improved law: forgetting time constant for '
                                  'the leakage sigma*L_s [s]', 1e-4, 1e4)
    stator_memory: float = _gain('stator_memory', 'improved law: forgetting time constant for '
                                 'the stator resistance R_s [s]', 1e-4, 1e4)
    didt_floor: float = _gain('didt_floor', 'improved law: current rate [A/s] of the information '
                              'floor for the leakage', 1e-6, 1e6)
    i_floor: float = _gain('i_floor', 'improved law: current [A] of the information floor (holds '
                           'unexcited directions)', 1e-6, 1e3)
    phi_floor: float = _gain('phi_floor', 'improved law: flux [Wb] of the information floor',
                             1e-9, 10.0)
    L_sigma: Optional[float] = _gain('L_sigma', 'improved law: initial (or fixed) leakage '
                                     'sigma*L_s [H] for the voltage-model rotor flux', 0.0, 10.0,
                                     'L_s - L_sr*theta_initial')
    L_sigma_min: Optional[float] = _gain('L_sigma_min', 'projection: lower bound of the leakage '
                                         'estimate [H]', 0.0, 10.0, 'L_sigma/4')
    L_sigma_max: Optional[float] = _gain('L_sigma_max', 'projection: upper bound of the leakage '
                                         'estimate [H]', 0.0, 10.0, '10*L_sigma')
    R_r_min: Optional[float] = _gain('R_r_min', 'projection: lower bound of the R_r estimate '
                                     '[ohm]', 1e-6, 100.0)
    R_r_max: Optional[float] = _gain('R_r_max', 'projection: upper bound of the R_r estimate '
                                     '[ohm]', 1e-6, 100.0)
    theta_min: float = _gain('theta_min', 'projection: lower bound of the theta estimate',
                             1e-3, 10.0)
    theta_max: float = _gain('theta_max', 'projection: upper bound of theta before the sigma '
                             'bound', 1e-3, 10.0)
    sigma_min: float = _gain('sigma_min', 'projection: smallest model leakage factor 1 - '
                             'theta*L_sr/L_s', 1e-6, 0.999)
    L_M_min: Optional[float] = _gain('L_M_min', 'projection: lower bound of the L_M estimate [H]',
                                     1e-6, 10.0)
    L_M_max: Optional[float] = _gain('L_M_max', 'projection: upper bound of the L_M estimate [H]',
                                     1e-6, 10.0)

    def __init__(self, **values):
        """Validate ``values``; an error is one :class:`InvalidParameter` naming the field."""
        try:
            super().__init__(**values)
        except ValidationError as exc:
            raise block_error(type(self), values, '', exc.errors()) from None

    @model_validator(mode='after')
    def _consistent(self) -> 'AdapterConfig':
        """Apply the adaptation's rules across fields (bounds ordered, sigma_min < 1, ...)."""
        self.gains()
        return self

    def gains(self) -> AdaptationGains:
        """Return the :class:`~im_adapt.adaptation.AdaptationGains` of this configuration."""
        return AdaptationGains(**{name: getattr(self, name) for name in type(self).model_fields})

    @classmethod
    def for_motor(cls, params: MotorParams, theta0: float) -> type:
        """
        Return the model whose motor-derived bounds default to ``params``'s (and ``theta0``'s).

        The fields whose default is None and whose parameter has no sentinel (R_r_min, R_r_max,
        L_M_min, L_M_max) default to :meth:`AdaptationGains.resolve`'s values, the node
        parameters' defaults; the rest is this model's.
        """
        derived = AdaptationGains().resolve(params, theta0)
        motor = {name: (info.annotation, Field(float(getattr(derived, name)),
                                               description=info.description,
                                               json_schema_extra=info.json_schema_extra))
                 for name, info in cls.model_fields.items()
                 if info.default is None and 'default' not in info.json_schema_extra['parameter']}
        return create_model(cls.__name__, __base__=cls, __module__=cls.__module__, **motor)


def declare_law(node, params: MotorParams, R_r0: float, theta0: float) -> ParameterAdapter:
    """
    Declare the adaptation gains on ``node`` and return the adapter.

    One read-only parameter per field of :meth:`AdapterConfig.for_motor` (its name, type,
    default or sentinel, description, choices and range:
    :func:`im_common.node_params.declare_model`), parsed back through the model. Invalid values
    raise :class:`InvalidParameter` naming the parameter.
    """
    model = AdapterConfig.for_motor(params, theta0)
    cfg = model(**model_arguments(model, declare_model(node, model)))
    return ParameterAdapter(params, cfg.gains(), R_r0, theta0)
