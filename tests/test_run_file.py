"""
The run file (issue 24 part 1, docs/running.md).

One frozen Scenario describes a run on every path — the ROS-free loop, the in-process graph,
``--processes``, ``--rerun`` of a bag — with breakpoint variations of any electrical parameter,
measurement noise, and one-line errors.
"""
from dataclasses import FrozenInstanceError, replace
import json
import math
import os

from im_bringup.offline import simulate
from im_bringup.run_file import RunFileError, Scenario
from im_common.params import CHAPTER4_ESTIMATES, ParameterSchedule, ramp, sinusoid, THESIS_MOTOR
import numpy as np
import pytest

HERE = os.path.dirname(os.path.abspath(__file__))
RUNS = os.path.join(HERE, '..', 'src', 'im_bringup', 'config', 'runs')
DRIFT = os.path.join(RUNS, 'drift.yaml')
CHAPTER4 = os.path.join(RUNS, 'chapter4.yaml')


def old_chapter4():
    """Return the chapter-4 profile as written before run files (constant/ramp/sine terms)."""
    return ParameterSchedule(THESIS_MOTOR, {'R_r': ramp(0.42, 0.42),
                                            'L_s': sinusoid(0.1, 0.016, math.pi),
                                            'L_r': sinusoid(0.1, 0.016, math.pi),
                                            'L_sr': sinusoid(0.097, 0.016, math.pi)})


@pytest.mark.slow
def test_the_shipped_chapter4_run_file_is_the_chapter4_profile():
    sc = Scenario.from_file(CHAPTER4)
    new, old = sc.plant_schedule(), old_chapter4()
    for t in np.linspace(0.0, 5.0, 1001):
        assert new.values(t) == old.values(t)
        assert new.inductance_rates(t) == old.inductance_rates(t)
    assert sc.model_estimates() == CHAPTER4_ESTIMATES
    a = simulate(replace(sc, controller='nominal'), record_every=100).summary
    b = simulate(Scenario(task='position', strategy='min_energy', schedule=old,
                          estimates=CHAPTER4_ESTIMATES, variation='chapter4_old'),
                 record_every=100).summary
    c = simulate(Scenario(task='position', strategy='min_energy', variation='chapter4'),
                 record_every=100).summary
    assert abs(a['E_in_J'] - b['E_in_J']) <= 1e-9 and abs(c['E_in_J'] - b['E_in_J']) <= 1e-9
    assert a['E_in_J'] > 1.0


def test_a_drift_of_ones_own_steps_and_ramps_from_the_motor_files_values():
    sc = Scenario.from_file(DRIFT)
    s = sc.plant_schedule()
    R_r, L_sr = THESIS_MOTOR.R_r, THESIS_MOTOR.L_sr
    assert s.params_at(0.49).R_r == R_r and s.params_at(0.5).R_r == 2.0 * R_r
    assert s.params_at(1.0).L_sr == pytest.approx(0.9 * L_sr, rel=1e-12)
    assert s.params_at(3.0).L_sr == pytest.approx(0.8 * L_sr, rel=1e-12)
    assert s.inductance_rates(1.0)[2] == pytest.approx(-0.1 * L_sr, rel=1e-12)
    assert (sc.current_noise_std, sc.speed_noise_std, sc.noise_seed) == (0.05, 0.05, 1)
    with pytest.raises(FrozenInstanceError):
        sc.task = 'speed'
    summary = simulate(replace(sc, duration=0.01)).summary
    assert 'R_r' in summary['variation'] and 'L_sr' in summary['variation']


