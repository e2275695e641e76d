"""
ROS parameters of the plant node ↔ :class:`im_plant.plant_sim.PlantSimulator`.

Every plant parameter is declared here with a description and a range (the motor through
:func:`im_common.node_params.declare_motor`, so a motor file's ``/**`` section reaches it);
the node builds its simulator from the values with :func:`simulator_from_parameters`.
"""
from __future__ import annotations

from im_common.inverter import Inverter
from im_common.loads import LOAD_DEFAULTS, load_from_parameters, LOAD_KINDS
from im_common.model import stator_flux
from im_common.node_params import declare_block, declare_motor, declare_variation
from im_common.params import (ELECTRICAL_NAMES, InvalidParameter, MotorParams, ParameterSchedule,
                              RATED, SCHEDULES, Variation, variation_schedule)
from im_plant.plant_sim import DEFAULT_INVERTER_RATING, PlantSimulator
from im_plant.sensors import Sensors

STEPPING_MODES = ('lockstep', 'free_run')


def declare_plant(node) -> dict:
    """
    Declare the plant's parameters on ``node``.

    Return their values by name (``motor``: the validated :class:`MotorParams`).
    """
    p = node.param
    blocks: dict = {}
    v = {'motor': declare_motor(node, blocks=blocks, warn_defaults=True)}
    v.update(blocks)                            # the motor file's saturation, thermal
    _declare_variation(node, v)
    _declare_load(node, v)
    _declare_initial_state(node, v)
    _declare_limits(node, v)
    _declare_noise(node, v)
    v['max_substep'] = p('max_substep', 1e-4, 'longest RK4 sub-step inside a period [s]', 1e-7,
                         0.1)
    _declare_real_plant(node, v)
    _declare_stepping(node, v)
    _declare_publishing(node, v)
    return v


def _declare_variation(node, v: dict) -> None:
    """Declare the time variation of the true parameters (variation, variation_*)."""
    p = node.param
    v['variation'] = p('variation', 'none',
                       'time variation of the true parameters (schedule: the breakpoints of '
                       'variation.<parameter>.*; custom: one parameter varied as variation_kind '
                       'with the variation_* values below)',
                       choices=tuple(SCHEDULES) + ('schedule', 'custom'))
    v['variation_block'] = declare_variation(node)     # variation.<parameter>.*
    v['variation_parameter'] = p('variation_parameter', 'R_r', 'custom variation: which parameter',
                                 choices=ELECTRICAL_NAMES)
    v['variation_kind'] = p('variation_kind', 'ramp',
                            'custom variation: value(t) = offset + slope*t (ramp), offset + '
                            'amplitude*sin(omega*t) (sinusoid), offset (constant)',
                            choices=('constant', 'ramp', 'sinusoid'))
    v['variation_offset'] = p('variation_offset', 0.842, 'custom variation: offset [SI]', -1e6,
                              1e6)
    v['variation_slope'] = p('variation_slope', 0.0, 'custom variation: slope [SI/s]', -1e6, 1e6)
    v['variation_amplitude'] = p('variation_amplitude', 0.0, 'custom variation: amplitude [SI]',
                                 -1e6, 1e6)
    v['variation_omega'] = p('variation_omega', 0.0,
                             'custom variation: angular frequency [rad/s]', -1e6, 1e6)


def _declare_load(node, v: dict) -> None:
    """Declare the shaft load (load, load_*)."""
    p = node.param
    v['load'] = p('load', 'none', 'shaft load', choices=LOAD_KINDS)
    d = LOAD_DEFAULTS
    v['load_mgl'] = p('load_mgl', d['mgl'], 'pendulum load: m g l [N m]', -1e4, 1e4)
    v['load_c1'] = p('load_c1', d['c1'], 'linear load: c1 [N m]', -1e4, 1e4)
    v['load_c2'] = p('load_c2', d['c2'], 'linear load: c2 [N m s]', -1e3, 1e3)
    v['load_tau'] = p('load_tau', d['tau'], 'constant load torque [N m]', -1e4, 1e4)
    v['load_t'] = p('load_t', 0.0, 'step load: the instant of the step [s]', 0.0, 1e6)
    v['load_tau_before'] = p('load_tau_before', 0.0, 'step load: torque before load_t [N m]',
                             -1e4, 1e4)
    v['load_tau_after'] = p('load_tau_after', 0.0, 'step load: torque from load_t on [N m]',
                            -1e4, 1e4)
    v['load_points'] = p('load_points', [0.0, 0.0],
                         'schedule load: points t0, tau0, t1, tau1, ... [s, N m], piecewise '
                         'linear, a time given twice is a jump (docs/running.md)')
    v['load_offset'] = p('load_offset', 0.0,
                         "live: load torque added to the load's own [N m]; a change acts from "
                         'the next step boundary and is announced on /im/status', -1e4, 1e4,
                         read_only=False)


