"""
``python -m im_studies.study_compare``: every law × strategy on the same drive (docs/baselines.md).

Its runs are the run files a user writes (``controller:``, the real plant's blocks, the drift),
its verdicts name the law that wins each row, and it runs as a command.
"""
import dataclasses
import json
import subprocess
import sys

from im_common.params import load_motor_file
from im_studies import study_compare as sc
import pytest


def test_the_cases_are_every_law_and_strategy_but_vhz_positioning():
    cases = list(sc.cases())
    assert len(cases) == len(sc.PLANTS) * len(sc.DRIFTS) * len(sc.STRATEGIES) * (3 + 4 + 4)
    assert not [c for c in cases if c[0] == 'vhz' and c[2] == 'position']


def test_the_real_plant_is_switched_delayed_and_drifts_in_its_resistance_only():
    real = sc.scenario('current_vector', 'min_loss', 'load_step', 'real, delay 1', 'chapter4')
    assert real.delay == 1 and real.inverter.switched and real.iron_loss
    assert set(real.variation) == {'R_r'}
    assert real.law == 'current_vector' and real.current_limit == sc.CURRENT_LIMIT
    ideal = sc.scenario('nominal', 'min_loss', 'position', 'ideal', 'chapter4')
    assert ideal.inverter is None and ideal.variation == 'chapter4' and ideal.law == 'thesis'


def test_verdicts_name_the_lowest_loss_and_error_and_skip_a_trip():
    rows = [{'plant': 'ideal', 'drift': 'none', 'task': 'speed', 'strategy': 'min_loss',
             'law': law, 'err_max': e, 'err_rms': e, 'E_loss_J': loss, 'E_in_J': 0.0,
             'i_max_A': 1.0, 'trip': trip}
            for law, e, loss, trip in (('nominal', 0.01, 80.0, ''),
                                       ('current_vector', 0.005, 84.0, ''),
                                       ('vhz', 0.001, 10.0, 'at 0.500 s, overcurrent'))]
    v, = sc.verdicts(rows)
    assert (v['lowest_loss'], v['lowest_error']) == ('nominal', 'current_vector')
    assert v['thesis_loss_ratio'] == 1.0 and v['thesis_error_ratio'] == pytest.approx(2.0)
    assert '| trip at 0.500 s, overcurrent |' in sc.markdown(rows)
    assert sc.figures({'pos_err_max_rad': 1.0, 'pos_err_rms_rad': 0.5, 'E_loss_J': 1.0,
                       'E_in_J': 2.0, 'i_max_A': 3.0, 'V_max_V': 4.0,
                       'trip': {'t': 0.25, 'reason': 'overcurrent'}},
                      'position')['trip'] == 'at 0.250 s, overcurrent'


