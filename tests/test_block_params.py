"""
The real plant's blocks and the variation as typed node parameters: no JSON (issue 45, item 1).

The motor's saturation and thermal blocks, the drive's curve and the variation are typed node
parameters: no node parameter holds JSON or YAML text.

Each block is one pydantic model (``im_common.saturation.SaturationBlock``,
``im_common.thermal.Thermal``, ``im_common.params.ParameterVariation``) whose fields are the
nodes' flat parameters (``saturation.beta``, ``thermal.C_s``, ``saturation_model.table_psi``,
``variation.R_r.points``; ``im_common.node_params.declare_block``). A run file's block becomes
those parameters (``Scenario.node_parameters``) and the node gives the identical model back; a
bad value is one line naming the parameter; a motor file's nested mapping is what a node takes.
"""
from im_adapt.adapter_node import AdapterNode
from im_bringup.run_file import Scenario
from im_common.host import build_node
from im_common.node_params import (block_from_parameters, block_parameters, ConfigurationError,
                                   variation_from_parameters, variation_parameters)
from im_common.params import (describe_variation, load_motor_blocks, normalize_variation,
                              ParameterVariation, shipped_motors_dir, THESIS_MOTOR,
                              variation_block, variation_schedule)
from im_common.saturation import saturation_block, saturation_from_dict, SaturationBlock
from im_common.thermal import Thermal, thermal_from_dict
from im_controller.controller_node import ControllerNode
from im_observer.observer_node import ObserverNode
from im_plant.plant_node import PlantNode
import pytest
from rclpy.parameter import Parameter
import yaml

THERMAL = {'C_s': 1000.0, 'R_th_s': 1.0, 'C_r': 400.0, 'R_th_r': 0.6, 'T_ambient': 30.0,
           'T0_r': 60.0, 'alpha_s': 0.004}
LAW = {'law': 'power', 'beta': 1.439, 'S': 7.0}
TABLE = {'table': [[0.2, 2.6], [0.4, 5.4], [0.5, 7.2]]}
#: every form of a breakpoint variation: scale and value levels, step and ramp, sine terms
#: (one written before a breakpoint: the schedule adds the sines whatever their place)
VARIATION = {
    'R_r': [{'t': 0.0, 'scale': 1.0}, {'t': 0.2, 'scale': 1.5, 'shape': 'ramp'},
            {'t': 0.3, 'scale': 1.2, 'shape': 'step'}],
    'L_sr': [{'sine': 0.0005, 'frequency': 2.0, 'phase': 0.5},
             {'t': 0.1, 'value': 0.083, 'shape': 'ramp'}],
    'R_s': [{'sine': 0.01, 'frequency': 5.0}],
}


def _node(cls, context, values):
    return build_node(cls, context=context,
                      parameter_overrides=[Parameter(k, value=v) for k, v in values.items()])


def _one_line(cls, context, values):
    with pytest.raises(ConfigurationError) as err:
        _node(cls, context, values)
    text = str(err.value)
    assert '\n' not in text, text
    return text


# Round trips, ROS-free ---------------------------------------------------------------------
@pytest.mark.parametrize('model, spec, parse, prefix', [
    (Thermal, THERMAL, thermal_from_dict, 'thermal'),
    (Thermal, {k: THERMAL[k] for k in ('C_s', 'R_th_s', 'C_r', 'R_th_r')}, thermal_from_dict,
     'thermal'),
    (SaturationBlock, LAW, saturation_block, 'saturation'),
    (SaturationBlock, TABLE, saturation_block, 'saturation_model'),
])
def test_a_block_round_trips_through_its_parameters(model, spec, parse, prefix):
    block = parse(spec)
    params = block_parameters(block, prefix)
    assert params[f'{prefix}.enabled'] is True
    assert not any(isinstance(v, str) and '{' in v for v in params.values())     # no text
    assert all(v != [] for v in params.values())        # ROS reads an empty array as no value
    back = block_from_parameters(model, params, prefix)
    assert back == block and back.describe() == block.describe()
    assert parse(block.describe()) == block             # the record's form parses to it too


