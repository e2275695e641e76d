"""
The observer's and the adapter's configuration models and the node parameters declared from them.

:class:`im_observer.parameters.ObserverConfig` and :class:`im_adapt.parameters.AdapterConfig`
(issue 45): the parameters a node declares (through a stand-in with ``param``) have the model's
defaults, a bad value is refused in one line naming the parameter, and values go from parameters
to the model and back unchanged. ROS-free.
"""
from im_adapt.adaptation import AdaptationGains
from im_adapt.parameters import AdapterConfig, declare_law
from im_common.node_params import model_arguments
from im_common.params import InvalidParameter, THESIS_MOTOR
from im_observer.parameters import declare_observer, observer_config, ObserverConfig
import pytest

CH4 = THESIS_MOTOR.with_values(L_s=0.084, L_sr=0.081, L_r=0.081 / 0.952941)
THETA0 = 0.952941


class FakeNode:
    """Records ``param`` calls like LockstepNode.param; returns the values given, else defaults."""

    def __init__(self, **given):
        self.given = given
        self.declared = {}

    def param(self, name, default, description, lo=None, hi=None, read_only=True, choices=None):
        assert description and name not in self.declared, name
        self.declared[name] = {'default': default, 'lo': lo, 'hi': hi, 'read_only': read_only,
                               'choices': choices}
        return self.given.get(name, default)


def _defaults(node) -> dict:
    return {name: d['default'] for name, d in node.declared.items()}


def _parameters(cfg) -> dict:
    """Return a configuration's node parameters: None back to its sentinel, a tuple a list."""
    out = {}
    for name, info in type(cfg).model_fields.items():
        value = getattr(cfg, name)
        for given, stands_for, _ in info.json_schema_extra['parameter']['sentinels']:
            if value == stands_for:
                value = given
                break
        out[name] = list(value) if isinstance(value, tuple) else value
    return out


def _fields(cfg) -> dict:
    return {name: getattr(cfg, name) for name in type(cfg).model_fields}


def test_observer_declares_one_read_only_parameter_per_field_with_its_default():
    node = FakeNode()
    values = declare_observer(node)
    assert list(node.declared) == list(ObserverConfig.model_fields)
    assert all(d['read_only'] for d in node.declared.values())
    assert values == _defaults(node)
    # the sentinels as the node declares them; the model's defaults are what they stand for
    assert values['k_e_injection'] == 0.0 and values['injection_gain'] == [0.0]
    assert values['initial_state'] == [0.0, 0.0, 0.0, 0.0]
    assert isinstance(values['estimate_decimation'], int)
    assert node.declared['max_substep']['lo'] == 1e-7
    assert _fields(observer_config(values, 1e-4)) == _fields(ObserverConfig())
    assert _parameters(ObserverConfig()) == values


@pytest.mark.parametrize('given, name', [
    ({'injection_gain': [1.0] * 5, 'gain_period': 1e-4}, 'injection_gain'),
    ({'initial_state': [0.0, 0.0, 1.0]}, 'initial_state'),
    ({'initial_state': 1.0}, 'initial_state'),
    ({'injection_gain': [1.0] * 8, 'gain_period': 2e-4}, 'gain_period'),
    ({'use_adapter': 'yes'}, 'use_adapter'),
    ({'estimate_decimation': 2.5}, 'estimate_decimation'),
])
def test_observer_refuses_a_bad_value_naming_it(given, name):
    with pytest.raises(InvalidParameter, match=f"^invalid parameter '{name}' = ") as err:
        observer_config(declare_observer(FakeNode(**given)), 1e-4)
    assert '\n' not in str(err.value)


