"""
The whole drive's losses: the drive-loss strategy and the efficiency map (docs/efficiency.md).

The strategy: with loss_scope drive the loss-optimizing flux minimizes the motor's losses plus
the inverter's r|i|² + c|i| (im_common.inverter.Inverter.steady_loss_coefficients), checked
against a brute-force minimum. The map: the command on a small grid of the real plant, its JSON
(every efficiency in [0, 1), zero only without mechanical output, the books closed), its
resumption and its refusals.
"""
import json
import math
import os

from im_bringup.run_file import RunFileError, Scenario
from im_common.inverter import Inverter, phase_values
from im_common.params import THESIS_MOTOR
from im_controller.flux import _drive_loss, flux_min_loss
from im_controller.reference import ModelCoefficients
from im_studies.efficiency_map import (build_parser, IEC_POINTS, main, MapFileError,
                                       read_map_file, run_map)
import numpy as np
import pytest

INV = {'V_dc': 325.0, 'pwm_frequency': 1e4, 'deadtime': 2e-6, 'v_on': 1.0, 'r_on': 0.02,
       'e_sw': 2e-4, 'v_sw': 300.0, 'i_sw': 10.0}


def test_the_steady_inverter_loss_is_the_mean_of_the_phase_losses():
    """r|i|² + c|i| is the time mean of Σ (v_on|i_x| + r_on i_x² + f_sw k V |i_x|) over a cycle."""
    inv = Inverter.from_block(INV)
    r, c = inv.steady_loss_coefficients()
    k = inv.switching_coefficient
    mag = 9.0
    total = 0.0
    n = 3600
    for j in range(n):
        ang = 2.0 * math.pi * j / n
        for i_x in phase_values(mag * math.cos(ang), mag * math.sin(ang)):
            total += (inv.v_on * abs(i_x) + inv.r_on * i_x * i_x
                      + inv.pwm_frequency * k * inv.V_dc * abs(i_x))
    assert total / n == pytest.approx(r * mag * mag + c * mag, rel=1e-6)
    assert Inverter.from_block({'delay': 1}).steady_loss_coefficients() == (0.0, 0.0)


@pytest.mark.parametrize('tau, omega', [(0.5, 50.0), (3.0, 18.3), (3.0, 91.6), (6.0, 91.6),
                                        (12.0, 183.0)])
def test_the_drive_strategy_finds_the_drive_loss_minimum(tau, omega):
    c = ModelCoefficients.from_params(THESIS_MOTOR)
    rc = Inverter.from_block(INV).steady_loss_coefficients()
    args = (c, tau, omega, 0.05, 1.2, 0.012, 0.012)
    motor = flux_min_loss(*args)
    drive = flux_min_loss(*args, inverter=rc)
    phis = np.linspace(0.05, 1.2, 46001)
    losses = [_drive_loss(c, tau, omega, 0.012, 0.012, 2.0, None, rc, p) for p in phis]
    best = phis[int(np.argmin(losses))]
    assert drive == pytest.approx(best, abs=5e-5)
    # never more than the motor-only flux's drive loss; lower flux (less current to switch)
    assert _drive_loss(c, tau, omega, 0.012, 0.012, 2.0, None, rc, drive) <= \
        _drive_loss(c, tau, omega, 0.012, 0.012, 2.0, None, rc, motor) + 1e-12
    assert drive < motor
    # no inverter: the motor's optimum as before, to the bit
    assert flux_min_loss(*args, inverter=(0.0, 0.0)) == motor


def test_loss_scope_drive_reaches_the_controller_and_needs_an_inverter(tmp_path):
    sc = Scenario(task='speed', strategy='min_loss', inverter=INV,
                  loss_scope='drive')
    r, c = Inverter.from_block(INV).steady_loss_coefficients()
    cfg = sc.controller_config()
    assert (cfg.drive_loss_r, cfg.drive_loss_c) == (r, c)
    ctl = sc.node_parameters()['controller']
    assert (ctl['drive_loss_r'], ctl['drive_loss_c']) == (r, c)
    assert Scenario.from_mapping(sc.to_mapping()).loss_scope == 'drive'
    assert 'drive_loss_r' not in Scenario(task='speed', inverter=INV).node_parameters()[
        'controller']
    run = tmp_path / 'run.yaml'
    run.write_text('task: speed\nstrategy: min_loss\nloss_scope: drive\n')
    with pytest.raises(RunFileError) as exc:
        Scenario.from_file(str(run))
    text = str(exc.value)
    assert 'loss_scope' in text and 'inverter' in text and '\n' not in text, text
    run.write_text('task: speed\nloss_scope: dc\n')
    with pytest.raises(RunFileError, match='loss_scope'):
        Scenario.from_file(str(run))


RUN = """
task: speed
controller: nominal
strategy: min_loss
motor: thesis
current_limit: 17.0
v_limit: 0
inverter: {V_dc: 325.0, pwm_frequency: 10000.0, deadtime: 2.0e-6, v_on: 1.0, r_on: 0.02,
           e_sw: 2.0e-4, v_sw: 300.0, i_sw: 10.0, delay: 1}
compensation: inverter
iron_loss: true
compare:
  - {strategy: constant_flux}
  - {strategy: min_loss, loss_scope: drive, label: drive}
"""


