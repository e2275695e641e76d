"""
ROS parameters of the controller node ↔ :class:`im_controller.control_law.ControllerConfig`.

Every field of the configuration is a declared parameter with a description and a range; the
node builds the configuration from them, so an invalid value is refused with its name (by the
range check at declaration, or by ``ControllerConfig`` validation).
"""
from __future__ import annotations

from im_common.loads import MODEL_KINDS
from im_common.params import RATED

from .control_law import (ControllerConfig, DEFAULT_CURRENT_MARGIN, DEFAULT_VOLTAGE_MARGIN,
                          FLUX_COUPLINGS, LIVE_FIELDS, MODES, PROFILES, STRATEGIES)
from .profiles import from_parameters as setpoints_from_parameters

# Parameters that make sense to change while the node runs (``ros2 param set``): gains, strategy,
# flux levels and limits — the configuration fields of the same names. The rest (mode, profile,
# motor model, period, load model, setpoints) are read-only.
LIVE_PARAMETERS = LIVE_FIELDS

# Parameters whose -1 (exactly) stands for a default the configuration chooses; any other
# negative value is refused by name, never quietly read as the sentinel.
SENTINEL_DEFAULTS = {'k_p': 'per-mode default', 'k_v': 'per-mode default',
                     'flux_preview': 'strategy default'}
# Parameters whose -1 (the default) stands for the motor model's rating
# (:func:`im_common.params.default_limits`); without that rating, the value before ratings were
# defaults: no limit, or the thesis's flux level (``ControllerConfig``'s default).
RATING_DEFAULTS = {'v_limit': 'rated voltage, else none',
                   'current_limit': 'rated current, else none',
                   'phi_d': 'rated flux, else 1.2 Wb',
                   'phi_min': 'share of the rated flux, else 0.2 Wb',
                   'phi_max': 'rated flux, else 1.2 Wb'}
SENTINEL_DEFAULTS.update({k: f'from the motor: {why}' for k, why in RATING_DEFAULTS.items()})
_OWN_SENTINELS = ('k_p', 'k_v', 'flux_preview')


