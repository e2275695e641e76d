"""
The loss floor of any run file (``python -m im_studies.loss_bound``, docs/controller.md §10).

The thesis tasks' bound (make reproduce) is this floor of their run; a run file of one's own —
a profile, a load, a steady start — gets its floor from each strategy's own start flux, and no
strategy beats it while optimal reaches it.
"""
import json

from im_bringup.offline import Scenario
from im_studies.loss_bound import main, run_loss_bound, start_flux
import pytest

RUN = """task: speed
start: steady
omega0: 100.0
duration: 2.0
profile: {setpoints: [{t: 0.0, velocity: 100.0}, {t: 0.3, velocity: -100.0, duration: 1.0}]}
load: {kind: constant, tau: 2.0}
"""


@pytest.mark.slow
def test_a_run_file_of_ones_own_has_a_floor_optimal_reaches_and_none_beats(tmp_path, capsys):
    path = tmp_path / 'reversal.yaml'
    path.write_text(RUN)
    out = tmp_path / 'floor.json'
    assert main([str(path), '--run', 'min_loss', '--run', 'optimal', '--run', 'min_energy',
                 '--json', str(out)]) == 0
    assert 'loss floor of' in capsys.readouterr().out
    res = json.loads(out.read_text())
    runs = res['runs']
    # a steady start is each strategy's own flux: min_loss and optimal start at 0.42 Wb,
    # min_energy at its floor 0.2 Wb — one floor per start (before, one floor from the file's
    # strategy put min_loss 2.8 % below its "floor")
    assert runs['min_loss']['start_flux_Wb'] != runs['min_energy']['start_flux_Wb']
    for st, r in runs.items():
        assert r['E_loss_J'] >= r['E_loss_bound_J'] * (1.0 - 1e-4), st
    assert runs['optimal']['ratio_loss'] == pytest.approx(1.0, abs=2e-3)
    assert runs['min_loss']['ratio_loss'] > 1.005
    assert runs['min_energy']['ratio_loss'] > 2.0


def test_the_floor_grows_with_the_load_and_copper_is_below_the_total(tmp_path):
    """Copper only ≤ copper + core; a heavier load can only raise the floor (same start)."""
    path = tmp_path / 'r.yaml'
    path.write_text(RUN.replace('duration: 2.0', 'duration: 0.5'))
    sc = Scenario.from_file(str(path))
    light = run_loss_bound(sc, step=4e-3)
    assert run_loss_bound(sc, step=4e-3, core=False).copper_J <= light.loss_J
    path.write_text(RUN.replace('duration: 2.0', 'duration: 0.5').replace('tau: 2.0', 'tau: 6.0'))
    heavy = run_loss_bound(Scenario.from_file(str(path)), step=4e-3, phi0=start_flux(sc))
    assert heavy.loss_J > light.loss_J


def test_the_torque_task_and_a_bad_file_get_one_line(tmp_path, capsys):
    path = tmp_path / 't.yaml'
    path.write_text('task: torque\n')
    assert main([str(path)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith('loss_bound: error:') and 'torque task' in err and '\n' not in err
    assert main([str(tmp_path / 'missing.yaml')]) == 2
    err = capsys.readouterr().err.strip()
    assert 'missing.yaml' in err and '\n' not in err