def _declare_initial_state(node, v: dict) -> None:
    """Declare the plant's initial state (shaft, locked rotor, current, flux)."""
    p = node.param
    v['theta0'] = p('theta0', 0.0, 'initial shaft position [rad]', -1e6, 1e6)
    v['omega0'] = p('omega0', 0.0, 'initial shaft speed [rad/s]', -1e5, 1e5)
    v['locked_rotor'] = p('locked_rotor', False,
                          'the shaft is held where it starts '
                          '(locked-rotor tests; omega0 must be 0)')
    v['initial_current'] = p('initial_current', [0.0, 0.0],
                             'initial stator current [i_alpha, i_beta] [A]')
    v['initial_flux'] = p('initial_flux', [0.0, 0.0],
                          'initial rotor flux [phi_alpha, phi_beta] [Wb]')


def _declare_limits(node, v: dict) -> None:
    """Declare the inverter's voltage limits and the protection's trips."""
    p = node.param
    v['v_limit'] = p('v_limit', -1.0, 'inverter voltage-vector limit [V] (0: no limit; -1: the '
                     "motor's rated voltage, no limit without one)", -1.0, 1e5)
    v['inverter_rating'] = p('inverter_rating', DEFAULT_INVERTER_RATING,
                             "the inverter's own voltage-vector limit [V]: a larger command trips "
                             'the plant to zero voltage (trip in the truth)', 1.0, 1e6)
    v['current_trip'] = p('current_trip', -1.0,
                          'protection: trip to zero voltage when |i_s| exceeds this [A] (0: off; '
                          "-1: 2 x the motor's rated current, off without one)", -1.0, 1e6)
    v['speed_trip'] = p('speed_trip', -1.0,
                        'protection: trip to zero voltage when |omega_r| exceeds this [rad/s] '
                        "(0: off; -1: 2 x the motor's rated speed, off without one)", -1.0, 1e6)


def _declare_noise(node, v: dict) -> None:
    """Declare the measurement noise."""
    p = node.param
    v['current_noise_std'] = p('current_noise_std', 0.0, 'std of current measurement noise [A]',
                               0.0, 1e3)
    v['speed_noise_std'] = p('speed_noise_std', 0.0, 'std of speed measurement noise [rad/s]',
                             0.0, 1e4)
    v['noise_seed'] = p('noise_seed', 0, 'seed of the measurement noise', 0, 2**31 - 1)


def _declare_real_plant(node, v: dict) -> None:
    """Declare the real plant's blocks (inverter.*, sensors.*) and the iron loss."""
    p = node.param
    # the run file's inverter and sensors blocks (docs/plant.md): <block>.enabled and one
    # parameter per field of the block's model; None when not enabled
    v['inverter'] = declare_block(node, Inverter, 'inverter',
                                  "the run file's inverter block, inverter.*: the switched "
                                  'inverter (V_dc, pwm_frequency) or the ideal voltage source '
                                  'with a computational delay (false: the ideal voltage source '
                                  'at once; docs/plant.md)')
    v['sensors'] = declare_block(node, Sensors, 'sensors',
                                 "real sensors, the run file's sensors block, sensors.* (false: "
                                 'the true state plus the noise above; docs/plant.md)')
    v['iron_loss'] = p('iron_loss', False,
                       'the core loss acts (an iron-loss branch dissipating the k_e, k_h loss); '
                       'false: booked only')


def _declare_stepping(node, v: dict) -> None:
    """Declare the stepping (lockstep, free_run) and the free_run lag and deadline watchdogs."""
    p = node.param
    v['mode'] = p('mode', 'lockstep', 'stepping', choices=STEPPING_MODES)
    v['max_lag'] = p('max_lag', 1.0,
                     'free_run: stop the run when the plant is this far behind the wall clock '
                     '[s] (it cannot integrate in real time; 0: never)', 0.0, 3600.0)
    v['force_rate'] = p('force_rate', False,
                        'free_run: start even when the pre-flight probe measures a loop latency '
                        'this machine cannot hold at 1/T_s (refused otherwise, naming the rate it '
                        'holds); the deadline watchdog still stops a loop that misses')
    v['deadline_miss_limit'] = p('deadline_miss_limit', 0.5,
                                 'free_run: stop the run with zero voltage when more than this '
                                 'fraction of the last deadline_window steps had no command by '
                                 'their deadline (0: never)', 0.0, 1.0)
    v['deadline_window'] = p('deadline_window', 100,
                             "free_run: the deadline watchdog's window [steps]", 1, 1000000)


