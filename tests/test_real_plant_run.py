"""
The real plant in a run: one description (run file + motor file) on every path.

A run file with an inverter, sensors and a saturated, warming motor with an acting iron loss runs
the speed task on the ROS-free loop and in the in-process graph with the same E_in; the bag holds
the temperatures and the inverter's truth; a bad block is one line naming the key.
"""
import os

from im_bringup.run_file import RunFileError, Scenario
from im_common.params import load_motor_blocks, load_motor_file, rated_flux, shipped_motors_dir
from im_common.saturation import saturation_from_dict
import pytest

MOTORS = shipped_motors_dir()
RUN = """task: speed
duration: {duration}
motor: {motor}
saturation: motor
thermal: motor
iron_loss: true
inverter: {{V_dc: 340.0, pwm_frequency: 10000.0, deadtime: 2.0e-6, v_on: 1.0, r_on: 0.02}}
sensors: {{encoder_lines: 2048, adc_bits: 12, current_range: 40.0}}
"""


def _run_file(tmp_path, duration=0.05, motor='thesis.yaml', extra=''):
    p = tmp_path / 'run.yaml'
    p.write_text(RUN.format(duration=duration, motor=os.path.join(MOTORS, motor)) + extra)
    return str(p)


@pytest.mark.parametrize('name', ['thesis', 'krause_3hp'])
def test_shipped_curves_put_rated_flux_at_87_5_percent_of_the_linear_flux(name):
    path = os.path.join(MOTORS, f'{name}.yaml')
    m = load_motor_file(path)
    blocks = load_motor_blocks(path)
    sat = saturation_from_dict(blocks['saturation'], m.L_M)
    psi = m.theta * rated_flux(m)
    assert 0.85 <= sat.L_M(psi) / m.L_M <= 0.90
    assert set(blocks) == {'saturation', 'thermal'}


def test_run_record_holds_every_block_and_round_trips(tmp_path):
    sc = Scenario.from_file(_run_file(tmp_path))
    rec = sc.to_mapping()
    for key in ('inverter', 'sensors', 'saturation', 'thermal'):
        assert isinstance(rec[key], dict), key
    assert rec['iron_loss'] is True and rec['saturation']['S'] == 7.0
    again = Scenario.from_mapping(rec)
    assert again.to_mapping() == rec and again.node_parameters() == sc.node_parameters()
    plant = sc.node_parameters()['plant']
    assert plant['iron_loss'] is True and plant['inverter.enabled'] is True
    assert plant['inverter.deadtime'] == 2e-06 and plant['sensors.encoder_lines'] == 2048
    # without the keys the plant's parameters are the ideal plant's, unchanged
    ideal = Scenario(task='speed').node_parameters()['plant']
    assert not {'inverter', 'sensors', 'saturation', 'thermal', 'iron_loss'} & set(ideal)
    assert not [k for k in ideal if k.startswith(('inverter.', 'sensors.'))]


@pytest.mark.parametrize('extra, key', [
    ('inverter: {V_dc: 340.0, pwm_frequency: 10000.0, deadtime: 2.0e-5}\n', 'inverter.deadtime'),
    ('inverter: {V_dc: 250.0, pwm_frequency: 10000.0}\n', 'inverter.V_dc'),
    ('sensors: {encoder_lines: 0}\n', 'sensors.encoder_lines'),
    ('sensors: {adc_bits: 0}\n', 'sensors.adc_bits'),
    ('saturation: {table: [[0.3, 4.0], [0.4, 3.0]]}\n', 'saturation.table[1]'),
])
def test_a_bad_block_is_one_line_naming_the_key(tmp_path, extra, key):
    text = RUN.format(duration=0.05, motor=os.path.join(MOTORS, 'thesis.yaml'))
    top = extra.split(':')[0]
    text = '\n'.join(line for line in text.splitlines() if not line.startswith(top + ':'))
    p = tmp_path / 'run.yaml'
    p.write_text(text + '\n' + extra)
    with pytest.raises(RunFileError) as exc:
        Scenario.from_file(str(p))
    assert f': {key}: ' in str(exc.value) and '\n' not in str(exc.value), str(exc.value)


def test_motor_block_needs_a_motor_file():
    with pytest.raises(Exception, match='saturation.*motor file'):
        Scenario(task='speed', saturation='motor')


@pytest.mark.parametrize('extra', ['', 'compensation: inverter\n'])
def test_graph_equals_the_offline_loop_with_every_block_on(tmp_path, extra):
    """
    The in-process graph and the ROS-free loop: the same E_in; the truth topics recorded.

    With the inverter-error compensation too: the controller, observer and adapter nodes get it
    from the run file as the ROS-free loop does.
    """
    from im_bringup.offline import simulate
    from im_bringup.testing import run_graph
    from im_common import topics as T
    from im_recording.bag import info
    run = _run_file(tmp_path, duration=0.05, extra=extra)
    off = simulate(Scenario.from_file(run)).summary
    bag = str(tmp_path / 'g.mcap')
    g = run_graph(scenario=run, record=bag)
    assert g.summary['ok'], g.summary.get('failures')
    assert g.summary['E_in_J'] == pytest.approx(off['E_in_J'], rel=1e-12)
    for s in (off, g.summary):
        assert abs(s['balance_residual_J']) <= 1e-6 * s['E_in_J']
    counts = info(bag).counts
    assert counts[T.TRUTH_TEMPERATURE] > 0 and counts[T.TRUTH_INVERTER] > 0


@pytest.mark.processes
@pytest.mark.slow
def test_scenario_processes_give_the_same_e_in_with_every_block_on(tmp_path):
    """``scenario --processes`` of the run file: E_in as in one process, the truth recorded."""
    import json
    import subprocess

    from im_bringup.processes import executable_path
    from im_bringup.testing import run_graph
    from im_common import topics as T
    from im_recording.bag import info
    run = _run_file(tmp_path, duration=0.05)
    bag = tmp_path / 'p.mcap'
    r = subprocess.run([executable_path('im_bringup', 'scenario'), run, '--processes', '--record',
                        str(bag), '--no-progress'], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    s = json.loads((tmp_path / 'p.json').read_text())
    live = run_graph(scenario=run)
    assert s['E_in_J'] == pytest.approx(live.summary['E_in_J'], rel=1e-12)
    assert abs(s['balance_residual_J']) <= 1e-6 * s['E_in_J']
    counts = info(str(bag)).counts
    assert counts[T.TRUTH_TEMPERATURE] > 0 and counts[T.TRUTH_INVERTER] > 0