def _args(out, *extra):
    return build_parser().parse_args(['x', '--speeds', '2', '--torques', '2', '--settle', '0.2',
                                      '--window', '0.1', '--workers', '2', '--out', str(out),
                                      *extra])


@pytest.mark.slow
def test_the_map_of_a_small_grid_and_the_standard_points(tmp_path, capsys):
    run = tmp_path / 'map.yaml'
    run.write_text(RUN)
    out = tmp_path / 'out'
    doc = run_map(str(run), _args(out), progress=False)
    assert doc['drives'] == ['nominal_constant_flux', 'drive']
    pts = doc['points']
    assert len(pts) == 2 * (4 + len(IEC_POINTS))
    held = [p for p in pts if p['held']]
    assert len(held) >= len(pts) - 4          # at most the rated corner, per drive and set
    for p in held:
        for key in ('eta_motor', 'eta_inverter', 'eta_system'):
            assert 0.0 <= p[key] < 1.0, (key, p)
        if p['speed_rel'] == 0.0 or p['torque_rel'] == 0.0:    # no output: zero, only there
            assert p['eta_system'] == 0.0 and p['eta_motor'] == 0.0
            assert abs(p['P_mech']) < 1e-3 * 2200.0             # the speed loop's jitter
        else:
            assert p['eta_system'] > 0.0 and p['P_mech'] > 0.0
            assert p['eta_system'] == pytest.approx(p['eta_motor'] * p['eta_inverter'],
                                                    rel=1e-12)
        assert p['balance_relative'] <= 1e-6 and p['balance_dc_relative'] <= 1e-9
        assert p['P_switching'] > 0.0 and p['P_conduction'] > p['P_switching']
        # the books over the window: what was drawn is the output, the losses and the storage
        assert p['P_dc'] == pytest.approx(p['P_mech'] + p['P_system_loss'] + p['P_storage'],
                                          rel=1e-6, abs=1e-6)
    for p in pts:
        if not p['held']:
            assert p['reason'] and 'eta_system' not in p
    iec = {(e['speed_pct'], e['torque_pct']): e for e in doc['iec']}
    assert set(iec) == set(IEC_POINTS)
    e = iec[(50, 50)]['drive']
    assert e['P_loss_pct'] == pytest.approx(100.0 * e['P_loss_W'] / 2200.0)
    assert json.loads((out / 'efficiency_map.json').read_text())['points'] == json.loads(
        json.dumps(pts))
    names = os.listdir(out)
    assert 'efficiency_drive.png' in names and 'difference_drive_vs_nominal_constant_flux.png' \
        in names
    report = (out / 'report.md').read_text()
    assert '| 50 | 50 |' in report and 'IEC 61800-9-2' in report
    # the same command again: every point from the journal, nothing run twice, the same rows
    again = run_map(str(run), _args(out), progress=False)
    assert again['points'] == doc['points']
    # another map in the same directory is refused, in one line
    assert main([str(run), '--speeds', '3', '--out', str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith('efficiency_map: error:') and 'another campaign' in err
    assert '\n' not in err


@pytest.mark.parametrize('text, where', [
    ('task: speed\ncompare: {strategy: min_loss}\n', 'compare: must be a non-empty list'),
    ('task: speed\ncompare: [{strategy: min_los}]\n', 'compare[0]: strategy'),
    ('task: speed\ncompare: [{strategy: min_loss}, {strategy: min_loss}]\n',
     "compare[1]: the label 'nominal_min_loss' is another entry's"),
    ('task: speed\nmotor: thesis\ncompare: [{bogus: 1}]\n', 'compare[0]: bogus'),
])
def test_a_bad_compare_list_is_one_line_naming_the_entry(tmp_path, text, where):
    run = tmp_path / 'map.yaml'
    run.write_text(text)
    with pytest.raises(MapFileError) as exc:
        read_map_file(str(run))
    line = str(exc.value)
    assert where in line and '\n' not in line, line


def test_the_shipped_map_files_read():
    runs = os.path.join(os.path.dirname(os.path.abspath(__file__)), '..', 'src', 'im_bringup',
                        'config', 'runs')
    for name in ('efficiency_thesis.yaml', 'efficiency_krause_3hp.yaml'):
        drives = read_map_file(os.path.join(runs, name))
        assert [d.label for d in drives][-1] == 'min_loss_drive'
        assert all(d.scenario.inverter.e_sw > 0 for d in drives)


def test_the_page_is_its_data():
    """docs/efficiency.md's generated block is what its kept data gives (efficiency_doc)."""
    from im_studies.efficiency_doc import BEGIN, block, END
    root = os.path.join(os.path.dirname(os.path.abspath(__file__)), '..')
    with open(os.path.join(root, 'docs', 'data', 'efficiency.json')) as f:
        data = json.load(f)
    with open(os.path.join(root, 'docs', 'efficiency.md')) as f:
        page = f.read()
    assert BEGIN + page.split(BEGIN, 1)[1].split(END, 1)[0] + END == block(data)
    for name, m in data.items():
        assert m['runs'] == len(m['drives']) * (100 + len(IEC_POINTS)), name
        assert os.path.exists(os.path.join(root, 'docs', 'figures', f'efficiency_{name}.png'))
        for rows in m['grid'].values():
            for w, t, eta, _, _ in rows:
                assert eta is None or (0.0 <= eta < 1.0 and (eta > 0.0) == (w * t > 0.0))
