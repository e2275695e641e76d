"""The study entry point and the sampled-data limit of the thesis's gains."""
import json

from im_studies.study import current_loop_estimate, is_stable, main


def test_sampling_limit_matches_the_scalar_current_loop():
    # σL_s ė = −R_eq e − k₁ e_k: the sampled current loop loses stability at
    # T_s = −(σL_s/R_eq) ln(1 − 2R_eq/(R_eq + k₁)) ≈ 318 µs; the full loop follows it.
    est = current_loop_estimate(40.0)
    assert 3.0e-4 < est < 3.3e-4
    assert is_stable('position', 'constant_flux', 0.95 * est, duration=0.5)[0]
    assert not is_stable('position', 'constant_flux', 1.05 * est, duration=0.5)[0]


def test_study_quick_run_writes_json(tmp_path, capsys):
    assert main(['--quick', '--no-limit', '--no-exponent1', '--out', str(tmp_path)]) == 0
    data = json.loads((tmp_path / 'study.json').read_text())
    rows = data['runs_core_exponent_2']
    assert {(r['task'], r['strategy']) for r in rows} == {
        (t, s) for t in ('position', 'speed') for s in ('min_energy', 'constant_flux', 'min_loss')}
    assert all(r['balance_relative'] < 1e-5 for r in rows)
    assert 'Energy table' in capsys.readouterr().out
