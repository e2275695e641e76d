"""
The run file's, motor file's and efficiency-map file's JSON Schemas agree with the models.

The schemas are generated from the typed models (python -m im_studies.schemas): the committed
files are the generated ones, installed to share/<package>/schema/, every shipped file names its
schema on its first line and is valid against it, and on a set of files the schema (checked by
the reference validator, jsonschema) and the readers (Scenario.from_mapping, load_motor_file)
accept the same ones and refuse the same ones.
"""
import copy
import glob
import json
import os

from ament_index_python.packages import get_package_share_directory
from im_bringup.run_file import RunFileError, Scenario
from im_common.params import InvalidParameter, load_motor_file
from im_studies.efficiency_map import MapFileError, read_map_file
from im_studies.schemas import HEADER, render_running, SCHEMA_FILES, schema_text, schemas
import jsonschema
import pytest
import yaml

SRC = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), 'src')
RUNS = sorted(glob.glob(os.path.join(SRC, 'im_bringup', 'config', 'runs', '*.yaml')))
MOTORS = sorted(glob.glob(os.path.join(SRC, 'im_common', 'config', 'motors', '*.yaml')))
GENERATED = schemas()


def _kind(path: str) -> str:
    if path in MOTORS:
        return 'motor'
    return 'efficiency_map' if 'compare' in (yaml.safe_load(open(path)) or {}) else 'run'


def _valid(kind: str, doc) -> bool:
    return jsonschema.Draft202012Validator(GENERATED[kind]).is_valid(doc)


def _run_accepted(doc) -> bool:
    try:
        Scenario.from_mapping(copy.deepcopy(doc), source='run.yaml')
    except RunFileError:
        return False
    return True


def _motor_accepted(doc, tmp_path) -> bool:
    path = tmp_path / 'motor.yaml'
    path.write_text(yaml.safe_dump(doc))
    try:
        load_motor_file(str(path))
    except InvalidParameter:
        return False
    return True


@pytest.mark.parametrize('kind', sorted(SCHEMA_FILES))
def test_the_committed_schema_is_the_generated_one_and_is_installed(kind):
    committed = os.path.join(SRC, SCHEMA_FILES[kind])
    with open(committed, encoding='utf-8') as f:
        assert f.read() == schema_text(GENERATED[kind]), \
            f'{committed} is stale: run python -m im_studies.schemas'
    package, _, name = SCHEMA_FILES[kind].split(os.sep)
    installed = os.path.join(get_package_share_directory(package), 'schema', name)
    with open(installed, encoding='utf-8') as f:
        assert json.load(f) == GENERATED[kind]
    jsonschema.Draft202012Validator.check_schema(GENERATED[kind])


def test_the_run_file_keys_table_is_the_models():
    page = os.path.join(os.path.dirname(SRC), 'docs', 'running.md')
    with open(page, encoding='utf-8') as f:
        text = f.read()
    assert render_running(text) == text, ('docs/running.md: the table of run-file keys is '
                                          'stale: run python -m im_studies.schemas')
    for key in ('task', 'inverter', 'saturation_model', 'noise', 'loss_scope'):
        assert f'| `{key}` |' in text


def test_every_shipped_file_names_its_schema_and_is_valid_against_it():
    assert len(RUNS) >= 6 and len(MOTORS) >= 3
    for path in RUNS + MOTORS:
        kind = _kind(path)
        with open(path, encoding='utf-8') as f:
            first = f.readline().rstrip('\n')
        assert first == HEADER.format(kind), f'{path}: first line {first!r}'
        # the relative path reaches the schema both in src/ and in the installed share/
        assert os.path.isfile(os.path.join(os.path.dirname(path), '..', '..', 'schema',
                                           f'{kind}.schema.json'))
        errors = [e.message for e in jsonschema.Draft202012Validator(
            GENERATED[kind]).iter_errors(yaml.safe_load(open(path)))]
        assert not errors, f'{path}: {errors[:3]}'


def test_every_shipped_file_is_read_by_its_model():
    for path in RUNS:
        if _kind(path) == 'efficiency_map':
            assert len(read_map_file(path)) >= 2
        else:
            Scenario.from_file(path)
    for path in MOTORS:
        load_motor_file(path)