def _declare_publishing(node, v: dict) -> None:
    """Declare the decimation of /clock and the ground truth."""
    p = node.param
    v['clock_decimation'] = p('clock_decimation', 10,
                              'publish /clock every N steps (the '
                              'lock-step protocol runs on stamps; '
                              '/clock drives sim time for timers and tools)', 1, 1000000)
    v['truth_decimation'] = p('truth_decimation', 10,
                              'publish ground truth every N steps (0: never); the last step is '
                              'always published', 0, 1000000)


#: plant parameters whose -1 (the default) stands for the motor's rating
#: (:func:`im_common.params.default_limits`; off without one)
PROTECTION_FROM_RATINGS = ('v_limit', 'current_trip', 'speed_trip')


def simulator_from_parameters(values: dict, T_s: float, duration: float = 0.0) -> PlantSimulator:
    """
    Build the plant simulator from declared parameter values (0 = off for limits and trips).

    ``duration`` > 0 validates the parameter schedule over the run.
    """
    motor: MotorParams = values['motor']
    v = dict(values)
    for key in PROTECTION_FROM_RATINGS:
        if v[key] == -1.0:
            v[key] = RATED                  # PlantSimulator takes the motor's rating
        elif v[key] < 0:
            raise ValueError(f"invalid parameter '{key}' = {v[key]!r}: must be >= 0, or -1 for "
                             f"the motor's rating")
        elif v[key] == 0:
            v[key] = None
    block = v.get('variation_block')
    if v['variation'] == 'schedule':
        if block is None:
            raise InvalidParameter('variation', 'schedule', 'takes the breakpoints of '
                                   'variation.<parameter>.*, but no variation.<parameter>.enabled '
                                   'is true')
        schedule = variation_schedule(motor, block)
    elif block is not None:             # breakpoints given that would act on nothing
        name = next(iter(block.parts()))
        raise InvalidParameter(f'variation.{name}.enabled', True,
                               f"variation is '{v['variation']}', not schedule: set variation "
                               f'schedule, or leave variation.{name}.* out')
    if v['variation'] == 'custom':
        schedule = ParameterSchedule(motor, {v['variation_parameter']: Variation(
            v['variation_kind'], v['variation_offset'], slope=v['variation_slope'],
            amplitude=v['variation_amplitude'], omega=v['variation_omega'])}, name='custom')
    elif v['variation'] != 'schedule':
        schedule = SCHEDULES[v['variation']](motor)
    if duration > 0:
        schedule.validate(duration)
    i0, f0 = list(v['initial_current']), list(v['initial_flux'])
    x0 = None
    if any(i0) or any(f0):
        if len(i0) != 2 or len(f0) != 2:
            raise ValueError("invalid parameter 'initial_current'/'initial_flux': two "
                             'values each (alpha, beta)')
        P0 = schedule.params_at(0.0)
        psi = stator_flux(i0[0], i0[1], f0[0], f0[1], P0.L_s, P0.L_r, P0.L_sr)
        x0 = (psi[0], psi[1], f0[0], f0[1], v['theta0'], v['omega0'])
    load = load_from_parameters(v)
    sim = PlantSimulator(schedule, load, T_s, **real_plant_blocks(v, motor),
                         max_substep=v['max_substep'],
                         v_limit=v['v_limit'],
                         current_noise_std=v['current_noise_std'],
                         speed_noise_std=v['speed_noise_std'], noise_seed=v['noise_seed'],
                         theta0=v['theta0'], omega0=v['omega0'], x0=x0,
                         inverter_rating=v['inverter_rating'],
                         current_trip=v['current_trip'],
                         speed_trip=v['speed_trip'],
                         locked_rotor=v['locked_rotor'])
    sim.set_load_offset(v['load_offset'])
    return sim


def real_plant_blocks(values: dict, motor: MotorParams) -> dict:
    """
    Return the PlantSimulator keywords of the real plant's blocks in the parameter values.

    ``inverter``, ``sensors`` and the motor's ``thermal`` as :func:`declare_plant` parsed them
    (an Inverter, a Sensors, a Thermal or None), the motor's ``saturation`` as the curve of its
    SaturationBlock on the motor's L_M.
    """
    out = {'iron_loss': bool(values.get('iron_loss', False))}
    for name in ('inverter', 'sensors', 'thermal'):
        if values.get(name) is not None:
            out[name] = values[name]
    if values.get('saturation') is not None:
        out['saturation'] = values['saturation'].curve(motor.L_M)
    return out
