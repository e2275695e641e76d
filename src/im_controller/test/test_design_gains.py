"""design_gains: certified drive gains at the node period (im_robust.drive) and the CLI.

Physics asserted: the certified current gain makes every sampled current-error model contract, the
thesis's 40 V/A at 1 ms does not (sampled pole a − b·k1 leaves the unit circle), and the offline
closed loop at 1 ms stays bounded with the certified gains while the thesis's diverges.
"""
import json
import math
import re

import numpy as np
import pytest

from im_controller import design_gains
from im_robust import drive

SMALL_OBS = {'R_r': 2, 'L_s': 2, 'L_r': 2, 'L_sr': 2, 'omega_r': 1}


@pytest.fixture(scope='module')
def gains_1ms():
    return drive.design_drive_gains(1e-3, observer_param_points=SMALL_OBS)


def _floats(text, key):
    m = re.search(rf'{key}: \[([^\]]*)\]', text)
    assert m, f'{key} missing'
    return [float(x) for x in m.group(1).split(',')]


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


def test_observer_injection_certified_over_the_speed_range(gains_1ms):
    o = gains_1ms.observer
    assert o.certified and o.omega_max == 200.0
    assert o.worst_rho_dense < 1.0 and o.worst_spectral_radius < 1.0
    L = gains_1ms.L
    assert L.shape == (4, 2) and np.allclose(L[2:], 0.0)


def test_offline_1ms_certified_bounded_thesis_diverges(gains_1ms):
    from im_bringup.offline import Scenario, simulate
    p = design_gains.node_overrides(gains_1ms)
    K = np.array(p['controller']['current_gain']).reshape(2, 2).tolist()
    L = np.array(p['observer']['injection_gain']).reshape(4, 2).tolist()
    with pytest.raises(FloatingPointError):
        simulate(Scenario(task='speed', strategy='min_energy', T_s=1e-3, duration=0.5))
    r = simulate(Scenario(task='speed', strategy='min_energy', T_s=1e-3, duration=0.5,
                          current_gain=K, observer_gain=L,
                          controller_options={'flux_coupling': p['controller']['flux_coupling']}))
    s = r.summary
    assert s['i_max_A'] < 30.0 and s['speed_err_max_rad_s'] < 0.5
    assert abs(s['balance_relative']) < 1e-3


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
