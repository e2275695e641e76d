"""
ROS parameters of the controller node ↔ :class:`im_controller.control_law.ControllerConfig`.

The parameters are generated from the configuration model's fields (description, type,
default, the -1 / 0 / [0.0] sentinels and their meaning, choices, range: each field's metadata);
the node builds the configuration from them through the model, so an invalid value is refused
with its name (by the range check at declaration, or by ``ControllerConfig`` validation).
"""
from __future__ import annotations

from im_common.node_params import declare_model, model_arguments

from .control_law import ControllerConfig, LIVE_FIELDS
from .profiles import from_parameters as setpoints_from_parameters

# Parameters that make sense to change while the node runs (``ros2 param set``): gains, strategy,
# flux levels and limits — the configuration fields of the same names. The rest (mode, profile,
# motor model, period, load model, setpoints) are read-only.
LIVE_PARAMETERS = LIVE_FIELDS

#: {parameter: what its -1 stands for} (the configuration's field metadata, the one place a
#: sentinel is given its meaning): -1 (exactly) is a default the configuration chooses — the
#: per-mode gains, the strategy's preview, the motor model's rating —; any other negative value
#: is refused by name, never quietly read as the sentinel
SENTINEL_DEFAULTS = {name: meaning for name, info in ControllerConfig.model_fields.items()
                     for given, _, meaning in ((info.json_schema_extra or {}).get('parameter')
                                               or {}).get('sentinels', ()) if given == -1.0}


def declare_controller(node) -> dict:
    """
    Declare the controller's parameters on ``node``; return their values by name.

    One parameter per field of :class:`~im_controller.control_law.ControllerConfig` the node
    takes, generated from the model (:func:`im_common.node_params.declare_model`: its name, type,
    default or sentinel, description, choices and range); the :data:`LIVE_PARAMETERS` writable
    while running, the rest read-only. Besides them ``gain_period``, the period ``current_gain``
    was designed for (no field: it is checked against T_s here).
    """
    v = declare_model(node, ControllerConfig, live=LIVE_PARAMETERS)
    v['gain_period'] = node.param('gain_period', 0.0, 'period current_gain was designed for [s]',
                                  0.0, 1.0)
    return v


def config_from_parameters(params, values: dict, T_s: float) -> ControllerConfig:
    """
    Return the controller configuration from declared parameter values.

    Each -1 / 0 / [0.0] is what the field's metadata says it stands for
    (:func:`im_common.node_params.model_arguments`); ``current_gain`` is row-major (4 numbers,
    designed for ``gain_period`` = T_s), ``setpoints`` flat triples. Parsed by the model: an
    error is one line naming the parameter.
    """
    v = dict(values)
    gain_period = v.pop('gain_period')
    v = model_arguments(ControllerConfig, v)
    if v.get('current_gain') is not None:
        gain = list(v['current_gain'])
        if len(gain) != 4:
            raise ValueError(f"invalid parameter 'current_gain' = {gain!r}: 4 numbers (row-major "
                             '2x2)')
        if abs(gain_period - T_s) > 1e-12:
            raise ValueError(f"invalid parameter 'gain_period' = {gain_period!r}: current_gain "
                             f'was designed for another period than T_s = {T_s}')
        v['current_gain'] = [gain[0:2], gain[2:4]]
    if 'setpoints' in v:
        v['setpoints'] = setpoints_from_parameters(v['setpoints'])
    return ControllerConfig(params=params, T_s=T_s, **v)


def live_changes(params, values: dict, changes: dict, T_s: float) -> dict:
    """
    Return the :meth:`DriveController.reconfigure` changes for new values of live parameters.

    Called by the node's parameter callback; the same conversions as
    :func:`config_from_parameters`.
    """
    bad = [k for k in changes if k not in LIVE_PARAMETERS]
    if bad:
        raise ValueError(f"parameter '{bad[0]}' is read-only while running "
                         f"(live: {', '.join(LIVE_PARAMETERS)})")
    merged = dict(values, **changes)
    if ('current_gain' in changes and 'gain_period' not in changes
            and len(changes['current_gain']) == 4):
        merged['gain_period'] = T_s
    cfg = config_from_parameters(params, merged, T_s)
    out = {}
    for key in changes:
        out[key] = getattr(cfg, key)
    if 'k1' in changes and 'current_gain' not in changes:
        out['current_gain'] = cfg.current_gain
    return out
