"""Speed-sensorless mode (issue 26 item 1, docs/sensorless.md): the speed-adaptive observer's
physics and the offline loop's sensorless option."""
import math

import numpy as np
import pytest

from im_bringup.offline import Scenario, build, simulate
from im_common.params import InvalidParameter, THESIS_MOTOR
from im_observer.speed_observer import SpeedAdaptiveObserver, linearized_poles


def _worst_regenerating_pole(obs):
    """Largest real part of the linearized observer over low-speed regeneration (torque against
    the speed) with the stator frequency away from zero (where the speed is unobservable)."""
    p = obs.params
    worst = -math.inf
    for tau in (-10.0, -5.0, -2.0, 2.0, 5.0, 10.0):
        for w in (-30.0, -10.0, -5.0, -2.0, 2.0, 5.0, 10.0, 30.0):
            w_s = p.pole_pairs * w + p.R_r * tau / p.pole_pairs     # φ = 1 Wb
            if abs(w_s) > 2.0:
                worst = max(worst, max(linearized_poles(obs, w, tau, 1.0).real))
    return worst


def test_plain_adaptation_law_is_unstable_in_low_speed_regeneration_and_the_rotated_error_is_not_worse_than_marginal():
    plain = _worst_regenerating_pole(SpeedAdaptiveObserver(THESIS_MOTOR, error_rotation=0.0))
    rotated = _worst_regenerating_pole(SpeedAdaptiveObserver(THESIS_MOTOR))
    assert plain > 2.0            # a pole at +2.8 /s: the known regenerating-mode instability
    assert rotated < 0.25 * plain


def test_linearized_observer_is_stable_when_motoring():
    obs = SpeedAdaptiveObserver(THESIS_MOTOR)
    for w in (10.0, 50.0, 135.0, 180.0):
        for tau in (0.5, 3.0, 12.0):
            assert max(linearized_poles(obs, w, tau, 1.2).real) < -1.0
            assert max(linearized_poles(obs, -w, -tau, 1.2).real) < -1.0


def test_speed_estimate_converges_from_a_wrong_initial_speed_using_only_voltage_and_current():
    """The sensored thesis speed task runs; beside it the observer starts at ω̂ = 100 rad/s while
    the shaft turns at 135 rad/s, and sees only V and i."""
    sc = Scenario(task='speed', strategy='constant_flux', duration=0.2)
    plant, ctl, obs = build(sc)
    so = SpeedAdaptiveObserver(sc.controller_config().params, x0=obs.state, omega0=100.0)
    x = obs.state
    errors = []
    for _ in range(int(round(sc.duration / sc.T_s))):
        m = plant.measure()
        v = ctl.compute(m.t, m.i_alpha, m.i_beta, m.theta_r, m.omega_r, x[2], x[3])
        plant.step(*v)
        x = obs.step(sc.T_s, v[0], v[1], m.i_alpha, m.i_beta, m.omega_r)
        so.step(sc.T_s, v[0], v[1], m.i_alpha, m.i_beta)
        errors.append(so.omega_hat - m.omega_r)
    assert abs(errors[0]) > 30.0
    assert abs(errors[-1]) < 0.15 * abs(errors[0])


def test_position_task_is_refused_in_sensorless_mode_with_one_line():
    with pytest.raises(InvalidParameter) as err:
        Scenario(task='position', sensorless=True)
    msg = str(err.value)
    assert 'sensorless' in msg and 'position' in msg and '\n' not in msg


def test_sensorless_run_ignores_the_measured_speed():
    """The measured speed made useless (noise 50 rad/s) changes nothing in a sensorless run."""
    a = simulate(Scenario(task='speed', strategy='min_energy', duration=0.3, sensorless=True))
    b = simulate(Scenario(task='speed', strategy='min_energy', duration=0.3, sensorless=True,
                          speed_noise_std=50.0))
    for key in ('omega_r', 'omega_hat', 'v_alpha', 'v_beta', 'E_loss'):
        np.testing.assert_array_equal(a.trace[key], b.trace[key])
    # and the sensored loop does feel it (the comparison can fail)
    c = simulate(Scenario(task='speed', strategy='min_energy', duration=0.3, speed_noise_std=50.0))
    assert not np.array_equal(a.trace['v_alpha'], c.trace['v_alpha'])
