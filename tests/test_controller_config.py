"""
The controller's configuration as one typed model (issue 45, item 1, the controller's slice).

``ControllerConfig`` is a pydantic model: each field's type, default, meaning and bounds, the
rules across fields as validators, every error one line naming the field. The controller node's
parameters are generated from it (``im_controller.parameters.declare_controller``): for every
field, the declared default, range, choices, live flag and sentinels are the model's.
"""
import math
from typing import get_args

from im_common.params import InvalidParameter, THESIS_MOTOR
from im_common.validation import literal_choices
from im_controller.control_law import (ControllerConfig, DriveController, FLUX_COUPLINGS,
                                       FluxCoupling, LIVE_FIELDS, Mode, MODES)
from im_controller.flux import STRATEGIES, Strategy
from im_controller.parameters import (config_from_parameters, declare_controller, live_changes,
                                      SENTINEL_DEFAULTS)
import pytest

#: the controller node's parameters and their defaults before they were generated from the
#: model (docs/parameters.md at 3e5a3cb): none may disappear or change its type or default
DECLARED_BEFORE = {
    'mode': 'position', 'profile': 'thesis', 'strategy': 'min_energy', 'phi_d': -1.0,
    'phi_min': -1.0, 'phi_max': -1.0, 'k1': 40.0, 'k_p': -1.0, 'k_v': -1.0, 'load_known': True,
    'load': 'pendulum', 'load_mgl': 10.0, 'load_c1': 1.0, 'load_c2': 0.001, 'load_tau': 0.0,
    'v_limit': -1.0, 'current_gain': [0.0], 'gain_period': 0.0, 'flux_coupling': 'cancel',
    'hold_compensation': True, 'torque_filter_bandwidth': 1000.0, 'flux_preview': -1.0,
    'core_loss_exponent': 2.0, 'setpoint_duration': 0.5, 'setpoints': [0.0],
    'torque_limit': 0.0, 'current_limit': -1.0, 'speed_limit': 0.0, 'field_weakening': True,
    'voltage_margin': 0.85, 'current_margin': 0.9}
#: the parameters added since, with their defaults (issue 43: the plant's computational delay)
ADDED_SINCE = {'delay': 0, 'law': 'thesis', 'drive_loss_r': 0.0, 'drive_loss_c': 0.0}


class RecordingNode:
    """A stand-in node: records each declaration, returns the default (or a value given)."""

    def __init__(self, **given):
        self.given = given
        self.declared = {}

    def param(self, name, default, description, lo=None, hi=None, read_only=True, choices=None):
        self.declared[name] = {'default': default, 'description': description, 'lo': lo,
                               'hi': hi, 'read_only': read_only, 'choices': choices}
        return self.given.get(name, default)


