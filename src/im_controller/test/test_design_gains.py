"""
design_gains: certified drive gains at the node period, and the CLI.

See im_controller.gain_design.drive.

Physics asserted: the certified current gain makes every sampled current-error model contract, the
thesis's 40 V/A at 1 ms does not (sampled pole a − b·k1 leaves the unit circle), and the offline
closed loop at 1 ms stays bounded with the certified gains while the thesis's diverges (that
closed-loop part needs the offline loop of im_bringup: tests/test_gain_design_closed_loop.py).
"""
import json
import math
import re

from im_controller import design_gains
from im_controller.gain_design import drive
import numpy as np
import pytest

SMALL_OBS = {'R_r': 2, 'L_s': 2, 'L_r': 2, 'L_sr': 2, 'omega_r': 1}


@pytest.fixture(scope='module')
def gains_1ms():
    return drive.design_drive_gains(1e-3, observer_param_points=SMALL_OBS)


def _floats(text, key):
    m = re.search(rf'{key}: \[([^\]]*)\]', text)
    assert m, f'{key} missing'
    return [float(x) for x in m.group(1).split(',')]


@pytest.mark.slow
def test_1ms_current_gain_certified_and_thesis_gain_rejected(gains_1ms):
    cur = gains_1ms.current
    assert cur.certified and gains_1ms.certified
    s = cur.summary()
    assert s['lyapunov_rho_dense'] < math.exp(-100.0 * 1e-3)          # ≥ 100 1/s guaranteed
    assert cur.dense_spectral_radius < 1.0
    ok = drive.certify_current_gain(cur.gain, 1e-3, decay_rate=cur.decay_rate)
    assert ok.certified
    bad = drive.certify_current_gain(40.0 * np.eye(2), 1e-3)
    assert not bad.certified
    # closed form: the sampled scalar pole a − b k1 of the nominal motor is outside the unit circle
    a, b = drive.subsystem_ab(np.array([[0.687 + 0.842 * (0.08136 / 0.08528) ** 2,
                                         0.08397 - 0.08136 ** 2 / 0.08528]]), 1e-3)
    assert abs(a[0] - 40.0 * b[0]) > 1.0
    assert abs(a[0] - cur.gain[0, 0] * b[0]) < 1.0


@pytest.mark.slow
def test_observer_injection_certified_over_the_speed_range(gains_1ms):
    o = gains_1ms.observer
    assert o.certified and o.omega_max == 200.0
    assert o.worst_rho_dense < 1.0 and o.worst_spectral_radius < 1.0
    L = gains_1ms.L
    assert L.shape == (4, 2) and np.allclose(L[2:], 0.0)


@pytest.mark.slow
def test_writes_parameters_yaml_with_certificate(tmp_path):
    out = tmp_path / 'gains.yaml'
    rc = design_gains.main(['--period', '1e-3', '--omega-max', '0', '--out', str(out)])
    assert rc == 0
    text = out.read_text()
    assert 'controller:\n  ros__parameters:' in text and 'observer:\n  ros__parameters:' in text
    assert len(_floats(text, 'current_gain')) == 4
    assert len(_floats(text, 'injection_gain')) == 8
    assert re.search(r'gain_period: 0\.001', text)
    cert = json.loads(out.with_suffix('.json').read_text())
    assert cert['certified'] and cert['current']['certified'] and cert['observer']['certified']
    assert cert['current']['dense_spectral_radius'] < 1


@pytest.mark.slow
def test_no_yaml_without_certificate(tmp_path):
    out = tmp_path / 'gains.yaml'
    # 1000 1/s at 1 ms is beyond the largest feasible current-error rate (about 155 1/s)
    rc = design_gains.main(['--period', '1e-3', '--omega-max', '0', '--decay-rate', '1000',
                            '--out', str(out)])
    assert rc == 1
    assert not out.exists()
    cert = json.loads(out.with_suffix('.json').read_text())
    assert cert['current']['status'] == 'infeasible' and cert['current']['gain'] is None


