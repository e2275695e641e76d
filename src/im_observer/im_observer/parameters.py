"""
The observer node's parameters.

The observer node's parameters, declared the same way as the other nodes' (``node.param(name,
default, description, lo, hi)``; see ``im_controller/parameters.py``). Nothing here imports rclpy.
"""
from __future__ import annotations


def declare_observer(node) -> dict:
    """
    Declare the observer's own parameters on ``node``.

    Return their values by name (checked: a gain of the wrong size is refused, naming the
    parameter).
    """
    p = node.param
    v = {
        'k_e_injection': p('k_e_injection', 0.0, 'current-error injection gain k_e of eq. 3.27 '
                           '[V/A] (0: the thesis value 1/sigma)', 0.0, 1e6),
        'injection_gain': list(p('injection_gain', [0.0], 'discrete-time 4x2 injection gain, '
                                 'row-major, from design_gains ([0.0]: unused)')),
        'gain_period': p('gain_period', 0.0, 'period the injection_gain was designed for [s]',
                         0.0, 1.0),
        'use_adapter': p('use_adapter', False,
                         'wait for and use the adapter estimates (eq. 4.13)'),
        'initial_state': list(p('initial_state', [0.0, 0.0, 0.0, 0.0],
                                'initial estimate [i_alpha, i_beta, phi_alpha, phi_beta] '
                                '[A, Wb]')),
        'sensorless': p('sensorless', False, 'estimate the speed from V and i and publish it '
                        '(speed-adaptive observer, docs/sensorless.md); the measured shaft is not '
                        'subscribed'),
        'initial_speed': p('initial_speed', 0.0, 'sensorless: initial speed estimate [rad/s]',
                           -1e4, 1e4),
        'max_substep': p('max_substep', 1e-4, 'longest integration sub-step [s]', 1e-7, 0.1),
        'estimate_decimation': p('estimate_decimation', 10, 'publish the current estimate every N '
                                 'steps (the flux estimate is published every step: the '
                                 'controller needs it)', 1, 1000000),
    }
    if len(v['initial_state']) != 4:
        raise ValueError(f"invalid parameter 'initial_state' = {v['initial_state']!r}: 4 values")
    gain = v['injection_gain']
    if gain == [0.0]:
        v['injection_gain'] = None
    elif len(gain) != 8:
        raise ValueError(f"invalid parameter 'injection_gain' = {gain!r}: 8 numbers (row-major "
                         f'4x2), or [0.0] for none')
    return v


def check_gain_period(values: dict, T_s: float) -> None:
    if values['injection_gain'] is not None and abs(values['gain_period'] - T_s) > 1e-12:
        raise ValueError(f"invalid parameter 'gain_period' = {values['gain_period']!r}: the "
                         f'injection gain was designed for another period than T_s = {T_s}')