def test_the_variation_round_trips_through_its_parameters():
    block = variation_block(VARIATION)
    params = variation_parameters(block)
    assert params['variation.R_r.points'] == [0.0, 1.0, 0.2, 1.5, 0.3, 1.2]
    assert params['variation.R_r.shape'] == ['step', 'ramp', 'step']
    assert params['variation.L_sr.by'] == 'value' and params['variation.R_r.by'] == 'scale'
    assert params['variation.R_s.points'] == [0.0]          # sines only: no breakpoint
    assert params['variation.R_s.sines'] == [0.01, 5.0, 0.0]
    assert 'variation.L_s.enabled' not in params            # not varied
    back = variation_from_parameters(params)
    assert back == block
    # the run file's mapping back, each parameter's breakpoints before its sine terms
    want = {k: sorted(v, key=lambda i: 'sine' in i) for k, v in
            normalize_variation(VARIATION).items()}
    assert back.spec() == want and variation_block(back.spec()) == block
    assert describe_variation(back) == describe_variation(VARIATION)
    # the same numbers, bit for bit, from the parameters as from the run file's mapping
    a = variation_schedule(THESIS_MOTOR, VARIATION)
    b = variation_schedule(THESIS_MOTOR, back)
    for t in (0.0, 0.05, 0.1, 0.15, 0.2, 0.25, 0.3, 0.7):
        assert a.values(t) == b.values(t) and a.inductance_rates(t) == b.inductance_rates(t)
    assert variation_from_parameters({}) is None


@pytest.mark.parametrize('spec, line', [
    ({'law': 'power', 'beta': -0.5, 'S': 7.0}, "'saturation.beta' = -0.5: must be >= 0"),
    ({'law': 'power', 'beta': 1.4}, "'saturation.S' = None: is missing"),
    ({'law': 'cubic', 'beta': 1.4, 'S': 7.0}, "'saturation.law' = 'cubic': must be one of power"),
    ({'table_psi': [0.2, 0.4], 'table_i_M': [2.0]}, "'saturation.table_i_M' = [2.0]: must list"),
    ({'table_psi': [0.2, 0.4], 'table_i_M': [2.0, 1.0]},
     "'saturation.table_psi[1]' = [0.4, 1.0]: the magnetizing curve is not monotonic"),
    ({'table': [[0.3, 4.0], [0.2, 5.0]]}, "'saturation.table[1]' = [0.2, 5.0]: the magnetizing"),
    ({'table': [[0.3, 4.0], [0.5, 5.0]], 'S': 7.0}, "'saturation.table' = '...': give either"),
    ({'table_psi': [0.3, 0.5], 'table_i_M': [4.0, 5.0], 'beta': 1.0},
     "'saturation.beta' = 1.0: give either a table or a law"),
])
def test_a_bad_saturation_block_is_one_line_naming_the_key(spec, line):
    with pytest.raises(Exception) as err:
        saturation_from_dict(spec, THESIS_MOTOR.L_M)
    assert line in str(err.value) and '\n' not in str(err.value), str(err.value)


@pytest.mark.parametrize('spec, line', [
    ({'points': [0.0, 1.0, 0.5]}, "'variation.R_r.points' = [0.0, 1.0, 0.5]: must be (t, level) "
                                  'pairs'),
    ({'points': [0.5, 1.0, 0.2, 1.1]}, 't = 0.2 s of breakpoint 1 must be after the previous'),
    ({'points': [-1.0, 1.0]}, 't = -1 s of breakpoint 0 must be >= 0'),
    ({'points': [0.0, 1.0], 'shape': ['jump']}, "'variation.R_r.shape' = ['jump']: must be step "
                                                'or ramp'),
    ({'points': [0.0, 1.0], 'shape': ['step', 'ramp']}, "'variation.R_r.shape' = ['step', 'ramp']"
                                                        ': must give one shape per breakpoint'),
    ({'sines': [0.1, 2.0]}, "'variation.R_r.sines' = [0.1, 2.0]: must be (amplitude, frequency"),
    ({'sines': [0.1, 0.0, 0.0]}, 'the frequency 0 Hz of sine term 0 must be > 0'),
    ({'by': 'percent', 'points': [0.0, 1.0]}, "'variation.R_r.by' = 'percent': must be one of"),
])
def test_a_bad_variation_parameter_is_one_line_naming_it(spec, line):
    values = dict({'variation.R_r.enabled': True},
                  **{f'variation.R_r.{k}': v for k, v in spec.items()})
    with pytest.raises(Exception) as err:
        block_from_parameters(ParameterVariation, values, 'variation.R_r')
    assert line in str(err.value) and '\n' not in str(err.value), str(err.value)