@pytest.mark.parametrize('args', [['--period', '0'], ['--period', 'nan'], ['--omega-max', '-1'],
                                  ['--rate-fraction', '1.5']])
def test_bad_arguments_are_rejected(args, capsys):
    with pytest.raises(SystemExit) as exc:
        design_gains.main(args)
    assert exc.value.code == 2
    assert args[0] in capsys.readouterr().err


# ---------------------------------------------------------------------------------------------
# 100 µs: the thesis's gains certified as they are (docs/robust.md §7 (e))
# ---------------------------------------------------------------------------------------------
@pytest.fixture(scope='module')
def gains_100us():
    return drive.design_drive_gains(1e-4, observer_param_points=SMALL_OBS)


def test_thesis_observer_error_map_is_the_observers_own():
    """
    Check the observer's one-period error map M against two observers and the exact map.

    M built column by column propagates the difference of two observers fed the same data, and
    differs from the exact held-injection ZOH map only at RK4 order (one 100 µs sub-step).
    """
    from im_common.params import THESIS_MOTOR
    from im_observer.observer import RotorFluxObserver
    m = THESIS_MOTOR
    p, w, k_e = (m.R_r, m.L_s, m.L_r, m.L_sr), 150.0, 1.0 / m.sigma
    M = drive.thesis_observer_error_map(p, w, 1e-4, k_e)
    x1, x2 = (1.0, -2.0, 0.3, 0.1), (0.5, 1.0, -0.2, 0.4)
    o1 = RotorFluxObserver(m, k_e=k_e, x0=x1)
    o2 = RotorFluxObserver(m, k_e=k_e, x0=x2)
    d = np.subtract(o1.step(1e-4, 30.0, -10.0, 2.0, 1.0, w),
                    o2.step(1e-4, 30.0, -10.0, 2.0, 1.0, w))
    assert np.allclose(d, M @ np.subtract(x1, x2), rtol=0, atol=1e-12)
    Mz, _ = drive.held_injection_zoh_map(p, w, 1e-4, k_e)
    assert np.abs(M - Mz).max() < 1e-5 * np.abs(M).max()


@pytest.mark.slow
def test_100us_thesis_observer_certified_1ms_not(gains_100us):
    c = gains_100us.thesis_observer
    assert gains_100us.observer_structure == 'thesis' and c.certified
    # k_e = 1/σ̂ of the nominal motor
    assert abs(c.k_e - 1.0 / 0.07562) < 1e-3
    assert c.scope.startswith('frozen-parameter') and c.speed_step >= 20.0
    assert c.worst_rho_dense < math.exp(-1.0 * 1e-4)                # ≥ 1 1/s for every speed path
    assert c.worst_spectral_radius < 1.0
    assert c.common_P_over_speed is False                           # the held skew injection
    assert c.rk4_vs_zoh_map < 1e-6 and c.model_residual < 1e-6
    bad = drive.certify_thesis_observer(1e-3, param_points=SMALL_OBS)
    assert not bad.certified and bad.worst_spectral_radius > 1.0


@pytest.mark.slow
def test_100us_overrides_keep_the_thesis_gains(gains_100us, monkeypatch):
    cur = gains_100us.current
    assert cur.source == 'thesis gain' and np.allclose(cur.gain, 40.0 * np.eye(2))
    assert cur.summary()['lyapunov_rho_dense'] < math.exp(-500.0 * 1e-4)   # ≥ 500 1/s
    assert gains_100us.certified and gains_100us.L is None
    monkeypatch.setattr(design_gains, '_design_cached', lambda T_s: gains_100us)
    p = design_gains.design_for_scenario(1e-4)
    assert p['observer'] == {'k_e_injection': 0.0}
    assert p['controller']['current_gain'] == [40.0, 0.0, 0.0, 40.0]
    assert p['controller']['flux_coupling'] == 'cancel' and p['controller']['gain_period'] == 1e-4
