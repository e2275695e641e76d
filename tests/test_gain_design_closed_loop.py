"""
Certified drive gains in the offline closed loop (the whole-system part of design_gains' tests).

Lives in tests/ because it runs :func:`im_bringup.offline.simulate`: im_controller may not import
im_bringup (docs/architecture.md). Physics asserted: at 1 ms the thesis's gains diverge and the
certified ones keep currents and speed error bounded with a closed energy balance; at 100 µs the
certified path (which keeps the thesis's gains) is no worse than the thesis.
"""
from im_bringup.offline import Scenario, simulate
from im_controller import design_gains
from im_controller.gain_design import drive
import numpy as np
import pytest

SMALL_OBS = {'R_r': 2, 'L_s': 2, 'L_r': 2, 'L_sr': 2, 'omega_r': 1}


@pytest.fixture(scope='module')
def gains_1ms():
    return drive.design_drive_gains(1e-3, observer_param_points=SMALL_OBS)


@pytest.fixture(scope='module')
def gains_100us():
    return drive.design_drive_gains(1e-4, observer_param_points=SMALL_OBS)


@pytest.mark.slow
def test_offline_1ms_certified_bounded_thesis_diverges(gains_1ms):
    p = design_gains.node_overrides(gains_1ms)
    K = np.array(p['controller']['current_gain']).reshape(2, 2).tolist()
    L = np.array(p['observer']['injection_gain']).reshape(4, 2).tolist()
    r0 = simulate(Scenario(task='speed', strategy='min_energy', T_s=1e-3, duration=0.5))
    assert r0.summary['trip'] and 'inverter rating' in r0.summary['trip']['reason']
    r = simulate(Scenario(task='speed', strategy='min_energy', T_s=1e-3, duration=0.5,
                          current_gain=K, observer_gain=L,
                          controller_options={'flux_coupling': p['controller']['flux_coupling']}))
    s = r.summary
    assert s['i_max_A'] < 30.0 and s['speed_err_max_rad_s'] < 0.5
    assert abs(s['balance_relative']) < 1e-3


@pytest.mark.slow
def test_offline_100us_certified_no_worse_than_thesis(gains_100us):
    """Same gains through the certified path: equal speed error up to rounding (1e-9 relative)."""
    p = design_gains.node_overrides(gains_100us)
    K = np.array(p['controller']['current_gain']).reshape(2, 2).tolist()
    k_e = p['observer']['k_e_injection'] or None
    base = {'task': 'speed', 'strategy': 'min_energy', 'T_s': 1e-4, 'duration': 0.15}
    ref = simulate(Scenario(**base)).summary
    coupling = {'flux_coupling': p['controller']['flux_coupling']}
    cert = simulate(Scenario(**base, current_gain=K, k_e=k_e, controller_options=coupling)).summary
    assert cert['speed_err_max_rad_s'] <= ref['speed_err_max_rad_s'] * (1.0 + 1e-9)
