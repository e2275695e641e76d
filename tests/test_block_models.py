"""
The run file's inverter and sensors blocks as typed models (issue 45, item 1).

``im_common.inverter.Inverter`` and ``im_plant.sensors.Sensors`` are pydantic models: their
rules (bounds, types, the rules across fields) in one place, their errors the run file's one
line (``im_common.validation.parse_block``); a Scenario parses a block once and keeps the model;
the plant node takes the block as typed parameters ``inverter.<field>``, ``sensors.<field>``
(``im_common.node_params.declare_block``), never as JSON text, and gives the model back equal.
"""
import dataclasses
import math

from im_bringup.run_file import Scenario
from im_common.host import build_node
from im_common.inverter import Inverter
from im_common.node_params import block_parameters, ConfigurationError
from im_common.validation import InvalidParameter
from im_plant.plant_node import PlantNode
from im_plant.sensors import Sensors
from pydantic import ValidationError
import pytest
from rclpy.parameter import Parameter

INV = {'V_dc': 340.0, 'pwm_frequency': 10000.0}
RUN = """task: speed
duration: 0.05
inverter: {V_dc: 340.0, pwm_frequency: 10000.0, deadtime: 2.0e-6, v_on: 1.0, r_on: 0.02,
           C_dc: 0.001, V_chopper: 380.0, V_trip: 400.0}
sensors: {encoder_lines: 2048, adc_bits: 12, current_range: 40.0,
          current_offset: [0.01, 0.0, -0.01], current_gain: 1.01}
"""


def _refused(cls, spec):
    with pytest.raises(InvalidParameter) as err:
        cls.from_block(spec)
    text = str(err.value)
    assert '\n' not in text, text
    return text


# The models' rules -----------------------------------------------------------------------
@pytest.mark.parametrize('spec, line', [
    (dict(INV, V_dc=True), "'inverter.V_dc' = True: must be a real number"),
    (dict(INV, V_dc='340'), "'inverter.V_dc' = '340': must be a real number"),
    (dict(INV, V_dc=math.nan), "'inverter.V_dc' = nan: must be finite"),
    (dict(INV, V_dc=-1.0), "'inverter.V_dc' = -1.0: must be > 0"),
    (dict(INV, v_on=-0.5), "'inverter.v_on' = -0.5: must be >= 0"),
    ({'V_dc': 340.0}, "'inverter.pwm_frequency' = None: is missing"),
    (dict(INV, bogus=1), "'inverter.bogus' = 1: unknown key (known: V_dc, pwm_frequency, "),
    (dict(INV, update='triple'), "'inverter.update' = 'triple': must be one of single, double"),
    (dict(INV, deadtime=2e-5), "'inverter.deadtime' = 2e-05: longer than a tenth of the PWM "
                               'period'),
    (dict(INV, C_dc=1e-3, V_trip=300.0), "'inverter.V_trip' = 300.0: must be above V_dc"),
    (dict(INV, C_dc=1e-3, V_chopper=500.0), "'inverter.V_chopper' = 500.0: must lie between"),
    ([340.0], "'inverter' = [340.0]: must be a mapping of V_dc, pwm_frequency, delay, deadtime, "),
])
def test_the_inverter_refuses_in_one_line_naming_the_key(spec, line):
    assert line in _refused(Inverter, spec)


@pytest.mark.parametrize('spec, line', [
    ({'encoder_lines': 0}, "'sensors.encoder_lines' = 0: an encoder needs >= 1 line"),
    ({'encoder_lines': 1024.0}, "'sensors.encoder_lines' = 1024.0: must be a whole number"),
    ({'adc_bits': True}, "'sensors.adc_bits' = True: must be a whole number"),
    ({'adc_bits': 0}, "'sensors.adc_bits' = 0: an ADC needs >= 1 bit"),
    ({'adc_bits': 33}, "'sensors.adc_bits' = 33: must be <= 32"),
    ({'speed_window': 0}, "'sensors.speed_window' = 0: must be >= 1"),
    ({'current_range': 'x'}, "'sensors.current_range' = 'x': must be a real number"),
    ({'current_gain': [1.0, 0.0, 1.0]}, "'sensors.current_gain' = [1.0, 0.0, 1.0]: must be > 0"),
    ({'current_gain': [1.0, 1.0]}, "'sensors.current_gain' = [1.0, 1.0]: must be one number or "
                                   'three (phases a, b, c)'),
    ({'current_offset': [0.0, False, 0.0]}, "'sensors.current_offset' = [0.0, False, 0.0]: must "
                                            'be a real number'),
])
def test_the_sensors_refuse_in_one_line_naming_the_key(spec, line):
    assert line in _refused(Sensors, spec)