@pytest.mark.slow
def test_the_study_runs_as_a_command_and_writes_its_rows_and_plot(tmp_path):
    out, png = tmp_path / 'c.json', tmp_path / 'c.png'
    r = subprocess.run([sys.executable, '-m', 'im_studies.study_compare', '--part', 'compare',
                        '--task', 'speed', '--plant', 'ideal', '--drift', 'none', '--json',
                        str(out), '--plot', str(png)], capture_output=True, text=True,
                       timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    doc = json.loads(out.read_text())
    assert len(doc['rows']) == 4 * 3 and len(doc['verdicts']) == 3
    assert '[12/12' in r.stderr and png.stat().st_size > 10_000
    rows = {(x['law'], x['strategy']): x for x in doc['rows']}
    # the same references: the current-vector controller, fed forward, tracks as the thesis law
    assert rows['current_vector', 'constant_flux']['err_max'] < 0.01
    assert rows['nominal', 'min_loss']['E_loss_J'] < rows['nominal', 'constant_flux']['E_loss_J']


def test_the_drive_check_runs_each_motor_on_the_real_plant_sensored_and_sensorless():
    """
    Both shipped motors, delay 1, the inverter-error compensation.

    A baseline takes no thesis gain; the thesis motor's check is the comparison's real plant with
    the compensation.
    """
    cases = list(sc.check_cases())
    assert len(cases) == 2 * 2 * 2 * 4 * 2 and {c[0] for c in cases} == {'thesis', 'krause_3hp'}
    for motor in sc.CHECK_MOTORS:
        for law, sensing in (('nominal', 'sensored'), ('current_vector', 'sensorless')):
            s = sc.check_scenario(motor, law, 'min_loss', 'load_step', sensing)
            assert s.delay == 1 and s.inverter.switched and s.iron_loss and s.law == (
                'thesis' if law == 'nominal' else law)
            assert s.sensorless == (sensing == 'sensorless') and s.compensation is not None
            assert s.motor == load_motor_file(sc.motor_path(motor))
            assert ('k_v' in s.controller_options) == (law == 'nominal' and motor != 'thesis')
    thesis = sc.check_scenario('thesis', 'vhz', 'min_loss', 'speed', 'sensored')
    real = sc.scenario('vhz', 'min_loss', 'speed', 'real, delay 1', 'none')
    assert thesis == dataclasses.replace(real, compensation=thesis.compensation)


def test_the_check_divides_by_the_thesis_law_of_the_same_run_and_names_what_fails():
    def row(law, sensing, rms, trip=''):
        return {'motor': 'thesis', 'task': 'speed', 'strategy': 'min_loss', 'law': law,
                'sensing': sensing, 'err_max': 2 * rms, 'err_rms': rms, 'E_loss_J': 80.0,
                'E_in_J': 90.0, 'E_dc_J': 95.0, 'i_max_A': 10.0, 'trip': trip}
    rows = [row('nominal', 'sensored', 0.1), row('current_vector', 'sensored', 0.15),
            row('nominal', 'sensorless', 0.2), row('current_vector', 'sensorless', 0.5),
            row('flux_vector', 'sensorless', 0.1, trip='at 0.100 s, overcurrent')]
    q = sc.rms_over_thesis(rows)
    assert [q[id(r)] for r in rows] == [1.0, pytest.approx(1.5), 1.0, pytest.approx(2.5), None]
    text = sc.check_markdown(rows)
    line = '| thesis | speed | min_loss | current_vector | sensored | 0.3 / 0.15 rad/s | 1.5 |'
    assert line in text
    assert text.endswith('5 runs, 1 tripped (thesis speed min_loss flux_vector sensorless); the '
                         "current- and flux-vector controllers' speed error RMS within 2× the "
                         "thesis law's in 1 of 3 runs (beyond: thesis speed min_loss "
                         'current_vector sensorless; thesis speed min_loss flux_vector '
                         'sensorless).')


@pytest.mark.slow
def test_the_quick_mode_runs_the_check_as_a_command(tmp_path):
    out, page = tmp_path / 'c.json', tmp_path / 'c.md'
    page.write_text('# c\n<!-- check:begin -->\nold\n<!-- check:end -->\n')
    r = subprocess.run([sys.executable, '-m', 'im_studies.study_compare', '--part', 'check',
                        '--quick', '--motor', 'krause_3hp', '--task', 'load_step', '--json',
                        str(out), '--doc', str(page)], capture_output=True, text=True,
                       timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    doc = json.loads(out.read_text())
    assert doc['rows'] == [] and len(doc['check']) == 4 * 2 * 2 and '[16/16' in r.stderr
    assert {x['motor'] for x in doc['check']} == {'krause_3hp'}
    assert all(x['E_dc_J'] > x['E_in_J'] > 0 and not x['trip'] for x in doc['check'])
    assert sc.check_markdown(doc['check']) in page.read_text() and 'old' not in page.read_text()


def test_the_comparison_page_holds_the_committed_rows():
    """docs/comparison.md's tables are docs/data/compare.json's, rendered by the study's code."""
    import os
    root = os.path.join(os.path.dirname(__file__), '..')
    rows = sc.load_rows(os.path.join(root, 'docs', 'data', 'compare.json'))
    assert len(rows) == len(list(sc.cases()))
    page = open(os.path.join(root, 'docs', 'comparison.md')).read()
    check = sc.load_check_rows(os.path.join(root, 'docs', 'data', 'compare.json'))
    assert len(check) == len(list(sc.check_cases()))
    stale = ('docs/comparison.md is stale: python -m im_studies.study_compare --from-json '
             'docs/data/compare.json --doc docs/comparison.md')
    assert sc.markdown(rows) in page and sc.check_markdown(check) in page, stale


def test_a_file_that_is_no_study_output_is_one_line(tmp_path):
    bad = tmp_path / 'x.json'
    bad.write_text('{"rows": 3}')
    r = subprocess.run([sys.executable, '-m', 'im_studies.study_compare', '--from-json',
                        str(bad)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and r.stderr.strip() == \
        f'study_compare: error: {bad}: not a study_compare --json (no rows)'