GOOD_RUNS = [
    {},
    {'task': 'speed', 'strategy': 'min_loss', 'controller': 'adaptive', 'T_s': 2e-4},
    {'task': 'speed', 'inverter': {'delay': 1}, 'noise': {'current': 0.05, 'seed': 3}},
    {'task': 'speed', 'motor': 'krause_3hp', 'saturation': 'motor', 'thermal': 'motor',
     'inverter': {'V_dc': 343.0, 'pwm_frequency': 10000.0, 'deadtime': 2.0e-6},
     'sensors': {'encoder_lines': 2048, 'adc_bits': 12, 'current_range': 43.0}},
    {'task': 'speed', 'saturation_model': {'table': [[0.5, 2.0], [0.8, 6.0]]}},
    {'task': 'position', 'variation': {'R_r': [{'t': 0.5, 'scale': 2.0, 'shape': 'step'}]},
     'current_limit': 0.0, 'v_limit': 220.0, 'start': 'rest'},
    {'task': 'speed', 'current_gain': [[1.0, 0.0], [0.0, 1.0]], 'sensorless': True,
     'mode': 'free_run', 'loss_scope': 'motor'},
    {'task': 'speed', 'load': {'kind': 'step', 't': 0.5, 'tau_before': 1.0, 'tau_after': 2.0},
     'profile': {'setpoints': [{'t': 0.0, 'velocity': 100.0}]}},
    {'task': 'position', 'load': {'kind': 'schedule', 'points': [[0.0, 1.0], [0.5, 2.0]]},
     'inverter': {'V_dc': 343.0, 'pwm_frequency': 10000.0}, 'compensation': 'inverter'},
]
BAD_RUNS = [
    {'tsk': 'speed'},
    {'task': 'walk'},
    {'strategy': 'fastest'},
    {'controller': 'pid'},
    {'T_s': -1e-4},
    {'T_s': 'fast'},
    {'T_s': None},
    {'duration': 0.0},
    {'start': 'hot'},
    {'v_limit': -5.0},
    {'sensorless': 'yes'},
    {'mode': 'fast'},
    {'loss_scope': 'inverter'},
    {'variation': 'linear'},
    {'noise': {'current': -0.1}},
    {'noise': {'curent': 0.1}},
    {'current_gain': [[1.0, 2.0]]},
    {'observer_gain': [[1.0, 2.0], [1.0, 2.0]]},
    {'motor': 42},
    {'motor': {'R_s': -1.0}},
    {'inverter': {'V_dc': -300.0, 'pwm_frequency': 10000.0}},
    {'inverter': {'deadtme': 1e-6}},
    {'sensors': {'adc_bits': 'twelve'}},
    {'thermal': {'C_s': -1.0, 'R_th_s': 1.0, 'C_r': 1.0, 'R_th_r': 1.0}},
    {'saturation': 'file'},
    {'saturation_model': 'yes'},
    {'saturation_model': {'table': [[0.0, 0.0], [0.5, 2.0]]}},
    {'parameters': {'planter': {'T_s': 1e-4}}},
    {'load': {'kind': 'spring'}},
    {'load': {'kind': 'step', 't': 0.5}},
    {'load': {'kind': 'linear', 'c1': 'one'}},
    {'compensation': {'v_dead': -1.0}},
    {'compensation': 'exact'},
]


@pytest.mark.parametrize('doc', GOOD_RUNS, ids=lambda d: ','.join(d) or 'empty')
def test_a_run_file_the_schema_accepts_the_model_accepts(doc):
    assert _valid('run', doc)
    assert _run_accepted(doc)


@pytest.mark.parametrize('doc', BAD_RUNS, ids=lambda d: json.dumps(d)[:40])
def test_a_run_file_the_schema_refuses_the_model_refuses(doc):
    assert not _valid('run', doc)
    assert not _run_accepted(doc)


def _motor(**values):
    base = {'R_s': 0.687, 'R_r': 0.842, 'L_s': 0.08397, 'L_r': 0.08528, 'L_sr': 0.08136,
            'pole_pairs': 2, 'J': 0.03, 'b': 0.01}
    base.update(values)
    return {'/**': {'ros__parameters': {k: v for k, v in base.items() if v is not None}}}


def test_motor_files_the_schema_and_the_reader_agree(tmp_path):
    good = [_motor(), _motor(rated_power=2200.0),
            _motor(thermal={'C_s': 1000.0, 'R_th_s': 1.0, 'C_r': 400.0, 'R_th_r': 0.6}),
            _motor(saturation={'law': 'power', 'beta': 1.4, 'S': 7.0})]
    bad = [_motor(R_s=-1.0), _motor(R_x=1.0), _motor(R_r=None), _motor(pole_pairs=2.5),
           _motor(J=1e12), _motor(thermal={'C_s': 1.0}),
           _motor(saturation={'law': 'power', 'beta': -1.0, 'S': 7.0}),
           {'plant': _motor()['/**']}]
    for doc in good:
        assert _valid('motor', doc) and _motor_accepted(doc, tmp_path), doc
    for doc in bad:
        assert not _valid('motor', doc), doc
        assert not _motor_accepted(doc, tmp_path), doc


def test_an_efficiency_map_file_the_schema_and_the_reader_agree(tmp_path):
    base = yaml.safe_load(open(next(p for p in RUNS if _kind(p) == 'efficiency_map')))
    motor = os.path.join(SRC, 'im_common', 'config', 'motors', base['motor'] + '.yaml')
    base['motor'] = motor

    def read(doc):
        path = tmp_path / 'map.yaml'
        path.write_text(yaml.safe_dump(doc))
        try:
            read_map_file(str(path))
        except MapFileError:
            return False
        return True
    good = dict(base, compare=[{'strategy': 'min_loss'}, {'strategy': 'constant_flux',
                                                          'label': 'cf'}])
    assert _valid('efficiency_map', good) and read(good)
    for bad in (dict(base, compare=[]), dict(base, compare=[{'strategy': 'fastest'}]),
                dict(base, compare=[{'tsk': 'speed'}])):
        assert not _valid('efficiency_map', bad) and not read(bad), bad['compare']
