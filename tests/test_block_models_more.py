"""
The load, the profile and the compensation as typed models (issue 45, item 1).

``im_common.loads.LoadBlock`` (one model per kind, discriminated on ``kind``),
``im_controller.profiles.ProfileBlock`` (its ``Setpoint`` entries) and
``im_common.compensation.CompensationBlock`` hold each field's default, bound and description once;
the parsers read through them, an error is one line naming the key, and a shipped file reads as it
did.
"""
import math
from pathlib import Path

from im_common.compensation import (compensation_from_dict, CompensationBlock,
                                    DEFAULT_CURRENT_BAND, InverterErrorModel)
from im_common.inverter import Inverter
from im_common.loads import (ConstantLoad, LinearLoad, load_file, load_from_dict, LOAD_KINDS,
                             LOAD_MODELS, load_parameters, LoadBlock, make_load, MODEL_KINDS,
                             NoLoad, PendulumLoad, ScheduleLoad, StepLoad, StepLoadBlock)
from im_common.params import read_yaml_file
from im_common.validation import InvalidParameter
from im_controller.profiles import (from_parameters, from_setpoints, KINDS, load_profile,
                                    profile_from_block, ProfileBlock, Setpoint)
from pydantic import TypeAdapter
import pytest

CONFIG = Path(__file__).resolve().parents[1] / 'src' / 'im_common' / 'config'
LOAD_FILES = sorted((CONFIG / 'loads').glob('*.yaml'))
PROFILE_FILES = sorted((CONFIG / 'profiles').glob('*.yaml'))
#: one block of each kind, and the load it describes
BLOCKS = [
    ({'kind': 'none'}, NoLoad()),
    ({'kind': 'constant', 'tau': 2.5}, ConstantLoad(2.5)),
    ({'kind': 'pendulum', 'mgl': 4.0}, PendulumLoad(4.0)),
    ({'kind': 'linear', 'c1': 0.5, 'c2': 0.02}, LinearLoad(0.5, 0.02)),
    ({'kind': 'step', 't': 0.5, 'tau_before': 2.0, 'tau_after': 8.0}, StepLoad(0.5, 2.0, 8.0)),
    ({'kind': 'schedule', 'points': [[0.0, 1.0], [0.5, 1.0], [0.5, 3.0], [1.0, 2.0]]},
     ScheduleLoad(((0.0, 1.0), (0.5, 1.0), (0.5, 3.0), (1.0, 2.0)))),
]
INV = Inverter.from_block({'V_dc': 340.0, 'pwm_frequency': 10000.0, 'deadtime': 2e-6,
                           'v_on': 1.0, 'r_on': 0.02})


def _refused(parse, spec):
    with pytest.raises(InvalidParameter) as err:
        parse(spec)
    text = str(err.value)
    assert '\n' not in text, text
    return err.value


# Loads -------------------------------------------------------------------------------------
def test_every_shipped_load_file_reads_as_before():
    assert LOAD_FILES
    expected = {'fan.yaml': LinearLoad(0.5, 0.02)}
    for path in LOAD_FILES:
        load = load_file(str(path))
        assert load == expected[path.name]
        doc = read_yaml_file(str(path), 'load file')
        assert TypeAdapter(LoadBlock).validate_python(doc).load() == load
        assert load_from_dict(load.describe()) == load


@pytest.mark.parametrize('block, load', BLOCKS, ids=[b['kind'] for b, _ in BLOCKS])
def test_each_kind_round_trips(block, load):
    assert load_from_dict(block) == load
    assert load_from_dict(load.describe()) == load
    model = TypeAdapter(LoadBlock).validate_python(block)
    assert type(model) is LOAD_MODELS[block['kind']] and load_from_dict(model) == load
    p = load_parameters(load)
    assert make_load(p['load'], **{k[len('load_'):]: v for k, v in p.items()
                                   if k != 'load'}) == load


def test_a_kinds_defaults_are_its_models():
    for kind in MODEL_KINDS:
        assert load_from_dict({'kind': kind}) == make_load(kind)
    assert LinearLoad() == LinearLoad(1.0, 0.001) == make_load('linear')
    assert PendulumLoad() == PendulumLoad(10.0) and ConstantLoad() == ConstantLoad(0.0)
    for kind in ('step', 'schedule'):        # a load in time has none
        assert 'is missing' in str(_refused(load_from_dict, {'kind': kind}))