def test_the_run_file_round_trips_and_gives_the_same_node_parameters(tmp_path):
    gains = os.path.join(HERE, '..', 'src', 'im_bringup', 'config', 'gains_1ms.yaml')
    profile = tmp_path / 'p.yaml'
    profile.write_text('setpoints: [{t: 0.0, velocity: 100.0}, {t: 0.2, velocity: 120.0}]\n')
    motor = os.path.join(HERE, '..', 'src', 'im_common', 'config', 'motors', 'krause_3hp.yaml')
    run = tmp_path / 'run.yaml'
    run.write_text(f'task: speed\nstrategy: min_loss\nT_s: 0.001\nmotor: {motor}\n'
                   f'profile: p.yaml\ngains: {gains}\nload: {{kind: linear, c1: 0.5, c2: 0.001}}\n'
                   'estimates: {R_r: 0.9}\ntorque_limit: 5.0\ncurrent_trip: 60.0\n'
                   'noise: {current: 0.01}\n')
    for sc in (Scenario.from_file(str(run)), Scenario.from_file(DRIFT),
               Scenario.from_file(CHAPTER4)):
        again = Scenario.from_mapping(sc.to_mapping())
        assert again.to_mapping() == sc.to_mapping()
        assert replace(again, profile=None) == replace(sc, profile=None)   # profile: its source
        assert again.node_parameters() == sc.node_parameters()
        assert json.loads(json.dumps(sc.to_mapping())) == sc.to_mapping()
    sc = Scenario.from_file(str(run))
    assert sc.estimates.R_r == 0.9 and sc.estimates.R_s == sc.motor.R_s   # over the motor file
    p = sc.node_parameters()
    assert p['controller']['torque_limit'] == 5.0 and p['plant']['current_trip'] == 60.0
    assert p['controller']['gain_period'] == 0.001 and p['plant']['current_noise_std'] == 0.01


@pytest.mark.parametrize('text, line', [
    ('variation: {R_r: [{t: 0.5, scale: 2.0, shape: cubic}]}',
     'run.yaml: variation.R_r[0].shape: must be step or ramp'),
    ('variation: {J: [{t: 0.5, scale: 2.0}]}', 'run.yaml: variation.J: only R_s, R_r'),
    ('variation: {R_r: [{t: 0.5, scale: 2.0}, {t: 0.2, scale: 1.0}]}',
     'run.yaml: variation.R_r[1].t: must be after the previous breakpoint'),
    ('variation: {L_sr: [{t: 1.0, scale: 1.5}]}', 'run.yaml: L_sr'),   # sigma <= 0: no motor
    ('tsk: speed', "run.yaml: tsk: unknown run-file key; did you mean 'task'?"),
    ('noise: {current: -0.1}', 'run.yaml: noise.current: must be >= 0 (got -0.1)'),
    ('strategy: fastest', 'run.yaml: strategy: must be one of'),
    ('motor: {R_s: 1.0}', 'run.yaml: motor: R_r: is missing'),
    ('motor: krause_5hp', 'run.yaml: motor: is no motor file and no shipped motor (shipped: '
     "krause_3hp, krause_50hp, thesis) (got 'krause_5hp')"),
])
def test_a_bad_run_file_is_one_line_naming_the_file_and_the_key(tmp_path, capsys, text, line):
    from im_bringup.scenario import main
    run = tmp_path / 'run.yaml'
    run.write_text(text + '\n')
    with pytest.raises(RunFileError) as exc:
        Scenario.from_file(str(run))
    msg = str(exc.value).replace(str(tmp_path) + os.sep, '')
    assert msg.startswith(line) and '\n' not in msg
    assert main([str(run), '--no-progress']) == 2       # the same line on the command line
    err = capsys.readouterr().err.strip().replace(str(tmp_path) + os.sep, '')
    assert err == f'scenario: error: {msg}'


def test_a_shipped_motor_by_name_is_its_file_unless_a_file_is_so_named(tmp_path):
    from im_bringup.scenario import main
    from im_common.params import load_motor_file, shipped_motors_dir
    krause = load_motor_file(os.path.join(shipped_motors_dir(), 'krause_3hp.yaml'))
    run = tmp_path / 'run.yaml'
    run.write_text('task: speed\nmotor: krause_3hp\nestimates: krause_3hp\nsaturation: motor\n')
    sc = Scenario.from_file(str(run))
    assert sc.motor == sc.estimates == krause and sc.saturation['S'] == 7.0
    (tmp_path / 'krause_3hp').write_text(open(os.path.join(shipped_motors_dir(), 'thesis.yaml'))
                                         .read())
    thesis = load_motor_file(os.path.join(shipped_motors_dir(), 'thesis.yaml'))
    assert Scenario.from_file(str(run)).motor == thesis != krause    # the file beside the run
    out = tmp_path / 's.json'
    assert main(['--task', 'speed', '--motor', 'krause_3hp', '--duration', '0.002',
                 '--no-progress', '--summary', str(out)]) == 0
    assert json.loads(out.read_text())['steps'] == 20