def declare_controller(node) -> dict:
    """
    Declare the controller's parameters on ``node``; return their values by name.

    Declare the controller's parameters on ``node``; return their values by name (the
    :data:`LIVE_PARAMETERS` writable while running, the rest read-only).
    """
    def p(name, *args, **kwargs):
        return node.param(name, *args, read_only=name not in LIVE_PARAMETERS, **kwargs)
    v = {}
    v['mode'] = p('mode', 'position', 'tracking task', choices=MODES)
    v['profile'] = p('profile', 'thesis',
                     'reference source: the thesis trajectories (seed 000 §3.4.4) or setpoints '
                     'from /im/setpoint turned into smooth references', choices=PROFILES)
    v['strategy'] = p('strategy', 'min_energy', 'flux strategy', choices=STRATEGIES)
    v['phi_d'] = p('phi_d', -1.0, "constant-flux level [Wb] (-1: the motor's rated flux, "
                   "else the thesis's 1.2)", -1.0, 10.0)
    v['phi_min'] = p('phi_min', -1.0, 'lower flux bound of min_energy / min_loss [Wb] (-1: 1/6 '
                     'of the rated flux, else 0.2)', -1.0, 10.0)
    v['phi_max'] = p('phi_max', -1.0, 'upper flux bound (saturation) [Wb] (-1: the rated flux, '
                     'else 1.2)', -1.0, 10.0)
    v['k1'] = p('k1', 40.0, 'current feedback gain K1 = k1 I [V/A] (Delta V = -K1 (i - i*))',
                1e-6, 1e6)
    v['k_p'] = p('k_p', -1.0, 'PD position gain of eq. 3.1 [N m/rad] (-1: per-mode default, '
                 'position 10, speed 1)', -1.0, 1e6)
    v['k_v'] = p('k_v', -1.0, 'PD speed gain of eq. 3.1 [N m s/rad] (-1: per-mode default, '
                 'position 1, speed 3)', -1.0, 1e6)
    v['load_known'] = p('load_known', True, 'feed the load model tau_c forward in eq. 3.1')
    v['load'] = p('load', 'pendulum', 'load model for tau_c (a function of the shaft state; a '
                  "load in time is the plant's, docs/running.md)", choices=MODEL_KINDS)
    v['load_mgl'] = p('load_mgl', 10.0, 'pendulum load model m g l [N m]', -1e4, 1e4)
    v['load_c1'] = p('load_c1', 1.0, 'linear load model c1 [N m]', -1e4, 1e4)
    v['load_c2'] = p('load_c2', 0.001, 'linear load model c2 [N m s]', -1e3, 1e3)
    v['load_tau'] = p('load_tau', 0.0, 'constant load model [N m]', -1e4, 1e4)
    v['v_limit'] = p('v_limit', -1.0, 'voltage-vector limit with anti-windup [V] (0: none; -1: '
                     "the motor's rated voltage, none without one)", -1.0, 1e5)
    v['current_gain'] = p('current_gain', [0.0],
                          'full 2x2 current gain K1, row-major, from design_gains ([0.0]: k1 I)')
    v['gain_period'] = p('gain_period', 0.0, 'period current_gain was designed for [s]', 0.0, 1.0)
    v['flux_coupling'] = p('flux_coupling', 'cancel',
                           "flux term of the current feedback: 'cancel', 'thesis' (K2 of eq. "
                           "3.30) or 'none'", choices=FLUX_COUPLINGS)
    v['hold_compensation'] = p('hold_compensation', True,
                               'rotate the feedforward to the middle of the hold interval')
    v['torque_filter_bandwidth'] = p('torque_filter_bandwidth', 1000.0,
                                     'bandwidth of the PD-part torque filter [rad/s]', 1.0, 1e6)
    v['flux_preview'] = p('flux_preview', -1.0,
                          'look-ahead of the flux target [s] (-1: strategy default)', -1.0, 10.0)
    v['core_loss_exponent'] = p('core_loss_exponent', 2.0,
                                'flux exponent of the core-loss model min_loss minimizes (1 or 2)',
                                1.0, 2.0)
    v['setpoint_duration'] = p('setpoint_duration', 0.5,
                               'duration of the smooth transition to a new setpoint [s]', 1e-3,
                               100.0)
    v['setpoints'] = p('setpoints', [0.0],
                       "profile 'setpoint': setpoints the controller applies itself, flat triples "
                       't [s], value, transition duration [s] (0: setpoint_duration); [0.0]: none '
                       '(im_controller.profiles writes them from a profile file)')
    v['torque_limit'] = p('torque_limit', 0.0, 'bound on |tau*| [N m] (0: none)', 0.0, 1e7)
    v['current_limit'] = p('current_limit', -1.0,
                           'stator-current magnitude the torque demand may ask for [A] (0: none; '
                           "-1: the motor's rated current, none without one)", -1.0, 1e6)
    v['speed_limit'] = p('speed_limit', 0.0,
                         'beyond this |omega_r| no torque pushes further [rad/s] (0: none)', 0.0,
                         1e5)
    v['field_weakening'] = p('field_weakening', True,
                             'cap the flux above base speed so the steady voltage fits v_limit')
    v['voltage_margin'] = p('voltage_margin', DEFAULT_VOLTAGE_MARGIN,
                            'share of v_limit the steady voltage may use under field weakening',
                            0.05, 1.0)
    v['current_margin'] = p('current_margin', DEFAULT_CURRENT_MARGIN,
                            'share of current_limit the steady current of min_energy/min_loss may '
                            'use (their flux moves into the range that fits)', 0.05, 1.0)
    return v


def config_from_parameters(params, values: dict, T_s: float) -> ControllerConfig:
    """
    Return the controller configuration from declared parameter values.

    -1 / 0 / [0.0] mean the defaults.
    """
    v = dict(values)
    gain = list(v.pop('current_gain'))
    gain_period = v.pop('gain_period')
    if len(gain) == 4:
        if abs(gain_period - T_s) > 1e-12:
            raise ValueError(f"invalid parameter 'gain_period' = {gain_period!r}: current_gain "
                             f'was designed for another period than T_s = {T_s}')
        v['current_gain'] = [gain[0:2], gain[2:4]]
    elif gain != [0.0]:
        raise ValueError(f"invalid parameter 'current_gain' = {gain!r}: 4 numbers (row-major 2x2)")
    for key in _OWN_SENTINELS:
        if v[key] == -1.0:
            v[key] = None
        elif v[key] < 0:
            raise ValueError(f"invalid parameter '{key}' = {v[key]!r}: must be >= 0, or -1 for "
                             f'the {SENTINEL_DEFAULTS[key]}')
    for key in RATING_DEFAULTS:
        if v[key] == -1.0:
            v[key] = RATED                  # ControllerConfig takes the motor model's rating
        elif v[key] < 0:
            raise ValueError(f"invalid parameter '{key}' = {v[key]!r}: must be >= 0, or -1 for "
                             f'the {SENTINEL_DEFAULTS[key]}')
    for key in ('v_limit', 'torque_limit', 'current_limit', 'speed_limit'):
        v[key] = None if v[key] == 0 else v[key]
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