# The model's rules --------------------------------------------------------------------------
@pytest.mark.parametrize('kwargs,line', [
    ({'k1': True}, "invalid parameter 'k1' = True: must be a real number"),
    ({'k1': '40'}, "invalid parameter 'k1' = '40': must be a real number"),
    ({'phi_d': False}, "invalid parameter 'phi_d' = False: must be a real number"),
    ({'torque_limit': '5'}, "invalid parameter 'torque_limit' = '5': must be a real number"),
    ({'load_known': 'yes'}, "invalid parameter 'load_known' = 'yes': must be true or false"),
    ({'field_weakening': 1}, "invalid parameter 'field_weakening' = 1: must be true or false"),
    ({'current_gain': [[True, 0.0], [0.0, 1.0]]},
     "invalid parameter 'current_gain' = [[True, 0.0], [0.0, 1.0]]: must be a 2x2 matrix of "
     'numbers'),
    ({'core_loss_exponent': True},
     "invalid parameter 'core_loss_exponent' = True: must be a real number"),
    ({'strategy': 'fast'}, "invalid parameter 'strategy' = 'fast': must be one of min_energy, "
     'constant_flux, min_loss, optimal'),
    ({'mode': 'angle'}, "invalid parameter 'mode' = 'angle': must be one of position, speed, "
     'torque'),
    ({'flux_coupling': 'half'}, "invalid parameter 'flux_coupling' = 'half': must be one of "
     'cancel, thesis, none'),
    ({'load': 'spring'}, "invalid parameter 'load' = 'spring': must be one of none, constant, "
     'pendulum, linear'),
    ({'k1': -40.0}, "invalid parameter 'k1' = -40.0: must be > 0"),
    ({'k_p': -1.0}, "invalid parameter 'k_p' = -1.0: must be >= 0"),
    ({'k_p': 0.0}, "invalid parameter 'k_p' = 0.0: must be > 0 in position mode"),
    ({'mode': 'speed', 'k_v': 0.0}, "invalid parameter 'k_v' = 0.0: must be > 0 in speed mode"),
    ({'phi_d': math.inf}, "invalid parameter 'phi_d' = inf: must be finite"),
    ({'voltage_margin': 1.5}, "invalid parameter 'voltage_margin' = 1.5: must be <= 1"),
    ({'phi_min': 0.5, 'phi_max': 0.4}, "invalid parameter 'phi_max' = 0.4: must be >= phi_min = "
     '0.5'),
    ({'magnetizing_floor': 0.3}, "invalid parameter 'magnetizing_floor' = 0.3: must be <= "
     'phi_min = 0.2'),
    ({'current_limit': 10.0}, "invalid parameter 'current_limit' = 10.0: must exceed the "
     'magnetizing current phi_max/L_sr = 14.75 A (no torque would be left)'),
    ({'mode': 'torque'}, "invalid parameter 'profile' = 'thesis': the thesis profiles are "
     "position/speed trajectories; mode 'torque' needs profile 'setpoint'"),
    ({'core_loss_exponent': 3}, "invalid parameter 'core_loss_exponent' = 3: must be 1 or 2"),
    ({'params': 'thesis'}, "invalid parameter 'params' = 'thesis': must be a MotorParams"),
    ({'gain': 1.0}, "invalid parameter 'gain' = 1.0: unknown key (known: mode, "),
])
def test_a_bad_field_is_one_line_naming_it(kwargs, line):
    with pytest.raises(InvalidParameter) as err:
        ControllerConfig(**kwargs)
    assert str(err.value).startswith(line), str(err.value)
    assert '\n' not in str(err.value)


def test_the_defaults_that_depend_on_the_task_and_the_strategy():
    expected = {'position': (10.0, 1.0, 'pendulum'), 'speed': (1.0, 3.0, 'linear'),
                'torque': (0.0, 0.0, 'none')}
    for mode, (k_p, k_v, load) in expected.items():
        cfg = ControllerConfig(mode=mode, profile='thesis' if mode != 'torque' else 'setpoint')
        assert (cfg.k_p, cfg.k_v, cfg.load) == (k_p, k_v, load)
    assert ControllerConfig(mode='speed', k_p=2.0, load='none').k_p == 2.0
    assert ControllerConfig(mode='speed', k_p=2.0, load='none').load == 'none'
    previews = {s: ControllerConfig(strategy=s).flux_preview for s in STRATEGIES}
    assert previews == {'min_energy': 0.0, 'constant_flux': 0.0, 'min_loss': 0.06,
                        'optimal': 0.06}
    assert ControllerConfig(strategy='min_loss', flux_preview=0.0).flux_preview == 0.0
    cfg = ControllerConfig()            # no ratings: the thesis's flux levels, no limits
    assert (cfg.phi_d, cfg.phi_min, cfg.phi_max, cfg.v_limit, cfg.current_limit) == (
        1.2, 0.2, 1.2, None, None)
    assert cfg.magnetizing_floor == 0.1 * 0.2 and cfg.from_ratings == {}


def test_a_number_is_a_float_and_the_matrices_are_rows_of_floats():
    import numpy as np
    cfg = ControllerConfig(k1=40, core_loss_exponent=1, current_gain=np.eye(2) * 30,
                           flux_time_constants=[0.1, 0.001])
    assert type(cfg.k1) is float and cfg.core_loss_exponent == 1.0
    assert cfg.current_gain == [[30.0, 0.0], [0.0, 30.0]]
    assert all(type(x) is float for row in cfg.current_gain for x in row)
    assert cfg.flux_time_constants == (0.1, 0.001)


def test_a_change_is_validated_as_a_whole_and_keeps_the_old_configuration():
    cfg = ControllerConfig(mode='speed')
    with pytest.raises(InvalidParameter, match="^invalid parameter 'strategy' = 'fast': must be "
                       'one of'):
        cfg.replace(strategy='fast')
    assert cfg.strategy == 'min_energy'
    new = cfg.replace(k1=60.0)
    assert new is not cfg and (new.k1, cfg.k1) == (60.0, 40.0)
    assert (new.mode, new.k_p, new.k_v) == ('speed', 1.0, 3.0)
    ctl = DriveController(cfg)
    with pytest.raises(InvalidParameter, match="^invalid parameter 'strategy' = 'fast'"):
        ctl.reconfigure({'strategy': 'fast'})
    assert ctl.config is cfg
    ctl.reconfigure({'strategy': 'min_loss', 'k_p': None})
    assert ctl.config.strategy == 'min_loss' and ctl.config.k_p == 1.0


