"""
Trajectories, reference model, flux strategies and the model inverse.

Seed 000 eq. 3.13/3.26 and eq. 3.29.
"""
import math
import random

from im_common.loads import NoLoad
from im_common.model import stator_flux
from im_common.params import InvalidParameter, THESIS_MOTOR
from im_controller.control_law import ControllerConfig, DriveController
from im_controller.flux import flux_min_energy, flux_min_loss, LowPass2
from im_controller.reference import (dq_reference, ModelCoefficients, reference_alpha_beta,
                                     steady_losses, steady_state, torque_alpha_beta)
from im_controller.trajectories import (cubed_gaussian_step_integral, Quintic,
                                        ThesisPositionProfile, ThesisSpeedProfile)
from im_plant.plant_sim import PlantSimulator
import numpy as np
import pytest

C = ModelCoefficients.from_params(THESIS_MOTOR)


def _fd_check(traj, ts, h=1e-6, rtol=1e-5):
    for t in ts:
        p0, v0, a0, j0 = traj.sample(t)
        pp, vp, ap, _ = traj.sample(t + h)
        pm, vm, am, _ = traj.sample(t - h)
        scale = 1.0 + abs(v0) + abs(a0) + abs(j0)
        assert (pp - pm) / (2 * h) == pytest.approx(v0, abs=rtol * scale)
        assert (vp - vm) / (2 * h) == pytest.approx(a0, abs=rtol * scale)
        assert (ap - am) / (2 * h) == pytest.approx(j0, abs=1e-3 * scale)


def test_thesis_profiles_and_their_derivatives():
    pos = ThesisPositionProfile()
    assert pos.sample(0.0)[0] == pytest.approx(-math.pi / 2)
    assert pos.sample(10.0)[0] == pytest.approx(-math.pi / 2 + 1.2 * math.pi)
    _fd_check(pos, [0.41, 0.5, 0.6, 0.75, 1.0, 1.3])
    spd = ThesisSpeedProfile()
    assert spd.sample(0.1)[1] == 135.0
    assert spd.sample(5.0)[1] == pytest.approx(180.0)
    _fd_check(spd, [0.25, 0.4, 0.6, 0.9])
    # θ* of the speed task is the integral of ω*: compare with a fine trapezoid
    t = np.linspace(0.0, 1.5, 150001)
    w = np.array([spd.sample(x)[1] for x in t])
    assert spd.sample(1.5)[0] == pytest.approx(np.trapezoid(w, t), rel=1e-9)
    assert cubed_gaussian_step_integral(-1.0) == 0.0


def test_quintic_boundary_conditions():
    q = Quintic(1.0, 0.5, 2.0, 3.0, -4.0, 7.0)
    assert q.sample(1.0) == pytest.approx((2.0, 3.0, -4.0, q.sample(1.0)[3]))
    end = q.sample(1.5 - 1e-12)
    assert end[:3] == pytest.approx((7.0, 0.0, 0.0), abs=1e-6)
    _fd_check(q, [1.1, 1.2, 1.37])
    t = np.linspace(1.0, 1.8, 80001)
    p = np.array([q.sample(x)[0] for x in t])
    assert q.integral(1.8) == pytest.approx(np.trapezoid(p, t), rel=1e-8)


def test_reference_torque_alignment_and_rotor_equations():
    rng = random.Random(1)
    for _ in range(50):
        tau = rng.uniform(-20, 20)
        dtau = rng.uniform(-200, 200)
        phi = rng.uniform(0.2, 1.2)
        dphi = rng.uniform(-5, 5)
        ddphi = rng.uniform(-100, 100)
        rho = rng.uniform(-math.pi, math.pi)
        i_ds, i_qs, di_ds, di_qs, i_dr, i_qr, w_sl = dq_reference(C, tau, dtau, phi, dphi, ddphi)
        # rotor flux from stator and rotor currents: aligned (φ_q = 0, eq. 3.8) with magnitude φ
        assert C.L_sr * i_ds + C.L_r * i_dr == pytest.approx(phi, abs=1e-12)
        assert C.L_sr * i_qs + C.L_r * i_qr == pytest.approx(0.0, abs=1e-12)
        # rotor equations in the flux frame (3.11-3.12, electrical slip)
        assert C.R_r * i_dr + dphi == pytest.approx(0.0, abs=1e-12)
        assert C.R_r * i_qr + w_sl * phi == pytest.approx(0.0, abs=1e-12)
        # torque in αβ after eq. 3.26 (eq. 3.7)
        i_a, i_b, p_a, p_b = reference_alpha_beta(C, rho, i_ds, i_qs, phi)
        assert torque_alpha_beta(C, i_a, i_b, p_a, p_b) == pytest.approx(tau, abs=1e-10)
        assert math.atan2(p_b, p_a) == pytest.approx(rho, abs=1e-12)