# The nodes -----------------------------------------------------------------------------------
def _scenario(**kw):
    return Scenario.from_mapping(dict(task='speed', duration=0.3, motor='thesis', **kw))


def test_the_plant_node_gives_the_run_files_blocks_back(context):
    resistances = {k: VARIATION[k] for k in ('R_s', 'R_r')}    # the real plant's variation
    sc = _scenario(saturation='motor', thermal=THERMAL, variation=resistances)
    params = sc.node_parameters()['plant']
    assert params['variation'] == 'schedule' and 'variation_schedule' not in params
    assert params['saturation.beta'] == 1.439 and params['thermal.T0_r'] == 60.0
    assert params['thermal.T0_s'] == -273.15            # not given: T_ambient
    node = _node(PlantNode, context, params)
    try:
        real = node.sim.real
        assert real.thermal == thermal_from_dict(sc.thermal)
        assert real.thermal.initial() == (30.0, 60.0)
        assert real.saturation.describe() == sc.saturation
        assert (real.saturation.beta, real.saturation.S, real.saturation.L_M0) == \
            (1.439, 7.0, sc.plant_motor().L_M)
        # no parameter of these blocks is text: the strings are choices and shapes
        names = node.list_parameters([], 0).names
        assert not {'saturation', 'thermal', 'variation_schedule'} & set(names)
        strings = sorted(n for n in names if n.startswith(('saturation', 'thermal', 'variation.'))
                         and isinstance(node.get_parameter(n).value, str))
        assert strings == ['saturation.law'] + [f'variation.{p}.by' for p in
                                                ('L_r', 'L_s', 'L_sr', 'R_r', 'R_s')]
        assert node.get_parameter('variation.R_r.shape').type_ == Parameter.Type.STRING_ARRAY
        assert node.get_parameter('saturation.table_psi').type_ == Parameter.Type.DOUBLE_ARRAY
    finally:
        node.destroy_node()
    for variation in (resistances, VARIATION):      # the ideal plant varies inductances too
        sc = _scenario(variation=variation)
        node = _node(PlantNode, context, sc.node_parameters()['plant'])
        try:
            want = variation_schedule(sc.plant_motor(), sc.variation)
            for t in (0.0, 0.05, 0.1, 0.15, 0.2, 0.25, 0.3):
                assert node.sim.schedule.values(t) == want.values(t)
                assert node.sim.schedule.inductance_rates(t) == want.inductance_rates(t)
            assert node.sim.schedule.name == describe_variation(sc.variation)
        finally:
            node.destroy_node()


def test_the_drive_nodes_take_the_curve_and_the_adapter_the_networks(context):
    own = TABLE
    sc = _scenario(saturation='motor', saturation_model=own)
    params = sc.node_parameters()
    assert params['controller']['saturation_model.table_psi'] == [0.2, 0.4, 0.5]
    for cls, node_name in ((ControllerNode, 'controller'), (ObserverNode, 'observer')):
        node = _node(cls, context, params[node_name])
        try:
            assert node.saturated.curve.describe() == own, node_name
            assert node.saturated.L_M0 == pytest.approx(sc.model_estimates().L_M, rel=1e-15)
        finally:
            node.destroy_node()
    sc = _scenario(thermal=THERMAL, controller='adaptive', sensorless=True,
                   parameters={'adapter': {'thermal_tracking': True, 'law': 'improved'}})
    params = sc.node_parameters()['adapter']
    assert params['thermal.C_r'] == 400.0
    node = _node(AdapterNode, context, params)
    try:
        assert node.law.temperatures.thermal == thermal_from_dict(THERMAL)
    finally:
        node.destroy_node()