_BAD_NUMBERS = [('x', 'must be a real number'), (True, 'must be a real number'),
                (math.nan, 'must be finite'), (math.inf, 'must be finite')]


@pytest.mark.parametrize('kind, key', [(kind, key) for kind, m in LOAD_MODELS.items()
                                       for key in m.model_fields if key not in ('kind', 'points')])
@pytest.mark.parametrize('value, why', _BAD_NUMBERS)
def test_a_bad_number_is_refused_naming_the_key(kind, key, value, why):
    block = dict(next(b for b, _ in BLOCKS if b['kind'] == kind), **{key: value})
    err = _refused(lambda s: load_from_dict(s, source='run.yaml: load'), block)
    assert err.name == f'run.yaml: load: {key}' and err.reason == why
    err = _refused(lambda kw: make_load(kind, **kw), {key: value})
    assert err.name == f'load_{key}'


@pytest.mark.parametrize('spec, name, why', [
    ([1.0], 'load', 'must be a mapping with a kind'),
    ({'kind': 'fan'}, 'load: kind', 'must be one of ' + ', '.join(LOAD_KINDS)),
    ({'kind': ['linear']}, 'load: kind', 'must be one of'),
    ({'c1': 1.0}, 'load: kind', 'must be one of'),
    ({'kind': 'none', 'tau': 1.0}, 'load: tau', 'unknown key (known: kind)'),
    ({'kind': 'linear', 'mgl': 1.0}, 'load: mgl', 'unknown key (known: kind, c1, c2)'),
    ({'kind': 'step', 't': -0.1, 'tau_before': 0.0, 'tau_after': 1.0}, 'load: t', 'must be >= 0'),
    ({'kind': 'step', 't': 0.1, 'tau_after': 1.0}, 'load: tau_before', 'is missing'),
    ({'kind': 'schedule', 'points': 3}, 'load: points', 'must be a list of [t, tau] points'),
    ({'kind': 'schedule', 'points': []}, 'load: points', 'at least 1'),
    ({'kind': 'schedule', 'points': [[0.0, 1.0, 2.0]]}, 'load: points[0]',
     'must be a point [t, tau]'),
    ({'kind': 'schedule', 'points': [['a', 1.0]]}, 'load: points[0].t', 'must be a real number'),
    ({'kind': 'schedule', 'points': [[0.0, math.nan]]}, 'load: points[0].tau', 'must be finite'),
    ({'kind': 'schedule', 'points': [[-1.0, 1.0]]}, 'load: points[0].t', 'must be >= 0 s'),
    ({'kind': 'schedule', 'points': [[0.5, 1.0], [0.2, 1.0]]}, 'load: points[1].t',
     'times must not decrease'),
    ({'kind': 'schedule', 'points': [[0.5, 1.0], [0.5, 2.0], [0.5, 3.0]]},
     'load: points[2].t', 'not three times'),
])
def test_a_bad_load_is_one_line_naming_the_key(spec, name, why):
    err = _refused(load_from_dict, spec)
    assert err.name == name and why in err.reason


def test_a_load_built_in_code_is_checked_by_its_model():
    assert 'load_t' == _refused(lambda t: StepLoad(t, 0.0, 1.0), -1.0).name
    assert 'load_points[1].t' == _refused(ScheduleLoad, [[0.5, 1.0], [0.2, 1.0]]).name
    assert 'load_mgl' == _refused(PendulumLoad, math.nan).name
    assert StepLoad(1, 2, 3).describe() == {'kind': 'step', 't': 1.0, 'tau_before': 2.0,
                                            'tau_after': 3.0}