def test_min_energy_slip_minimizes_magnetic_energy():
    tau = 6.0

    def energy(phi):
        i_ds, i_qs, _, _, i_dr, i_qr, _ = dq_reference(C, tau, 0.0, phi, 0.0, 0.0)
        return 0.5 * (C.L_s * (i_ds ** 2 + i_qs ** 2) + 2 * C.L_sr * (i_ds * i_dr + i_qs * i_qr)
                      + C.L_r * (i_dr ** 2 + i_qr ** 2))
    grid = np.linspace(0.1, 1.0, 9001)
    best = grid[np.argmin([energy(p) for p in grid])]
    phi_me = flux_min_energy(C, tau, 0.01, 10.0)
    assert phi_me == pytest.approx(best, abs=2e-4)
    _, _, _, _, _, _, w_sl = dq_reference(C, tau, 0.0, phi_me, 0.0, 0.0)
    assert w_sl == pytest.approx(C.slip_min_energy, rel=1e-12)   # eq. 3.19 (electrical slip)
    # eq. 3.25 branches become the clip
    assert flux_min_energy(C, 0.0, 0.2, 1.2) == 0.2
    assert flux_min_energy(C, -1e4, 0.2, 1.2) == 1.2


@pytest.mark.parametrize('exponent', [1.0, 2.0])
@pytest.mark.parametrize('tau,omega', [(6.0, 0.0), (3.0, 180.0), (-10.0, 20.0), (40.0, 100.0)])
def test_min_loss_flux_minimizes_steady_losses(tau, omega, exponent):
    phi = flux_min_loss(C, tau, omega, 0.05, 1.2, 0.012, 0.012, exponent)
    grid = np.linspace(0.05, 1.2, 23001)
    losses = [steady_losses(C, tau, p, omega, 0.012, 0.012, exponent) for p in grid]
    # the map refreshes f_e with the solution's slip but ignores ∂f_e/∂φ: within 0.1 %
    assert steady_losses(C, tau, phi, omega, 0.012, 0.012, exponent) <= min(losses) * (1 + 1e-3)


def test_filter_is_exact_for_held_input():
    f = LowPass2(0.1, 0.001)
    f.set_input(1.0)
    # fine RK4 of the same ODE
    y, dy, h = 0.0, 0.0, 1e-6

    def acc(y, dy):
        return f.p_prod * (1.0 - y) - f.p_sum * dy

    for _ in range(20):
        f.advance(1e-4)
    for _ in range(2000):
        k1 = (dy, acc(y, dy))
        k2 = (dy + h / 2 * k1[1], acc(y + h / 2 * k1[0], dy + h / 2 * k1[1]))
        k3 = (dy + h / 2 * k2[1], acc(y + h / 2 * k2[0], dy + h / 2 * k2[1]))
        k4 = (dy + h * k3[1], acc(y + h * k3[0], dy + h * k3[1]))
        y += h / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
        dy += h / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
    assert f.y == pytest.approx(y, abs=1e-10)
    assert f.dy == pytest.approx(dy, abs=1e-8)
    with pytest.raises(ValueError, match='tau1'):
        LowPass2(0.0, 1.0)


@pytest.mark.parametrize('strategy,hold', [('constant_flux', True), ('min_loss', True),
                                           ('constant_flux', False)])