def test_the_models_take_what_a_run_file_writes_and_describe_it_back():
    inv = Inverter.from_block({'V_dc': 340, 'pwm_frequency': 10000, 'update': 'double'})
    assert inv.V_dc == 340.0 and isinstance(inv.V_dc, float) and inv.T_s == 0.5e-4
    assert Inverter.from_block(inv.describe()) == inv and list(inv.describe())[:2] == [
        'V_dc', 'pwm_frequency']
    se = Sensors.from_block({'encoder_lines': 1024, 'current_gain': 1.02})
    assert se.current_gain == (1.02, 1.02, 1.02) and se.counts_per_rev == 4096
    # an ideal encoder and ADC are left out, as the run file leaves them out
    assert se.describe() == {'encoder_lines': 1024, 'speed_window': 10, 'current_range': 50.0,
                             'current_offset': [0.0, 0.0, 0.0], 'current_gain': [1.02] * 3,
                             'vdc_range': 1000.0}
    assert Sensors.from_block(se.describe()) == se
    assert Sensors.from_block({}).adc(0.3, -1.0, 1.0) == 0.3        # 0 bits: ideal
    with pytest.raises(ValidationError):        # frozen
        inv.V_dc = 1.0


# Parsed once -----------------------------------------------------------------------------
def test_a_scenario_parses_each_block_once_and_keeps_the_model(monkeypatch):
    calls = []
    for cls in (Inverter, Sensors):
        real = cls.model_validate
        monkeypatch.setattr(cls, 'model_validate',
                            lambda spec, _real=real, _cls=cls: calls.append(_cls) or _real(spec))
    sc = Scenario(task='speed', duration=0.05, inverter=dict(INV, deadtime=2e-6),
                  sensors={'adc_bits': 12}, compensation='inverter')
    assert isinstance(sc.inverter, Inverter) and isinstance(sc.sensors, Sensors)
    sc.node_parameters()
    rec = sc.to_mapping()
    dataclasses.replace(sc, duration=0.1)
    assert sorted(c.__name__ for c in calls) == ['Inverter', 'Sensors']
    assert rec['inverter'] == sc.inverter.describe() and rec['sensors'] == {
        'adc_bits': 12, 'speed_window': 10, 'current_range': 50.0,
        'current_offset': [0.0, 0.0, 0.0], 'current_gain': [1.0, 1.0, 1.0], 'vdc_range': 1000.0}
    assert Scenario.from_mapping(rec) == sc


# The plant node's parameters -------------------------------------------------------------
def _plant(context, values):
    return build_node(PlantNode, context=context,
                      parameter_overrides=[Parameter(k, value=v) for k, v in values.items()])


def test_run_file_to_plant_node_parameters_gives_the_models_back(context, tmp_path):
    path = tmp_path / 'run.yaml'
    path.write_text(RUN)
    sc = Scenario.from_file(str(path))
    params = sc.node_parameters()['plant']
    assert params['inverter.enabled'] is True and params['inverter.C_dc'] == 0.001
    assert params['sensors.current_gain'] == [1.01, 1.01, 1.01]
    node = _plant(context, params)
    try:
        assert node.sim.real.inverter == sc.inverter
        assert node.sim.real.sensors == sc.sensors
        assert sc.inverter == Inverter.from_block(sc.to_mapping()['inverter'])
    finally:
        node.destroy_node()
    ideal = _plant(context, Scenario(task='speed').node_parameters()['plant'])
    try:
        assert ideal.sim.real is None
    finally:
        ideal.destroy_node()


