"""
The observer node's parameters ↔ :class:`ObserverConfig`.

The observer's own configuration is one pydantic model: each field's type, default (or the
sentinel its node parameter uses), description and range is declared once, there. The node's
parameters are generated from it (:func:`im_common.node_params.declare_model`, as the controller's
are from :class:`im_controller.control_law.ControllerConfig`) and parsed back through it
(:func:`observer_config`), so an invalid value is refused in one line naming the parameter.
Nothing here imports rclpy: a stand-in with ``param`` works too.
"""
from __future__ import annotations

from typing import Optional, Tuple

from im_common.node_params import declare_model, model_arguments
from im_common.validation import (BLOCK_CONFIG, block_error, InvalidParameter,
                                  parameter_spec as _node)
from pydantic import BaseModel, Field, field_validator, ValidationError


def _sized(name: str, value, size: int, reason: str):
    """Return a sequence parameter's ``value`` as a tuple of ``size``; else one line naming it."""
    if isinstance(value, (str, bytes)) or not hasattr(value, '__iter__'):
        raise InvalidParameter(name, value, reason)
    values = list(value)                    # rclpy gives an array.array for a double array
    if len(values) != size:
        raise InvalidParameter(name, values, reason)
    return tuple(values)


class ObserverConfig(BaseModel):
    """
    The observer node's own parameters (SI units; each field's meaning in its Field).

    Each field's ``json_schema_extra`` says how the node declares it (:func:`_node`: the
    parameter's range, and the sentinel that stands for None). Invalid values are one
    :class:`InvalidParameter` line naming the parameter (a gain of the wrong size too).
    """

    model_config = BLOCK_CONFIG

    k_e_injection: Optional[float] = Field(
        None, description='current-error injection gain k_e of eq. 3.27 [V/A]',
        json_schema_extra=_node(0.0, 0.0, 1e6, [(0.0, None, 'the thesis value 1/sigma')]))
    injection_gain: Optional[Tuple[float, ...]] = Field(
        None, description='discrete-time 4x2 injection gain, row-major, from design_gains',
        json_schema_extra=_node([0.0], sentinels=[([0.0], None, 'unused')]))
    gain_period: float = Field(0.0, description='period the injection_gain was designed for [s]',
                               json_schema_extra=_node(lo=0.0, hi=1.0))
    use_adapter: bool = Field(False, description='wait for and use the adapter estimates '
                              '(eq. 4.13)', json_schema_extra=_node())
    initial_state: Tuple[float, float, float, float] = Field(
        (0.0, 0.0, 0.0, 0.0), description='initial estimate [i_alpha, i_beta, phi_alpha, '
        'phi_beta] [A, Wb]', json_schema_extra=_node())
    sensorless: bool = Field(False, description='estimate the speed from V and i and publish it '
                             '(speed-adaptive observer, docs/sensorless.md); the measured shaft '
                             'is not subscribed', json_schema_extra=_node())
    initial_speed: float = Field(0.0, description='sensorless: initial speed estimate [rad/s]',
                                 json_schema_extra=_node(lo=-1e4, hi=1e4))
    max_substep: float = Field(1e-4, description='longest integration sub-step [s]',
                               json_schema_extra=_node(lo=1e-7, hi=0.1))
    estimate_decimation: int = Field(
        10, description='publish the current estimate every N steps (the flux estimate is '
        'published every step: the controller needs it)',
        json_schema_extra=_node(lo=1, hi=1000000))

    def __init__(self, **values):
        """Validate ``values``; an error is one :class:`InvalidParameter` naming the field."""
        try:
            super().__init__(**values)
        except ValidationError as exc:
            raise block_error(type(self), values, '', exc.errors()) from None

    @field_validator('injection_gain', mode='before')
    @classmethod
    def _gain_size(cls, value):
        return None if value is None else _sized(
            'injection_gain', value, 8, '8 numbers (row-major 4x2), or [0.0] for none')

    @field_validator('initial_state', mode='before')
    @classmethod
    def _state_size(cls, value):
        return _sized('initial_state', value, 4, '4 values')


def declare_observer(node) -> dict:
    """
    Declare the observer's own parameters on ``node``; return their values as declared.

    One read-only parameter per field of :class:`ObserverConfig` (its name, type, default or
    sentinel, description and range: :func:`im_common.node_params.declare_model`);
    :func:`observer_config` parses the values.
    """
    return declare_model(node, ObserverConfig)


def observer_config(values: dict, T_s: float) -> ObserverConfig:
    """
    Return the observer configuration of declared parameter ``values`` (checked).

    Each sentinel is the None it stands for (:func:`im_common.node_params.model_arguments`); a
    gain of the wrong size, or an injection gain designed for another period than ``T_s``, is
    refused in one line naming the parameter.
    """
    cfg = ObserverConfig(**model_arguments(ObserverConfig, values))
    if cfg.injection_gain is not None and abs(cfg.gain_period - T_s) > 1e-12:
        raise InvalidParameter('gain_period', cfg.gain_period, 'the injection gain was designed '
                               f'for another period than T_s = {T_s}')
    return cfg
