"""
The adapter node's parameters.

Every adaptation gain declared with a description and a range, the same way as the other nodes
(``node.param(name, default, description, lo, hi)``; see ``im_controller/parameters.py``). Nothing
here imports rclpy: a stand-in with ``param`` works too.
"""
from __future__ import annotations

from im_common.params import MotorParams

from .adaptation import (AdaptationGains, FEED_DEFAULT, FEEDS, LAWS, ParameterAdapter,
                         START_OFFSETS)

_DOC = {
    'gamma_t': 'thesis law: gain gamma_t of eq. 4.4 for theta [1/(N m A s)]',
    'gamma_r': 'thesis law: gain gamma_r of eq. 4.9 for R_r [1/s]',
    'epsilon': 'thesis law: epsilon of eq. 4.9 [A^2]',
    'flux_corner': 'corner [rad/s] below which the stator flux of eq. 4.3 follows the current '
                   'model (drift removal; 0 = pure integral); the upper bound of the '
                   'frequency-following corner',
    'flux_corner_ratio': 'corner / stator frequency: the flux corner follows kappa*abs(omega_e) '
                         'between flux_corner_min and flux_corner (0 = fixed at flux_corner)',
    'flux_corner_min': 'lower bound [rad/s] of the frequency-following flux corner',
    'filter_corner': 'improved law: corner [rad/s] of the regression filter',
    'memory': 'improved law: forgetting time constant of the least squares for R_R, L_M [s]',
    'leakage_memory': 'improved law: forgetting time constant for the leakage sigma*L_s [s]',
    'stator_memory': 'improved law: forgetting time constant for the stator resistance R_s [s]',
    'didt_floor': 'improved law: current rate [A/s] of the information floor for the leakage',
    'i_floor': 'improved law: current [A] of the information floor (holds unexcited directions)',
    'phi_floor': 'improved law: flux [Wb] of the information floor',
    'L_sigma': 'improved law: initial (or fixed) leakage sigma*L_s [H] for the voltage-model '
               'rotor flux (0 = L_s - L_sr*theta_initial)',
    'L_sigma_min': 'projection: lower bound of the leakage estimate [H] (0 = L_sigma/4)',
    'L_sigma_max': 'projection: upper bound of the leakage estimate [H] (0 = 10*L_sigma)',
    'R_r_min': 'projection: lower bound of the R_r estimate [ohm]',
    'R_r_max': 'projection: upper bound of the R_r estimate [ohm]',
    'theta_min': 'projection: lower bound of the theta estimate',
    'theta_max': 'projection: upper bound of theta before the sigma bound',
    'sigma_min': 'projection: smallest model leakage factor 1 - theta*L_sr/L_s',
    'L_M_min': 'projection: lower bound of the L_M estimate [H]',
    'L_M_max': 'projection: upper bound of the L_M estimate [H]',
}
_RANGES = {
    'gamma_t': (0.0, 1e3), 'gamma_r': (0.0, 1e4), 'epsilon': (1e-9, 1e6),
    'flux_corner': (0.0, 1e3), 'flux_corner_ratio': (0.0, 100.0), 'flux_corner_min': (0.0, 1e3),
    'filter_corner': (1.0, 1e5), 'memory': (1e-4, 1e3),
    'leakage_memory': (1e-4, 1e4), 'stator_memory': (1e-4, 1e4), 'didt_floor': (1e-6, 1e6),
    'L_sigma_min': (0.0, 10.0), 'L_sigma_max': (0.0, 10.0),
    'i_floor': (1e-6, 1e3), 'phi_floor': (1e-9, 10.0), 'L_sigma': (0.0, 10.0),
    'R_r_min': (1e-6, 100.0), 'R_r_max': (1e-6, 100.0), 'theta_min': (1e-3, 10.0),
    'theta_max': (1e-3, 10.0), 'sigma_min': (1e-6, 0.999), 'L_M_min': (1e-6, 10.0),
    'L_M_max': (1e-6, 10.0),
}


def declare_law(node, params: MotorParams, R_r0: float, theta0: float) -> ParameterAdapter:
    """
    Declare the adaptation gains on ``node`` and return the adapter.

    Each is declared with ``node.param(name, default, description, lo, hi)``. Invalid values raise
    :class:`InvalidParameter` naming the parameter.
    """
    d = AdaptationGains()
    values = {
        'law': node.param('law', d.law, 'adaptation law', choices=list(LAWS)),
        'feed': node.param('feed', FEED_DEFAULT, 'what the controller and observer take: '
                           'inverse_gamma (L_sigma, L_M, R_R) or thesis_pair (R_r, theta); auto = '
                           'inverse_gamma for the improved law, thesis_pair for the thesis law',
                           choices=list(FEEDS)),
        'freeze': node.param('freeze', d.freeze, 'hold the estimates (signals keep running)'),
        'estimate_leakage': node.param('estimate_leakage', d.estimate_leakage,
                                       'improved law: estimate sigma*L_s too (else hold L_sigma)'),
        'estimate_stator_resistance': node.param(
            'estimate_stator_resistance', d.estimate_stator_resistance,
            'improved law, sensored: estimate R_s too (learnt below 100 rad/s stator frequency, '
            'where L_M is held; sensorless always estimates it)'),
        'start_offset': node.param('start_offset', d.start_offset,
                                   'improved law: estimate the start offset of the voltage-model '
                                   'flux of a drive started magnetised; auto = unless R_s is '
                                   'estimated', choices=list(START_OFFSETS)),
        'decimation': node.param('decimation', d.decimation,
                                 'update the estimates every N control periods', 1, 100000),
    }
    derived = d.resolve(params, theta0)       # defaults of the bounds derived from the motor
    for name, doc in _DOC.items():
        default = getattr(derived, name)
        if name in ('L_sigma', 'L_sigma_min', 'L_sigma_max'):
            default = 0.0                       # 0: derived (documented in the description)
        lo, hi = _RANGES[name]
        values[name] = float(node.param(name, float(default), doc, lo, hi))
    for name in ('L_sigma', 'L_sigma_min', 'L_sigma_max'):
        if values[name] == 0.0:
            values[name] = None
    return ParameterAdapter(params, AdaptationGains(**values), R_r0, theta0)