def test_a_motor_files_nested_blocks_are_what_a_node_takes(context, tmp_path):
    """A motor file's ``saturation: {...}`` reaches a node as ``saturation.<key>``: on."""
    with open(f'{shipped_motors_dir()}/thesis.yaml') as f:
        doc = yaml.safe_load(f)
    values = doc['/**']['ros__parameters']
    values['saturation'] = dict(LAW)
    values['thermal'] = dict(THERMAL)
    path = tmp_path / 'motor.yaml'
    path.write_text(yaml.safe_dump(doc))
    assert load_motor_blocks(str(path)) == {'saturation': LAW, 'thermal': THERMAL}
    flat = {k: v for k, v in values.items() if k not in ('saturation', 'thermal')}
    for block in ('saturation', 'thermal'):     # rcl flattens a nested mapping: dotted names
        flat.update({f'{block}.{k}': v for k, v in values[block].items()})
    node = _node(PlantNode, context, flat)
    try:
        assert node.sim.real.saturation.describe() == LAW
        assert node.sim.real.thermal == Thermal(**THERMAL)
    finally:
        node.destroy_node()
    # the text a motor file held before: refused, never silently dropped
    assert "invalid parameter 'saturation' = '{law: power, beta: 1.4, S: 7}': a block is a " \
        'mapping now' in _one_line(PlantNode, context, {'saturation': '{law: power, beta: 1.4, '
                                                                      'S: 7}'})


@pytest.mark.parametrize('values, line', [
    ({'saturation.beta': -0.5, 'saturation.S': 7.0},
     "invalid parameter 'saturation.beta' = -0.5: must be >= 0"),
    ({'saturation.beta': 1.4}, "invalid parameter 'saturation.S' = None: is missing "
                               '(saturation.beta is given, which turns the saturation block on)'),
    ({'thermal.enabled': True}, "invalid parameter 'thermal.C_s' = None: is missing "
                                '(thermal.enabled is given, which turns the thermal block on)'),
    ({'saturation.beta': 'x'}, "invalid parameter 'saturation.beta' = 'x' for node 'plant': must "
                               'be a real number'),
    ({'thermal.C_s': 1.0, 'thermal.R_th_s': 1.0, 'thermal.C_r': 1.0},
     "invalid parameter 'thermal.R_th_r' = None: is missing"),
    ({'thermal.C_s': -1.0, 'thermal.R_th_s': 1.0, 'thermal.C_r': 1.0, 'thermal.R_th_r': 1.0},
     "invalid parameter 'thermal.C_s' = -1.0: must be > 0"),
    ({'thermal.C_s': 1.0, 'thermal.R_th_s': 1.0, 'thermal.C_r': 1.0, 'thermal.R_th_r': 1.0,
      'thermal.T0_s': -300.0}, "invalid parameter 'thermal.T0_s' = -300.0: must be > -273.15"),
    ({'thermal.enabled': False, 'thermal.C_s': 1.0},
     "invalid parameter 'thermal.C_s' = 1.0: set, but thermal.enabled is false"),
    ({'variation': 'schedule'}, "invalid parameter 'variation' = 'schedule': takes the "
                                'breakpoints of variation.<parameter>.*'),
    ({'variation.R_r.enabled': True, 'variation.R_r.points': [0.0, 1.5]},
     "invalid parameter 'variation.R_r.enabled' = True: variation is 'none', not schedule"),
    ({'variation': 'schedule', 'variation.R_r.enabled': True,
      'variation.R_r.points': [0.0, 1.5, 0.1]},
     "invalid parameter 'variation.R_r.points' = [0.0, 1.5, 0.1]: must be (t, level) pairs"),
])
def test_a_bad_block_parameter_on_the_plant_is_one_line_naming_it(context, values, line):
    assert line in _one_line(PlantNode, context, values)


def test_a_bad_curve_parameter_on_the_controller_is_one_line(context):
    text = _one_line(ControllerNode, context, {'saturation_model.enabled': True,
                                               'saturation_model.table_psi': [0.2, 0.4],
                                               'saturation_model.table_i_M': [2.0, 1.0]})
    assert "invalid parameter 'saturation_model.table_psi[1]' = [0.4, 1.0]: the magnetizing " \
        'curve is not monotonic' in text