def test_observer_parameters_round_trip():
    given = {'k_e_injection': 3.5, 'injection_gain': [float(x) for x in range(1, 9)],
             'gain_period': 1e-4, 'use_adapter': True, 'initial_state': [0.1, -0.2, 0.3, 0.4],
             'sensorless': True, 'initial_speed': 12.0, 'max_substep': 5e-5,
             'estimate_decimation': 3}
    cfg = observer_config(declare_observer(FakeNode(**given)), 1e-4)
    assert cfg.injection_gain == tuple(given['injection_gain']) and cfg.k_e_injection == 3.5
    assert _parameters(cfg) == given
    back = observer_config(declare_observer(FakeNode(**_parameters(cfg))), 1e-4)
    assert _fields(back) == _fields(cfg)
    # the sentinels: 0 is the thesis k_e, [0.0] no injection gain
    none = observer_config(declare_observer(FakeNode(k_e_injection=0.0)), 1e-4)
    assert none.k_e_injection is None and none.injection_gain is None


def test_adapter_declares_one_read_only_parameter_per_field_with_its_default():
    model = AdapterConfig.for_motor(CH4, THETA0)
    node = FakeNode()
    law = declare_law(node, CH4, 0.842, THETA0)
    assert list(node.declared) == list(AdapterConfig.model_fields)
    assert set(AdapterConfig.model_fields) == set(AdaptationGains.__dataclass_fields__)
    assert all(d['read_only'] for d in node.declared.values())
    assert node.declared['law']['choices'] == ('thesis', 'improved')
    defaults = _defaults(node)
    assert _fields(model(**model_arguments(model, defaults))) == _fields(model())
    assert _parameters(model()) == defaults
    # the adaptation's own defaults; the motor-derived bounds the motor's
    assert defaults['feed'] == 'auto' and defaults['L_sigma'] == 0.0
    assert model().gains() == AdaptationGains(R_r_min=0.25 * CH4.R_r, R_r_max=4.0 * CH4.R_r,
                                              L_M_min=model().L_M_min, L_M_max=model().L_M_max)
    assert defaults['R_r_min'] == pytest.approx(0.25 * CH4.R_r)
    assert defaults['L_M_max'] == pytest.approx(2.0 * CH4.L_sr ** 2 / CH4.L_r)
    assert law.gains == AdaptationGains().resolve(CH4, THETA0)
    assert AdapterConfig().R_r_min is None      # without a motor: derived by the adaptation


@pytest.mark.parametrize('given, name', [
    ({'R_r_min': 50.0}, 'R_r_min'),
    ({'law': 'lms'}, 'law'),
    ({'freeze': 'yes'}, 'freeze'),
    ({'law': 'thesis', 'feed': 'inverse_gamma'}, 'feed'),
    ({'theta_min': 1.0}, 'theta_min'),
    ({'decimation': 0}, 'decimation'),
])
def test_adapter_refuses_a_bad_value_naming_it(given, name):
    model = AdapterConfig.for_motor(CH4, THETA0)
    node = FakeNode()
    declare_law(node, CH4, 0.842, THETA0)
    with pytest.raises(InvalidParameter, match=f"^invalid parameter '{name}' = ") as err:
        model(**model_arguments(model, dict(_defaults(node), **given)))
    assert '\n' not in str(err.value)


def test_adapter_parameters_round_trip():
    given = {'law': 'improved', 'feed': 'thesis_pair', 'freeze': True, 'decimation': 4,
             'gamma_t': 0.5, 'L_sigma': 0.006, 'L_sigma_min': 0.002, 'R_r_max': 2.5,
             'start_offset': 'off', 'estimate_stator_resistance': True}
    model = AdapterConfig.for_motor(CH4, THETA0)
    node = FakeNode(**given)
    law = declare_law(node, CH4, 0.9, THETA0)
    cfg = model(**model_arguments(model, dict(_defaults(node), **given)))
    params = _parameters(cfg)
    assert {k: params[k] for k in given} == given
    assert params == dict(_defaults(node), **given)
    assert _fields(model(**model_arguments(model, params))) == _fields(cfg)
    assert cfg.L_sigma_max is None      # 0: ten times L_sigma, derived by the adaptation
    assert law.gains == cfg.gains().resolve(CH4, THETA0)
    assert law.gains.L_sigma_max == pytest.approx(0.06)
