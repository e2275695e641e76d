"""
The wall times of the studies, ``make reproduce`` and the campaign, and the real plant's switch.

Each command writes ``wall_s``, ``wall_parts_s`` and ``real_plant_kernel`` beside its results
and prints them (:class:`im_studies.campaign_pool.WallTime`, docs/commands.md); the reproduce
summary carries them in a last row that is not a run. ``IM_REAL_PLANT_KERNEL=0`` selects the
real plant's pure-Python reference (docs/plant.md §9). No bound on any time here: the figures'
presence and form only.
"""
import json
import os
import subprocess
import sys

from im_plant import real_plant_kernel
from im_plant.real_plant import RealPlant
from im_studies import reproduce, study, study_delay, study_real_plant
from im_studies.campaign_pool import wall_line, WallTime
from im_studies.readme_status import load_summary
import pytest


def _check(doc: dict, parts) -> None:
    """Check that ``doc`` carries the wall-time figures with one entry per part."""
    assert isinstance(doc['wall_s'], float)
    assert list(doc['wall_parts_s']) == list(parts)
    assert all(isinstance(v, float) for v in doc['wall_parts_s'].values())
    assert doc['real_plant_kernel'] is RealPlant.use_kernel


def test_wall_time_adds_up_a_part_timed_twice_and_prints_one_line():
    clock = WallTime()
    for _ in range(2):
        with clock.part('a'):
            pass
    with pytest.raises(ZeroDivisionError):
        with clock.part('b'):
            1 / 0
    fig = clock.figures()
    _check(fig, ['a', 'b'])
    line = wall_line(fig)
    assert line.startswith('wall time ') and '(a ' in line and '\n' not in line
    assert line.endswith('compiled (numba)' if RealPlant.use_kernel else
                         'pure Python (IM_REAL_PLANT_KERNEL=0 or no numba)')
    assert wall_line(dict(fig, wall_parts_s={})).split(';')[0].endswith(' s')


def test_study_delay_writes_its_wall_time(tmp_path, capsys):
    out = tmp_path / 'delay.json'
    assert study_delay.main(['--part', 'current loop', '--json', str(out)]) == 0
    doc = json.loads(out.read_text())
    _check(doc, ['current loop'])
    assert doc['current loop']                      # the rows as before, beside the figures
    assert capsys.readouterr().out.rstrip().splitlines()[-1].startswith('wall time ')


def test_study_real_plant_writes_its_wall_time_per_part(tmp_path, monkeypatch, capsys):
    row = {'motor': 'thesis', 'plant': 'ideal plant', 'dip': 1.0, 'recovery_s': 0.1,
           'trip': None, 'step': '2 → 8 N·m'}
    monkeypatch.setattr(study_real_plant, 'run_load_step', lambda: [row])
    out = tmp_path / 'real_plant.json'
    assert study_real_plant.main(['--part', 'load_step', '--json', str(out)]) == 0
    doc = json.loads(out.read_text())
    _check(doc, ['load_step'])
    assert doc['load_step'] == [row]
    assert capsys.readouterr().out.rstrip().splitlines()[-1].startswith('wall time ')


def test_study_writes_its_wall_time_per_part(tmp_path, monkeypatch, capsys):
    keys = ('E_in_J', 'E_loss_J', 'E_copper_J', 'E_core_J', 'W_load_J', 'E_friction_J',
            'dE_kinetic_J', 'dW_magnetic_J', 'balance_residual_J', 'pos_err_max_rad',
            'speed_err_max_rad_s', 'torque_err_max_Nm', 'V_max_V', 'i_max_A', 'us_per_compute',
            'us_per_observer_step')
    rows = [dict(dict.fromkeys(keys, 1.0), task='speed', strategy='min_loss', thesis_E_in_J=None,
                 thesis_E_loss_J=None)]
    monkeypatch.setattr(study, 'energy_table', lambda *a: rows)
    assert study.main(['--quick', '--no-limit', '--out', str(tmp_path)]) == 0
    doc = json.loads((tmp_path / 'study.json').read_text())
    _check(doc, ['exponent2', 'exponent1'])
    assert doc['runs_core_exponent_2'] == rows
    assert capsys.readouterr().out.rstrip().splitlines()[-1].startswith('wall time ')


def test_reproduce_writes_its_wall_time_as_a_last_row_that_is_not_a_run(tmp_path, monkeypatch,
                                                                        capsys):
    """
    Check the reproduce summary's wall row: after the runs and bound rows, not in the tables.

    The summary stays a list the results page's generator reads (readme_status.load_summary).
    """
    def run_all(specs, out, record=False, workers=None):
        figures = dict(dict.fromkeys(reproduce.CH3_KEYS[4:], 1.0), rate_hz=1e4, ok=True,
                       wall_s=0.5)
        return [dict(s, **figures) for s in specs]
    monkeypatch.setattr(reproduce, 'run_all', run_all)
    monkeypatch.setattr(reproduce, 'bound_rows', lambda results: [])
    assert reproduce.main(['--out', str(tmp_path), '--only', 'ch3']) == 0
    runs = load_summary(str(tmp_path / 'summary.json'))
    *rows, wall = runs
    assert len(rows) == len(reproduce.chapter3_runs() + reproduce.optimal_runs())
    assert wall['strategy'] == 'wall' and 'task' not in wall
    _check(wall, ['runs', 'bound'])
    assert wall['run_s_by_part'] == {'ch3': 0.5 * len(rows)}
    assert reproduce.markdown(runs) == reproduce.markdown(rows)
    assert reproduce.bound_markdown(runs) == reproduce.bound_markdown(rows)
    md = (tmp_path / 'summary.md').read_text()
    assert md.rstrip().splitlines()[-1].startswith('wall time ')
    assert capsys.readouterr().out.rstrip().splitlines()[-1].startswith('wall time ')


def _use_kernel(value):
    """Return ``RealPlant.use_kernel`` in a fresh Python with IM_REAL_PLANT_KERNEL=value."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))   # this tree's src/
    env.pop('IM_REAL_PLANT_KERNEL', None)
    if value is not None:
        env['IM_REAL_PLANT_KERNEL'] = value
    p = subprocess.run([sys.executable, '-c', 'from im_plant.real_plant import RealPlant; '
                        'print(RealPlant.use_kernel)'], env=env, capture_output=True, text=True,
                       timeout=120)
    assert p.returncode == 0, p.stderr
    return p.stdout.strip()


@pytest.mark.processes
def test_im_real_plant_kernel_0_selects_the_pure_python_reference():
    assert _use_kernel('0') == 'False'
    assert _use_kernel(None) == _use_kernel('1') == str(real_plant_kernel.available)
