"""Drive application: sampled motor models, gridding, designs, the thesis's gains."""
from im_common.model import eq112_matrices
from im_common.params import THESIS_MOTOR as M
from im_controller.gain_design import motor
import numpy as np
import pytest

SMALL = {'R_r': 2, 'L_s': 2, 'L_r': 2, 'L_sr': 2, 'omega_r': 3}


def test_dc_steady_state_of_eq_1_112():
    # ω_r = 0, constant V_α: i_α = V/R_s, φ_rα = L_sr i_α (no rotor current) is an equilibrium.
    A, B = eq112_matrices(M.R_s, M.R_r, M.L_s, M.L_r, M.L_sr, M.pole_pairs, 0.0)
    V = 10.0
    x = np.array([V / M.R_s, 0.0, M.L_sr * V / M.R_s, 0.0])
    np.testing.assert_allclose(A @ x + B @ np.array([V, 0.0]), 0.0, atol=1e-9)


def test_zoh_scalar_closed_form():
    Ad, Bd = motor.zoh(np.array([[-2.0]]), np.array([[3.0]]), 0.1)
    np.testing.assert_allclose(Ad, [[np.exp(-0.2)]])
    np.testing.assert_allclose(Bd, [[1.5 * (1 - np.exp(-0.2))]])


def test_grid_respects_sigma_floor_and_reaches_it():
    g = motor.parameter_grid(5, 200.0, sigma_min=0.05)
    sigma = 1 - g[:, 3] ** 2 / (g[:, 1] * g[:, 2])
    assert sigma.min() >= 0.05 - 1e-12
    np.testing.assert_allclose(sigma.min(), 0.05, atol=1e-9)     # boundary points kept
    with pytest.raises(ValueError, match='sigma_min'):
        motor.parameter_grid(3, 200.0, sigma_min=0.0)


def test_thesis_current_gain_is_unstable_at_1ms_and_stable_at_50us():
    fast = motor.thesis_gain_stability(5e-5, points=SMALL)
    slow = motor.thesis_gain_stability(1e-3, points=SMALL)
    assert fast['stable'] and fast['current_loop_rho'] < 1
    assert slow['current_loop_rho'] > 1 and not slow['stable']


def test_designed_current_gain_is_certified_and_stable_on_dense_grid():
    d = motor.design_current_gain(1e-3, omega_max=0.0, vertex_points=SMALL,
                                  certify_points={'R_r': 4, 'L_s': 4, 'L_r': 4, 'L_sr': 4,
                                                  'omega_r': 1})
    assert d.certified
    assert d.result.certificate.grid_margin > 0
    assert d.dense_spectral_radius < 1.0


def test_infeasible_design_returns_no_gain():
    d = motor.design_current_gain(1e-3, omega_max=200.0, vertex_points=SMALL,
                                  certify_points=SMALL)
    assert d.result.status == 'infeasible'
    assert d.gain is None and not d.certified


def test_observer_dual_gain_maps_back():
    d = motor.design_observer_gain(1e-3, omega_max=0.0, vertex_points=SMALL,
                                   certify_points={'R_r': 3, 'L_s': 3, 'L_r': 3, 'L_sr': 3,
                                                   'omega_r': 1})
    assert d.certified and d.gain.shape == (4, 2)
    g = motor.parameter_grid({'R_r': 3, 'L_s': 3, 'L_r': 3, 'L_sr': 3, 'omega_r': 1}, 0.0)
    A_d, _ = motor.sampled_models(g, 1e-3)
    assert np.abs(np.linalg.eigvals(A_d - d.gain @ motor.C_CURRENT)).max() < 1.0


@pytest.mark.slow
def test_thesis_gain_limit_over_the_box_is_the_scalar_current_loop_closed_form():
    """
    The 210 µs the README quotes.

    The 4-state sampled current loop with K = 40 I loses stability where the scalar
    current-error loop does, T_s = −(σL_s/R_eq) ln(1 − 2R_eq/(R_eq + k₁)), at the stiffest
    admissible point of the box (σ = σ_min); the nominal motor tolerates more (≈ 318 µs).
    """
    pts = {'R_r': 3, 'L_s': 3, 'L_r': 3, 'L_sr': 3, 'omega_r': 3}
    r = motor.thesis_gain_stability_limit(points=pts, T_min=1e-4, T_max=1e-3, samples=6,
                                          refine_steps=10)
    g = motor.parameter_grid(pts, 200.0)
    R_r, L_s, L_r, L_sr = g[:, 0], g[:, 1], g[:, 2], g[:, 3]
    sigma_L_s = L_s - L_sr ** 2 / L_r
    R_eq = M.R_s + R_r * (L_sr / L_r) ** 2
    closed = (-(sigma_L_s / R_eq) * np.log(1.0 - 2.0 * R_eq / (R_eq + 40.0))).min()
    assert r['current_loop_limit'] == pytest.approx(closed, rel=2e-3)
    assert 2.0e-4 < r['current_loop_limit'] < 2.2e-4
    assert r['limit'] == min(r['current_loop_limit'], r['observer_limit'])
    nominal_R_eq = M.R_s + M.R_r * (M.L_sr / M.L_r) ** 2
    nominal = (-(M.sigma * M.L_s / nominal_R_eq)
               * np.log(1 - 2 * nominal_R_eq / (nominal_R_eq + 40.0)))
    assert nominal > 1.4 * r['current_loop_limit']
