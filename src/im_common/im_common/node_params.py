"""Parameters several nodes declare the same way: the motor, the period, the run length."""
from __future__ import annotations

from typing import Optional

from .params import (ELECTRICAL_NAMES, MOTOR_BLOCKS, MotorParams, THESIS_MOTOR,
                     warn_motor_defaults)

_MOTOR_DOC = {
    'R_s': ('stator resistance [ohm]', 1e-6, 100.0),
    'R_r': ('rotor resistance referred to the stator [ohm]', 1e-6, 100.0),
    'L_s': ('stator self inductance [H]', 1e-6, 10.0),
    'L_r': ('rotor self inductance [H]', 1e-6, 10.0),
    'L_sr': ('stator-rotor mutual inductance [H]', 1e-6, 10.0),
    'J': ('inertia of motor and load [kg m^2]', 1e-6, 1e9),
    'b': ('viscous friction [N m s]', 0.0, 100.0),
    'k_e': ('eddy-current core-loss coefficient [W s/Wb^2]', 0.0, 10.0),
    'k_h': ('hysteresis core-loss coefficient [W s/Wb^2]', 0.0, 10.0),
    'rated_voltage_rms_line': ('nameplate voltage, line-to-line RMS [V] (0: not given)', 0.0, 1e5),
    'rated_current_rms': ('nameplate current, line RMS [A] (0: not given)', 0.0, 1e5),
    'rated_frequency': ('nameplate frequency [Hz] (0: not given)', 0.0, 1e4),
    'rated_speed_rpm': ('nameplate shaft speed [rpm] (0: not given)', 0.0, 1e6),
    'rated_power': ('nameplate shaft power [W] (0: not given)', 0.0, 1e9),
    'rated_flux': ('rated rotor flux [Wb] (0: from rated voltage, frequency and speed)', 0.0,
                   100.0),
}


def declare_motor(node, base: MotorParams = THESIS_MOTOR, what: str = 'motor',
                  blocks: Optional[dict] = None, warn_defaults: bool = False) -> MotorParams:
    """
    Declare the motor parameters on ``node`` (defaults: the thesis motor) and validate them.

    A motor file (``--params-file motor.yaml`` with ``/**:``) sets them on every node at once.

    ``blocks``, when given, receives the motor file's ``saturation`` and ``thermal`` text (the
    real plant's blocks, docs/plant.md; '' when absent); every node declares them, since a motor
    file reaches every node.

    ``warn_defaults``: when a motor was given (its electrical fields), warn once, one line each,
    of the fields it lacks and the defaults they take (:func:`im_common.params.motor_defaults`).

    Raises :class:`im_common.params.InvalidParameter` naming the parameter (e.g. σ ≤ 0 names L_sr).
    """
    values = {}
    for name, (doc, lo, hi) in _MOTOR_DOC.items():
        values[name] = node.param(name, float(getattr(base, name)), f'{what}: {doc}', lo, hi)
    values['pole_pairs'] = node.param('pole_pairs', int(base.pole_pairs),
                                      f'{what}: pole pairs v', 1, 64)
    for name in MOTOR_BLOCKS:                   # a motor file's real-plant blocks (the plant's)
        text = node.param(name, '', f"{what}: the real plant's {name} block as YAML text ('': "
                                    'none; docs/plant.md)')
        if blocks is not None:
            blocks[name] = text
    motor = MotorParams(**values)
    given = set(getattr(node, '_parameter_overrides', {}))
    if warn_defaults and given.issuperset(ELECTRICAL_NAMES):
        warn_motor_defaults(f"node '{node.get_name()}' motor", given, motor,
                            log=node.get_logger().warning)
    return motor


def declare_compensation(node):
    """
    Declare the inverter-error compensation: ``comp_v_dead``, ``comp_r_on``, ``comp_current_band``.

    The controller, observer and adapter declare the same three (docs/compensation.md); returns
    the :class:`~im_common.compensation.InverterErrorModel`, or None when v_dead = r_on = 0.
    """
    from .compensation import compensation_from_parameters, DEFAULT_CURRENT_BAND
    doc = {'comp_v_dead': ('inverter error per phase: dead time t_d f_sw V_dc + device drop '
                           'v_on [V] (0 with comp_r_on 0: no compensation)', 0.0, 0.0, 1e4),
           'comp_r_on': ("inverter error per phase: the devices' on-state resistance [ohm]",
                         0.0, 0.0, 100.0),
           'comp_current_band': ('inverter error: the current over which its sign ramps from -1 '
                                 'to +1 is +-this [A]', DEFAULT_CURRENT_BAND, 0.0, 1e4)}
    values = {name: node.param(name, default, desc, lo, hi)
              for name, (desc, default, lo, hi) in doc.items()}
    return compensation_from_parameters(values)


def declare_saturation_model(node, params):
    """
    Declare ``saturation_model``: the drive's magnetizing curve ('' : the linear model).

    The observer and controller declare it (docs/plant.md §2, "The drive on the curve"): a
    ``saturation`` block as text (``{law: power, beta, S}`` or ``{table: [[psi, i_M], ...]}``,
    a motor file's form). Returns the :class:`~im_common.saturation.SaturatedModel` of
    ``params`` on it, or None; a bad block is one error naming the parameter.
    """
    import yaml
    from .saturation import saturated_model_from_text
    text = node.param('saturation_model', '', "the drive's magnetizing curve, a saturation block "
                      "as text ('': the linear model; docs/plant.md section 2)")
    return saturated_model_from_text(text, params, 'saturation_model', yaml.safe_load)


def declare_run(node):
    """
    Declare T_s (read-only), duration and the timeouts.

    Returns (T_s, duration, input_timeout, startup_timeout).
    """
    T_s = node.param('T_s', 1e-4, 'control period T_s [s] (whole nanoseconds)', 1e-6, 0.1)
    duration = node.param('duration', 0.0,
                          'simulated run length [s]; the node stops cleanly after it (0: no end)',
                          0.0, 1e6)
    timeout = node.param('input_timeout', 5.0,
                         'wall-clock seconds to wait for an input of the current step before '
                         'reporting it and stopping', 0.01, 3600.0)
    startup = node.param('startup_timeout', 30.0,
                         'wall-clock seconds to wait for the first step (discovery)', 0.01, 3600.0)
    return T_s, duration, timeout, startup