def test_the_load_schema_lists_each_kind_and_its_keys():
    schema = TypeAdapter(LoadBlock).json_schema()
    kinds = {d['properties']['kind']['const']: set(d['properties'])
             for d in schema['$defs'].values()}
    assert kinds == {'none': {'kind'}, 'constant': {'kind', 'tau'}, 'pendulum': {'kind', 'mgl'},
                     'linear': {'kind', 'c1', 'c2'},
                     'step': {'kind', 't', 'tau_before', 'tau_after'},
                     'schedule': {'kind', 'points'}}
    assert set(schema['discriminator']['mapping']) == set(LOAD_KINDS)
    step = StepLoadBlock.model_json_schema()
    assert step['properties']['t']['minimum'] == 0 and set(step['required']) == {
        'kind', 't', 'tau_before', 'tau_after'}
    assert schema['$defs']['LinearLoadBlock']['properties']['c2']['default'] == 0.001


# Profiles ----------------------------------------------------------------------------------
def test_every_shipped_profile_file_reads_as_before():
    expected = {'reversal.yaml': ((0.0, 100.0, None), (0.3, -100.0, None)),
                'speed_steps.yaml': ((0.0, 100.0, None), (0.2, 180.0, None),
                                     (1.5, 100.0, None))}
    assert {p.name for p in PROFILE_FILES} == set(expected)
    for path in PROFILE_FILES:
        prof = load_profile(str(path))
        assert prof.mode == 'speed' and prof.setpoints == expected[path.name]
        block = ProfileBlock.model_validate(read_yaml_file(str(path), 'profile file'))
        assert profile_from_block(block, str(path)) == prof
        assert from_parameters(prof.as_parameters()['setpoints']) == prof.setpoints
    csv = load_profile(str(CONFIG / 'profiles' / 'position_samples.csv'))
    assert csv.mode == 'position' and csv.start_value == pytest.approx(-1.5707963)


@pytest.mark.parametrize('kind', list(KINDS))
def test_each_setpoint_kind_round_trips(kind):
    entries = [{'t': 0.0, kind: 1.0}, {'t': 0.2, kind: 2, 'duration': 0.3}]
    prof = from_setpoints(entries)
    assert prof.mode == KINDS[kind]
    assert prof.setpoints == ((0.0, 1.0, None), (0.2, 2.0, 0.3))
    assert profile_from_block({'setpoints': entries}) == prof
    assert profile_from_block(ProfileBlock(setpoints=[Setpoint(**e) for e in entries])) == prof


@pytest.mark.parametrize('key', ['t', 'velocity', 'duration'])
@pytest.mark.parametrize('value, why', _BAD_NUMBERS)
def test_a_bad_setpoint_number_is_refused_naming_the_key(key, value, why):
    entries = [{'t': 0.0, 'velocity': 1.0}, {'t': 0.2, 'velocity': 2.0, 'duration': 0.3}]
    entries[1][key] = value
    err = _refused(from_setpoints, entries)
    assert err.name == f'profile: setpoints[1].{key}' and err.reason == why


@pytest.mark.parametrize('entries, name, why', [
    ([], 'profile: setpoints', 'at least 1'),
    ({'t': 0.0}, 'profile: setpoints', 'must be a non-empty list'),
    ([3.0], 'profile: setpoints[0]', 'must be a mapping of t, position, velocity, effort, '
                                     'duration'),
    ([{'t': 0.0, 'speed': 1.0}], 'profile: setpoints[0].speed', 'unknown key (known: t, '),
    ([{'velocity': 1.0}], 'profile: setpoints[0].t', 'is missing'),
    ([{'t': -0.1, 'velocity': 1.0}], 'profile: setpoints[0].t', 'must be >= 0'),
    ([{'t': 0.0, 'velocity': 1.0, 'duration': 0.0}], 'profile: setpoints[0].duration',
     'must be > 0'),
    ([{'t': 0.0}], 'profile: setpoints[0]', 'needs exactly one of position, velocity, effort'),
    ([{'t': 0.0, 'velocity': 1.0, 'effort': 1.0}], 'profile: setpoints[0]', 'exactly one'),
    ([{'t': 0.0, 'velocity': 1.0}, {'t': 0.1, 'position': 1.0}], 'profile: setpoints[1].position',
     'a profile has one kind; the first entry set velocity'),
    ([{'t': 0.5, 'velocity': 1.0}, {'t': 0.1, 'velocity': 1.0}], 'profile: setpoints[1].t',
     'must not be before the previous t = 0.5'),
])
def test_a_bad_profile_is_one_line_naming_the_key(entries, name, why):
    err = _refused(from_setpoints, entries)
    assert err.name == name and why in err.reason