def test_each_vocabulary_has_one_home_and_its_type_is_the_fields():
    assert get_args(Strategy) == STRATEGIES
    assert get_args(Mode) == MODES and get_args(FluxCoupling) == FLUX_COUPLINGS
    fields = ControllerConfig.model_fields
    assert fields['strategy'].annotation is Strategy and fields['mode'].annotation is Mode
    assert fields['flux_coupling'].annotation is FluxCoupling


# The node's parameters, generated from the model -------------------------------------------
def test_every_parameter_is_declared_as_before():
    node = RecordingNode()
    values = declare_controller(node)
    assert {k: v['default'] for k, v in node.declared.items()} == dict(DECLARED_BEFORE,
                                                                       **ADDED_SINCE)
    for name, default in dict(DECLARED_BEFORE, **ADDED_SINCE).items():
        assert type(values[name]) is type(default), name


def test_each_declaration_is_its_fields():
    node = RecordingNode()
    declare_controller(node)
    fields = ControllerConfig.model_fields
    for name, info in fields.items():
        spec = info.json_schema_extra['parameter']
        if spec is None:
            assert name not in node.declared, name
            continue
        d = node.declared[name]
        assert d['default'] == spec.get('default', info.default), name
        assert (d['lo'], d['hi']) == spec['range'], name
        assert d['choices'] == literal_choices(info.annotation), name
        assert d['read_only'] == (name not in LIVE_FIELDS), name
        assert d['description'].startswith(info.description), name
        for given, _, meaning in spec['sentinels']:
            assert f': {meaning}' in d['description'], name
    # the one parameter that is no field: the period current_gain was designed for
    assert set(node.declared) - set(fields) == {'gain_period'}
    assert set(LIVE_FIELDS) <= set(node.declared)
    assert SENTINEL_DEFAULTS['k_p'] == 'per-mode default'
    assert set(SENTINEL_DEFAULTS) == {'phi_d', 'phi_min', 'phi_max', 'k_p', 'k_v', 'v_limit',
                                      'flux_preview', 'current_limit'}


def test_the_declared_defaults_are_the_models_defaults():
    values = declare_controller(RecordingNode())
    for motor in (THESIS_MOTOR, THESIS_MOTOR.with_values(rated_voltage_rms_line=220.0,
                                                         rated_current_rms=20.0)):
        from_node = config_from_parameters(motor, values, 1e-4)
        assert from_node.fields() == ControllerConfig(params=motor, T_s=1e-4).fields()


def test_each_sentinel_is_what_its_field_says_it_stands_for():
    values = declare_controller(RecordingNode())
    for name, info in ControllerConfig.model_fields.items():
        spec = info.json_schema_extra['parameter']
        for given, stands_for, _ in (spec or {}).get('sentinels', ()):
            cfg = config_from_parameters(THESIS_MOTOR, dict(values, **{name: given}), 1e-4)
            model = ControllerConfig(**{name: stands_for})
            assert getattr(cfg, name) == getattr(model, name), name
            if given == -1.0:
                with pytest.raises(InvalidParameter, match=f"^invalid parameter '{name}' = "
                                   r'-0\.5: must be >= 0, or -1'):
                    config_from_parameters(THESIS_MOTOR, dict(values, **{name: -0.5}), 1e-4)


def test_a_live_change_parses_through_the_model():
    values = declare_controller(RecordingNode())
    assert live_changes(THESIS_MOTOR, values, {'strategy': 'min_loss', 'torque_limit': 0.0},
                        1e-4) == {'strategy': 'min_loss', 'torque_limit': None}
    assert live_changes(THESIS_MOTOR, values, {'k_p': -1.0}, 1e-4) == {'k_p': 10.0}
    assert live_changes(THESIS_MOTOR, values, {'v_limit': -1.0}, 1e-4) == {'v_limit': None}
    with pytest.raises(InvalidParameter, match="^invalid parameter 'strategy' = 'fast': must be "
                       'one of min_energy'):
        live_changes(THESIS_MOTOR, values, {'strategy': 'fast'}, 1e-4)
    with pytest.raises(ValueError, match="'mode' is read-only"):
        live_changes(THESIS_MOTOR, values, {'mode': 'speed'}, 1e-4)