def test_feedforward_open_loop_reproduces_the_reference(strategy, hold):
    """
    Check that a plant started on the reference and driven by V* alone follows it.

    The model inverse.
    """
    omega0 = 100.0
    # constant speed: the test is about the electrical inverse
    params = THESIS_MOTOR.with_values(J=1e5)
    cfg = ControllerConfig(mode='torque', profile='setpoint', strategy=strategy, phi_d=0.8,
                           k1=1e-12, flux_coupling='none', params=params, load='none',
                           setpoint_duration=2.0, hold_compensation=hold)
    ss = steady_state(C, 0.0, 0.8 if strategy == 'constant_flux' else 0.2, omega0)
    psi = stator_flux(ss['i_alpha'], ss['i_beta'], ss['phi_alpha'], ss['phi_beta'],
                      C.L_s, C.L_r, C.L_sr)
    plant = PlantSimulator(params, NoLoad(), T_s=1e-4, max_substep=5e-5,
                           x0=(psi[0], psi[1], ss['phi_alpha'], ss['phi_beta'], 0.0, omega0))
    ctl = DriveController(cfg)
    worst_i = worst_phi = worst_tau = 0.0
    for k in range(5000):
        m = plant.measure()
        out = plant.model.outputs(m.t, plant.x)
        if k == 10:
            ctl.set_setpoint('torque', 8.0, m.t)
        if k == 2500:
            ctl.set_setpoint('torque', -4.0, m.t)
        va, vb = ctl.compute(m.t, m.i_alpha, m.i_beta, m.theta_r, m.omega_r,
                             out['phi_r_alpha'], out['phi_r_beta'])
        r = ctl.reference
        worst_i = max(worst_i,
                      math.hypot(m.i_alpha - r['i_alpha_ref'], m.i_beta - r['i_beta_ref']))
        worst_phi = max(worst_phi, math.hypot(out['phi_r_alpha'] - r['phi_alpha_ref'],
                                              out['phi_r_beta'] - r['phi_beta_ref']))
        worst_tau = max(worst_tau, abs(out['tau_m'] - r['tau_ref']))
        plant.step(va, vb)
    assert abs(ctl.reference['tau_ref'] + 4.0) < 1e-6
    if not hold:
        # anti-test: the voltage sampled at t_k and held lags the rotating reference by T_s/2
        assert worst_i > 0.1
        return
    # A, against currents up to ~15 A; the residual is the ZOH of the d-axis feedforward while
    # the 1-ms pole of the flux filter moves (V* is exact at t_k, not averaged over the period)
    assert worst_i < 0.05
    assert worst_phi < 1e-3        # Wb
    assert worst_tau < 0.05        # N·m, against 8 N·m


def test_invalid_config_names_the_field():
    for kwargs, name in [({'k1': -40.0}, 'k1'), ({'strategy': 'fast'}, 'strategy'),
                         ({'mode': 'angle'}, 'mode'),
                         ({'phi_min': 0.5, 'phi_max': 0.4}, 'phi_max'),
                         ({'phi_d': float('nan')}, 'phi_d'),
                         ({'current_gain': [[1, 0]]}, 'current_gain'),
                         ({'current_gain': [[-1, 0], [0, 1]]}, 'current_gain'),
                         ({'v_limit': 0.0}, 'v_limit'), ({'k_p': -1.0}, 'k_p'),
                         ({'load': 'spring'}, 'load'), ({'mode': 'torque'}, 'profile'),
                         ({'flux_time_constants': (0.1,)}, 'flux_time_constants'),
                         ({'core_loss_exponent': 3}, 'core_loss_exponent'),
                         ({'flux_coupling': 'half'}, 'flux_coupling')]:
        with pytest.raises(InvalidParameter, match=name):
            ControllerConfig(**kwargs)


def test_defaults_decode_the_gain_table():
    position = ControllerConfig(mode='position')
    assert (position.k_p, position.k_v) == (10.0, 1.0)
    assert (ControllerConfig(mode='speed').k_p, ControllerConfig(mode='speed').k_v) == (1.0, 3.0)
    assert ControllerConfig().k1 == 40.0


def test_compute_refuses_non_finite_inputs():
    ctl = DriveController(ControllerConfig())
    with pytest.raises(ValueError, match='omega_r'):
        ctl.compute(0.0, 0.0, 0.0, 0.0, float('inf'), 0.0, 0.0)