def test_a_profile_block_refuses_another_key():
    err = _refused(lambda d: profile_from_block(d, 'p.yaml'), {'steps': []})
    assert err.name == 'p.yaml: steps' and err.reason == 'unknown key (known: setpoints)'
    assert _refused(lambda d: profile_from_block(d, 'p.yaml'), 3).name == 'p.yaml'


def test_the_profile_schema_lists_the_setpoint_keys():
    schema = ProfileBlock.model_json_schema()
    assert schema['required'] == ['setpoints'] and schema['properties']['setpoints'][
        'minItems'] == 1
    entry = schema['$defs']['Setpoint']
    assert list(entry['properties']) == ['t', 'position', 'velocity', 'effort', 'duration']
    assert entry['required'] == ['t'] and entry['additionalProperties'] is False
    assert {k: entry['properties'][k]['mode'] for k in KINDS} == KINDS


# Compensation ------------------------------------------------------------------------------
@pytest.mark.parametrize('spec, model', [
    (None, None), (False, None),
    (True, InverterErrorModel(7.8, 0.02)), ('inverter', InverterErrorModel(7.8, 0.02)),
    ({'inverter': True}, InverterErrorModel(7.8, 0.02)),
    ({'inverter': True, 'current_band': 0.5}, InverterErrorModel(7.8, 0.02, 0.5)),
    ({'v_dead': 5.0}, InverterErrorModel(5.0, 0.0, DEFAULT_CURRENT_BAND)),
    ({'v_dead': 5, 'r_on': 0.1, 'current_band': 0}, InverterErrorModel(5.0, 0.1, 0.0)),
])
def test_each_compensation_form_reads_as_before(spec, model):
    got = compensation_from_dict(spec, INV)
    if model is None:
        assert got is None
        return
    assert got.describe() == pytest.approx(model.describe())
    assert compensation_from_dict(got.describe()) == got      # the form a run record writes
    if isinstance(spec, dict):
        assert compensation_from_dict(CompensationBlock.model_validate(spec), INV) == got


@pytest.mark.parametrize('key', ['v_dead', 'r_on', 'current_band'])
@pytest.mark.parametrize('value, why', _BAD_NUMBERS + [(-1.0, 'must be >= 0')])
def test_a_bad_compensation_number_is_refused_naming_the_key(key, value, why):
    spec = {'v_dead': 1.0, key: value}
    err = _refused(compensation_from_dict, spec)
    assert err.name == f'compensation.{key}' and err.reason == why


@pytest.mark.parametrize('spec, name, why', [
    (3.0, 'compensation', 'must be false, inverter, or a mapping'),
    ('exact', 'compensation', 'must be false, inverter, or a mapping'),
    ({'r_on': 0.1}, 'compensation.v_dead', 'is missing'),
    ({'v_dead': 1.0, 'deadband': 2}, 'compensation.deadband', 'unknown key (known: inverter, '
                                                              'v_dead, r_on, current_band)'),
    ({'inverter': False}, 'compensation.inverter', 'must be true'),
    ({'inverter': 'yes'}, 'compensation.inverter', 'must be true'),
    ({'inverter': True, 'v_dead': 1.0}, 'compensation.v_dead', 'unknown key with inverter: true'),
    ({'inverter': True, 'current_band': -1.0}, 'compensation.current_band', 'must be >= 0'),
    ('inverter', 'compensation', "takes the run's inverter block"),
])
def test_a_bad_compensation_is_one_line_naming_the_key(spec, name, why):
    err = _refused(compensation_from_dict, spec)
    assert err.name == name and why in err.reason


def test_the_compensation_schema_lists_its_keys():
    schema = CompensationBlock.model_json_schema()
    assert list(schema['properties']) == ['inverter', 'v_dead', 'r_on', 'current_band']
    assert schema['properties']['inverter']['const'] is True
    assert schema['properties']['current_band']['default'] == DEFAULT_CURRENT_BAND
    assert schema['additionalProperties'] is False