def test_an_override_names_the_command_line(tmp_path, capsys):
    from im_bringup.scenario import main
    assert main([DRIFT, '--set', 'variation.R_r=[{t: 0.5, scale: 2.0, shape: jump}]',
                 '--no-progress']) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(
        'scenario: error: command line: variation.R_r[0].shape: must be step or ramp')
    assert Scenario.from_file(DRIFT, {'noise.current': 0.0}).current_noise_std == 0.0


def test_rerun_of_a_bag_without_a_run_record_is_one_line(tmp_path, capsys):
    from im_bringup.scenario import main
    from im_recording.bag import BagWriter
    bag = tmp_path / 'old.mcap'
    BagWriter(str(bag)).close()
    assert main(['--rerun', str(bag), '--no-progress']) == 2
    err = capsys.readouterr().err.strip()
    assert err == f'scenario: error: {bag}: no "run" record (recorded before run files existed, ' \
                  'or not by the scenario runner); cannot re-run it'


@pytest.mark.parametrize('task', ['position', 'speed'])
def test_the_run_record_of_a_default_run_holds_its_motor_load_and_profile(tmp_path, task):
    """
    A run with the default motor, load and profile: its bag's run file says what they were.

    docs/running.md: "the run file, fully resolved"; it reads back as the same run.
    """
    import yaml
    from im_bringup.run_file import motor_parameters
    from im_bringup.scenario import main
    from im_recording.bag import info
    bag = str(tmp_path / 'default.mcap')
    assert main(['--task', task, '--duration', '0.005', '--record', bag, '--no-progress']) == 0
    record = yaml.safe_load(info(bag).metadata['run']['yaml'])
    assert record['motor'] == motor_parameters(THESIS_MOTOR)
    assert record['motor']['R_r'] == THESIS_MOTOR.R_r and record['motor']['pole_pairs'] == 2
    assert record['load'] == ({'kind': 'pendulum', 'mgl': 10.0} if task == 'position' else
                              {'kind': 'linear', 'c1': 1.0, 'c2': 0.001})
    assert record['profile'] == (
        {'kind': 'thesis_position', 'theta0': -math.pi / 2, 'amplitude': 1.2 * math.pi,
         't0': 0.4, 'k': 10.0} if task == 'position' else
        {'kind': 'thesis_speed', 'omega0': 135.0, 'amplitude': 45.0, 't0': 0.2, 'k': 10.0,
         'theta0': 0.0})
    default = Scenario.from_mapping({'task': task, 'duration': 0.005})
    again = Scenario.from_mapping(record)
    assert again == default and again.node_parameters() == default.node_parameters()
    # the thesis's reference has its parameters only; another task's is refused, in one line
    with pytest.raises(RunFileError, match='^run: profile: the thesis_\\w+ reference has the '
                                           "thesis's parameters only"):
        Scenario.from_mapping(dict(record, profile=dict(record['profile'], t0=0.3)), 'run')
    other = 'speed' if task == 'position' else 'position'
    with pytest.raises(RunFileError, match=f'^run: profile: is the thesis {task} reference; '
                                           f'the task is {other}'):
        Scenario.from_mapping(dict(record, task=other), 'run')


# --- the graph: in one process, as processes, and re-run from the bag (run in a netns) ---------
def _summary(path):
    with open(path) as f:
        return json.load(f)


@pytest.mark.processes
@pytest.mark.slow
def test_drift_runs_identically_in_one_process_with_processes_and_rerun(tmp_path):
    from im_bringup.scenario import main
    from im_recording.bag import info
    over = ['--set', 'duration=0.3', '--no-progress']
    one, procs, again = (str(tmp_path / f'{n}.mcap') for n in ('one', 'procs', 'again'))
    assert main([DRIFT, '--record', one] + over) == 0
    assert main([DRIFT, '--processes', '--record', procs] + over) == 0
    assert main(['--rerun', one, '--record', again, '--no-progress']) == 0
    expected = Scenario.from_file(DRIFT, {'duration': 0.3}).to_yaml()
    for bag in (one, procs, again):
        assert info(bag).metadata['run']['yaml'] == expected       # every bag holds the run file
    s = [_summary(os.path.splitext(b)[0] + '.json') for b in (one, procs, again)]
    assert s[0]['E_in_J'] > 1.0 and 'R_r' in s[0]['variation']
    for other in s[1:]:
        assert abs(other['E_in_J'] - s[0]['E_in_J']) <= 1e-9
        assert abs(other['pos_err_rms_rad'] - s[0]['pos_err_rms_rad']) <= 1e-9