def test_a_parameters_file_may_nest_a_block_as_ros_2_reads_it(context, tmp_path):
    """A ``ros__parameters`` block written nested is read as its dotted names, as rcl reads it."""
    from im_common.yamlio import load_parameters_file
    flat = tmp_path / 'flat.yaml'
    flat.write_text('plant:\n  ros__parameters:\n    inverter.enabled: true\n'
                    '    inverter.V_dc: 400.0\n    inverter.pwm_frequency: 10000.0\n'
                    '    inverter.deadtime: 2.0e-6\n')
    nested = tmp_path / 'nested.yaml'
    nested.write_text('plant:\n  ros__parameters:\n    inverter:\n      enabled: true\n'
                      '      V_dc: 400.0\n      pwm_frequency: 10000.0\n'
                      '      deadtime: 2.0e-6\n')
    values = load_parameters_file(str(nested), nodes=['plant'])
    assert values == load_parameters_file(str(flat), nodes=['plant'])
    node = _plant(context, values['plant'])
    try:
        assert node.sim.real.inverter == Inverter(V_dc=400.0, pwm_frequency=1e4, deadtime=2e-6)
    finally:
        node.destroy_node()


def test_the_plant_declares_no_json_text_for_the_blocks(context):
    node = build_node(PlantNode, context=context)
    try:
        names = node.list_parameters([], 0).names
        assert 'inverter' not in names and 'sensors' not in names
        mine = [n for n in names if n.startswith(('inverter.', 'sensors.'))]
        assert {n.split('.', 1)[1] for n in mine if n.startswith('inverter.')} == \
            set(Inverter.model_fields) | {'enabled'}
        assert {n.split('.', 1)[1] for n in mine if n.startswith('sensors.')} == \
            set(Sensors.model_fields) | {'enabled'}
        strings = [n for n in mine if isinstance(node.get_parameter(n).value, str)]
        assert strings == ['inverter.update']       # a choice (single, double), not JSON
        assert node.get_parameter('sensors.current_gain').type_ == Parameter.Type.DOUBLE_ARRAY
        assert node.get_parameter('sensors.encoder_lines').type_ == Parameter.Type.INTEGER
        assert node.describe_parameter('inverter.deadtime').description.startswith(
            'inverter: dead time t_d [s]')
    finally:
        node.destroy_node()


def test_block_parameters_are_every_field_flattened():
    inv = Inverter.from_block(INV)
    out = block_parameters(inv, 'inverter')
    assert out.pop('inverter.enabled') is True
    # every field, those not given (None) at their parameter's sentinel 0
    assert out == {f'inverter.{k}': 0.0 if v is None else v
                   for k, v in inv.model_dump().items()}


@pytest.mark.parametrize('given, line', [
    ({'inverter.enabled': True, 'inverter.V_dc': 340.0, 'inverter.pwm_frequency': 1e4,
      'inverter.deadtime': 2e-5}, "invalid parameter 'inverter.deadtime' = 2e-05: longer than"),
    ({'inverter.enabled': True, 'inverter.pwm_frequency': 1e4},
     "invalid parameter 'inverter.V_dc' = None: is missing: V_dc and pwm_frequency make the "
     'switched inverter together'),
    ({'inverter.enabled': True, 'inverter.V_dc': 340.0, 'inverter.pwm_frequency': 1e4,
      'inverter.v_on': -1.0}, "invalid parameter 'inverter.v_on' = -1.0: must be >= 0"),
    ({'inverter.V_dc': 'x'}, "invalid parameter 'inverter.V_dc' = 'x' for node 'plant': must be "
                             'a real number'),
    ({'inverter.enabled': True, 'inverter.V_dc': 340.0, 'inverter.pwm_frequency': 1e4,
      'inverter.update': 'triple'}, "invalid parameter 'inverter.update' = 'triple' for node"),
    ({'sensors.enabled': True, 'sensors.encoder_lines': -1},
     "invalid parameter 'sensors.encoder_lines' = -1: an encoder needs >= 1 line"),
    ({'sensors.enabled': True, 'sensors.current_gain': [1.0, 0.0, 1.0]},
     "invalid parameter 'sensors.current_gain' = [1.0, 0.0, 1.0]: must be > 0"),
    ({'sensors.enabled': True, 'sensors.current_offset': [0.1, 0.2]},
     "invalid parameter 'sensors.current_offset' = [0.1, 0.2]: must be one number or three"),
    ({'inverter.V_dc': 540.0, 'inverter.pwm_frequency': 1e4},      # the block left off
     "invalid parameter 'inverter.V_dc' = 540.0: set, but inverter.enabled is false"),
])
def test_a_bad_block_parameter_on_the_plant_is_one_line_naming_it(context, given, line):
    with pytest.raises(ConfigurationError) as err:
        _plant(context, given)
    text = str(err.value)
    assert line in text and '\n' not in text, text