@pytest.mark.slow
def test_the_adaptive_controller_holds_the_position_under_the_drift_the_nominal_loses_it():
    from im_bringup.testing import run_graph
    sc = Scenario.from_file(DRIFT)        # 4 s, noise on
    adaptive = run_graph(scenario=sc).summary
    nominal = run_graph(scenario=replace(sc, controller='nominal')).summary
    assert nominal['pos_err_rms_rad'] > 0.1
    assert adaptive['pos_err_rms_rad'] <= 0.01


def test_the_launch_file_takes_the_run_file_and_records_it(tmp_path):
    from im_bringup.scenario import launch_processes
    bag = str(tmp_path / 'l.mcap')
    args = {'run': DRIFT, 'task': '', 'duration': '0.3', 'controller': 'nominal', 'record': bag,
            'use_adapter': '', 'gains': '', 'params_file': '', 'sensorless': '', 'mode': ''}
    procs = {p.name: p for p in launch_processes(args)}
    sc = Scenario.from_file(DRIFT, {'duration': 0.3, 'controller': 'nominal'})
    assert {k: v for k, v in procs['plant'].parameters.items() if k not in (
        'graph_key_file', 'wait_for', 'mode')} == sc.node_parameters()['plant']
    from im_common.node_params import variation_from_parameters
    assert variation_from_parameters(procs['plant'].parameters).spec() == sc.variation
    meta = json.loads(procs['recorder'].arguments[procs['recorder'].arguments.index('--metadata')
                                                  + 1])
    assert meta['run']['yaml'] == sc.to_yaml() and 'adapter' not in procs
    with pytest.raises(RunFileError, match='^launch arguments: controller: must be one of'):
        launch_processes(dict(args, controller='clever'))


def test_the_summary_names_the_variation_the_plant_runs():
    from im_bringup.testing import run_graph
    custom = run_graph(task='position', duration=0.01, parameters={'plant': {
        'variation': 'custom', 'variation_parameter': 'R_r', 'variation_kind': 'ramp'}})
    assert custom.summary['variation'] == 'custom R_r ramp'          # was 'none'
    drift = run_graph(scenario=Scenario.from_file(DRIFT, {'duration': 0.01}))
    assert drift.summary['variation'].startswith('R_r step x2 at 0.5 s; L_sr')


def test_an_inline_motor_without_ratings_is_warned_of_and_a_default_run_record_is_not(
        caplog, monkeypatch):
    from im_common import params
    from im_common.params import REQUIRED_MOTOR_FIELDS
    monkeypatch.setattr(params, '_WARNED', set())
    caplog.set_level('WARNING', logger='im_common.params')
    bare = {k: getattr(THESIS_MOTOR, k) for k in REQUIRED_MOTOR_FIELDS}
    Scenario.from_mapping({'motor': dict(bare, R_s=0.7)}, source='run.yaml')
    said = [r.getMessage() for r in caplog.records]
    assert len(said) == 6 and said[0].startswith('run.yaml: motor: no k_e: ')
    caplog.clear()
    # a run record writes the built-in thesis motor out in full: it reads back as the default
    Scenario.from_mapping(Scenario(task='speed').to_mapping(), source='record')
    assert not caplog.records


def test_simulate_runs_the_adapter_an_adaptive_run_file_describes():
    """
    ``simulate(sc)`` of ``controller: adaptive`` adapts, as the graph does, to the last bit.

    Not the nominal drive under the adaptive name: the adapter node's parameters build the same
    adapter on the ROS-free loop (docs/running.md).
    """
    from im_bringup.testing import run_graph
    sc = replace(Scenario.from_file(DRIFT), duration=0.3)
    off = simulate(sc).summary
    g = run_graph(scenario=sc).summary
    assert g['ok'], g['failures']
    assert off['E_in_J'] == pytest.approx(g['E_in_J'], rel=1e-12)
    nominal = simulate(replace(sc, controller='nominal')).summary
    assert abs(nominal['E_in_J'] - off['E_in_J']) > 1e-3 * off['E_in_J']
    assert off['controller'] == 'adaptive'
