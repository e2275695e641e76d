"""
Physics tests of the motor model (seed 000 eq. 1.111-1.113, 1.127) against closed forms.

Every expected value is computed here from a formula (equivalent circuit, eq. 1.112 matrices,
matrix exponential, an independent solve_ivp integration), never copied from a previous run.
"""
import math

from im_common.loads import LinearLoad, NoLoad
from im_common.model import currents, eq112_matrices, MotorModel, stator_flux, torque
from im_common.params import THESIS_MOTOR
from im_common.steady_state import (params_steady_state, zoh_gain,
                                    zoh_sample_flux_offset)
from im_plant.plant_sim import PlantSimulator
import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.linalg import expm

P = THESIS_MOTOR
T_S = 1e-4
OMEGA_E = 2.0 * math.pi * 60.0          # 60 Hz supply
V_HAT = 220.0                           # power-invariant αβ amplitude = line-to-line RMS [V]
BIG_J = 1e9                             # shaft inertia that holds the speed (τ·t/J < 1e-6 rad/s)


def _A_B(params, omega_r):
    return eq112_matrices(params.R_s, params.R_r, params.L_s, params.L_r, params.L_sr,
                          params.pole_pairs, omega_r)


def _sampled_sinusoid(k, T_s=T_S, V_hat=V_HAT, omega_e=OMEGA_E):
    """Command for step k whose zero-order hold has exactly the fundamental V_hat·e^{jω_e t}."""
    v = zoh_gain(omega_e, T_s) * V_hat * np.exp(1j * omega_e * (k + 0.5) * T_s)
    return v.real, v.imag


# ---------------------------------------------------------------------------------------------
# 1. Phasor steady state under a balanced sinusoidal supply
# ---------------------------------------------------------------------------------------------
def _run_and_sample(sim, n_steps, n_tail):
    """
    Step n_steps with the ZOH sinusoid.

    Return (t, i_s, tau_m, omega) of the last n_tail steps.
    """
    ts, i_s, tau, om = [], [], [], []
    for k in range(n_steps):
        if k >= n_steps - n_tail:
            tr = sim.truth()
            ts.append(sim.t)
            i_s.append(tr['i_alpha'] + 1j * tr['i_beta'])
            tau.append(tr['tau_m'])
            om.append(tr['omega_r'])
        sim.step(*_sampled_sinusoid(k))
    return np.array(ts), np.array(i_s), np.array(tau), np.array(om)


def _expected_samples(ss, params, ts):
    """
    Stator current, torque and power factor the samples at t_k should show.

    The circuit phasor I_s plus the zero-order-hold ripple offset at the sampling instant,
    δI = jω_e V̂ T_s²/(12 σL_s) (derived in :func:`zoh_sample_flux_offset`; ≈ 1e-3 of |I_s| near
    rated slip, so it must be accounted for to test at 1e-4).
    """
    dI = zoh_sample_flux_offset(ss.V_s, ss.omega_e, T_S) / (params.sigma * params.L_s)
    I_k = (ss.I_s + dI) * np.exp(1j * ss.omega_e * ts)
    tau_k = (params.pole_pairs * params.L_sr / params.L_r
             * np.imag(np.conj(ss.Phi_r) * (ss.I_s + dI)))
    v = ss.V_s * np.exp(1j * ss.omega_e * ts)
    pf_k = np.real(v * np.conj(I_k)) / (np.abs(v) * np.abs(I_k))
    return I_k, tau_k, pf_k


def _check_against_circuit(ss, params, ts, i_s, tau, om, omega_r):
    # Tolerances: after the ZOH offset, what is left is its next order, O(ω_e T_s) ≈ 4e-2 of an
    # offset that is itself ≲ 1.1e-3 of |I_s|, i.e. ≲ 5e-5 of |I_s| at worst, plus RK4 error
    # (~1e-9) and the undecayed start transient (≲ 1e-6). Measured when written: ≤ 6e-7 of |I_s|
    # and of τ_m over the four speeds. Bound 2e-5; a 0.1 % error in any parameter fails it.
    I_k, tau_k, pf_k = _expected_samples(ss, params, ts)
    np.testing.assert_allclose(np.abs(i_s), np.abs(I_k), rtol=2e-5)
    np.testing.assert_allclose(np.angle(i_s / I_k), 0.0, atol=2e-5)            # rad
    np.testing.assert_allclose(i_s, I_k, atol=2e-5 * abs(ss.I_s))
    # Torque: eq. 1.127 on the phasors, and independently the air-gap power over the slip speed.
    np.testing.assert_allclose(ss.tau_m, ss.tau_airgap, rtol=1e-9)
    np.testing.assert_allclose(tau, tau_k, atol=2e-5 * abs(ss.tau_m))
    # Stator power factor of the samples against the supply phasor at the same instants.
    v = ss.V_s * np.exp(1j * ss.omega_e * ts)
    pf = np.real(v * np.conj(i_s)) / (np.abs(v) * np.abs(i_s))
    np.testing.assert_allclose(pf, pf_k, atol=2e-5)
    np.testing.assert_allclose(pf, ss.power_factor, atol=3e-3)   # the offset moves pf by ≲ 1e-3
    np.testing.assert_allclose(om, omega_r, atol=1e-6)


def test_locked_rotor_transient_decays_to_circuit_steady_state():
    params = P.with_values(J=BIG_J)
    ss = params_steady_state(params, V_HAT, OMEGA_E, 0.0)
    # Run from rest for 16 time constants of the slowest electrical eigenvalue of eq. 1.112 at
    # ω = 0 (the DC offset of the start decays as e^{λ_slow t}; e^{-16} ≈ 1e-7).
    lam_slow = np.max(np.linalg.eigvals(_A_B(params, 0.0)[0]).real)
    assert lam_slow < 0
    n = int(math.ceil(16.0 / -lam_slow / T_S))
    sim = PlantSimulator(params, NoLoad(), T_s=T_S)
    ts, i_s, tau, om = _run_and_sample(sim, n, n_tail=300)
    # Locked rotor draws a large, lagging current and a positive (motoring) torque.
    assert ss.tau_m > 0 and 0 < ss.power_factor < 1
    _check_against_circuit(ss, params, ts, i_s, tau, om, 0.0)


@pytest.mark.parametrize('omega_r', [
    1750.0 * 2 * math.pi / 60,   # rated speed of the thesis motor: slip ≈ 2.8 %, motoring
    95.0,                        # large slip
    195.0,                       # above synchronous speed (188.5 rad/s): generating
])
def test_constant_slip_steady_state_matches_circuit(omega_r):
    params = P.with_values(J=BIG_J)
    ss = params_steady_state(params, V_HAT, OMEGA_E, omega_r)
    slip = (OMEGA_E - params.pole_pairs * omega_r) / OMEGA_E
    assert np.sign(ss.tau_m) == np.sign(slip)
    # (a) Started in the steady state, the plant stays there.
    dpsi = zoh_sample_flux_offset(ss.V_s, OMEGA_E, T_S)
    x0 = ss.state(0.0) + [0.0, omega_r]
    x0[0] += dpsi.real
    x0[1] += dpsi.imag
    sim = PlantSimulator(params, NoLoad(), T_s=T_S, x0=x0)
    ts, i_s, tau, om = _run_and_sample(sim, 1000, n_tail=1000)
    _check_against_circuit(ss, params, ts, i_s, tau, om, omega_r)
    # (b) Started with no flux, the transient decays (slowest eigenvalue of eq. 1.112 at this
    # speed, 20 time constants: the start transient is ~10x |I_s|) onto the same steady state.
    lam_slow = np.max(np.linalg.eigvals(_A_B(params, omega_r)[0]).real)
    n = int(math.ceil(20.0 / -lam_slow / T_S))
    sim = PlantSimulator(params, NoLoad(), T_s=T_S, omega0=omega_r)
    ts, i_s, tau, om = _run_and_sample(sim, n, n_tail=300)
    _check_against_circuit(ss, params, ts, i_s, tau, om, omega_r)


def test_steady_state_input_power_matches_losses_and_shaft_power():
    """Circuit closed form is itself consistent: Re(V I*) = R_s|I_s|² + R_r|I_r|² + τ ω_r."""
    for omega_r in (0.0, 120.0, 183.0, 195.0):
        ss = params_steady_state(P, V_HAT, OMEGA_E, omega_r)
        rhs = P.R_s * abs(ss.I_s) ** 2 + P.R_r * abs(ss.I_r) ** 2 + ss.tau_m * omega_r
        np.testing.assert_allclose(ss.P_in, rhs, rtol=1e-12)


# ---------------------------------------------------------------------------------------------
# 3. Zero input
# ---------------------------------------------------------------------------------------------
def test_zero_input_from_rest_stays_exactly_at_rest():
    sim = PlantSimulator(P, NoLoad(), T_s=T_S)
    for _ in range(5000):
        sim.step(0.0, 0.0)
    assert all(v == 0.0 for v in sim.x), sim.x
    tr = sim.truth()
    assert tr['E_core'] == 0.0 and tr['balance_residual'] == 0.0


def test_zero_input_flux_decay_matches_matrix_exponential_of_eq112():
    """V = 0 (stator shorted), rotor at rest, initial rotor flux: x(t) = expm(A(0) t) x0."""
    A, _ = _A_B(P, 0.0)
    phi0 = 0.9 * np.exp(1j * 0.7)                    # arbitrary direction
    i0 = 0.0
    x_is = np.array([i0, i0, phi0.real, phi0.imag])
    psi_a, psi_b = stator_flux(0.0, 0.0, phi0.real, phi0.imag, P.L_s, P.L_r, P.L_sr)
    sim = PlantSimulator(P, NoLoad(), T_s=T_S, x0=[psi_a, psi_b, phi0.real, phi0.imag, 0.0, 0.0])
    errs = []
    for k in range(1, 5001):                         # 0.5 s ≈ 2.3 slow time constants
        sim.step(0.0, 0.0)
        if k % 250 == 0:
            x_ref = expm(A * k * T_S) @ x_is
            i_sa, i_sb, _, _ = sim.state_currents()
            x = np.array([i_sa, i_sb, sim.x[2], sim.x[3]])
            errs.append(np.max(np.abs(x - x_ref)) / abs(phi0))
    # RK4 with |hλ| ≤ 0.024 has local error ~ (hλ)^5/120 < 1e-10; 1e-7 leaves a wide margin.
    assert max(errs) < 1e-7, max(errs)
    # The current and flux stay collinear at ω = 0, so no torque and the shaft does not move.
    assert abs(sim.x[5]) < 1e-12
    # The flux magnitude decays monotonically, never faster than the fast mode and at the end
    # with the slow eigenvalue (both from eq. 1.112).
    lam = np.sort(np.linalg.eigvals(A).real)
    assert np.hypot(sim.x[2], sim.x[3]) < abs(phi0) * math.exp(lam[-1] * 0.5) * 1.5


# ---------------------------------------------------------------------------------------------
# 4. Flux-linkage form of model.rhs ≡ eq. 1.112 / 1.111 / 1.127 for constant parameters
# ---------------------------------------------------------------------------------------------
def test_rhs_equals_eq112_at_random_states():
    rng = np.random.default_rng(1234)
    load = LinearLoad(1.0, 0.001)
    for params in (P, P.with_values(R_s=1.3, R_r=0.4, L_s=0.2, L_r=0.15, L_sr=0.16, pole_pairs=3,
                                    J=0.2, b=0.05)):
        model = MotorModel(params, load)
        for _ in range(50):
            i_s = rng.normal(0, 20, 2)
            phi = rng.normal(0, 1, 2)
            theta, omega = rng.uniform(-10, 10), rng.normal(0, 150)
            V = rng.normal(0, 300, 2)
            psi = stator_flux(i_s[0], i_s[1], phi[0], phi[1], params.L_s, params.L_r, params.L_sr)
            x = [psi[0], psi[1], phi[0], phi[1], theta, omega] + [0.0] * 7
            d = model.rhs(0.3, x, V[0], V[1])
            # Chain rule: i_s = (ψ_s − (L_sr/L_r) φ_r)/(σ L_s).
            sls = params.sigma * params.L_s
            di_s = (np.array(d[0:2]) - params.L_sr / params.L_r * np.array(d[2:4])) / sls
            A, B = _A_B(params, omega)
            expected = A @ np.r_[i_s, phi] + B @ V
            np.testing.assert_allclose(np.r_[di_s, d[2:4]], expected, rtol=1e-10,
                                       atol=1e-10 * np.max(np.abs(expected)))
            # eq. 1.111 and 1.127
            tau = (params.pole_pairs * params.L_sr / params.L_r
                   * (i_s[1] * phi[0] - i_s[0] * phi[1]))
            np.testing.assert_allclose(torque(i_s[0], i_s[1], phi[0], phi[1], params.L_r,
                                              params.L_sr, params.pole_pairs), tau, rtol=1e-12)
            d_omega = (tau - params.b * omega - load.torque(0.3, theta, omega)) / params.J
            np.testing.assert_allclose(d[5], d_omega, rtol=1e-10, atol=1e-9)
            assert d[4] == omega
            # Round trip ψ_s, φ_r -> currents.
            i_back = currents(psi[0], psi[1], phi[0], phi[1], params.L_s, params.L_r, params.L_sr)
            np.testing.assert_allclose(i_back[:2], i_s, rtol=1e-10, atol=1e-10)


def test_eq112_anti_test_detects_a_wrong_parameter():
    """The comparison above can fail: a 1 % error in R_r is visible far above its tolerance."""
    model = MotorModel(P.with_values(R_r=P.R_r * 1.01), NoLoad())
    i_s, phi, omega, V = np.array([10.0, -4.0]), np.array([0.5, 0.8]), 100.0, np.array([200, 50])
    psi = stator_flux(*i_s, *phi, P.L_s, P.L_r, P.L_sr)
    d = model.rhs(0.0, [*psi, *phi, 0.0, omega] + [0.0] * 7, *V)
    A, _ = _A_B(P, omega)
    expected_phi = (A @ np.r_[i_s, phi])[2:4]
    assert np.max(np.abs(np.array(d[2:4]) - expected_phi)) > 1e-4 * np.max(np.abs(expected_phi))


# ---------------------------------------------------------------------------------------------
# 5. Accuracy of the RK4 plant against solve_ivp (DOP853, rtol 1e-10, atol 1e-12)
# ---------------------------------------------------------------------------------------------
def _reference_start(params, load, T_s, n_steps, V_hat=V_HAT, omega_e=OMEGA_E):
    """Independent reference: eq. 1.112 + 1.111 in [i_s, φ_r, θ, ω], same ZOH voltage per step."""
    A0, B = _A_B(params, 0.0)
    vp = params.pole_pairs
    c = params.L_sr / params.L_r

    def f(t, y, v):
        A, _ = _A_B(params, y[5])
        dx = A @ y[:4] + B @ v
        tau = vp * c * (y[1] * y[2] - y[0] * y[3])
        return np.r_[dx, y[5], (tau - params.b * y[5] - load.torque(t, y[4], y[5])) / params.J]

    y = np.zeros(6)
    out = [y.copy()]
    for k in range(n_steps):
        vk = V_hat * np.exp(1j * omega_e * k * T_s)
        sol = solve_ivp(f, (k * T_s, (k + 1) * T_s), y, method='DOP853', rtol=1e-10, atol=1e-12,
                        args=(np.array([vk.real, vk.imag]),))
        y = sol.y[:, -1]
        out.append(y.copy())
    return np.array(out)


def test_rk4_plant_matches_solve_ivp_on_a_start_transient():
    load = LinearLoad(1.0, 0.001)
    n = 2000                                          # 0.2 s of a direct-on-line start
    ref = _reference_start(P, load, T_S, n)
    sim = PlantSimulator(P, load, T_s=T_S)
    got = [np.zeros(6)]
    for k in range(n):
        vk = V_HAT * np.exp(1j * OMEGA_E * k * T_S)
        sim.step(vk.real, vk.imag)
        i_sa, i_sb, _, _ = sim.state_currents()
        got.append(np.array([i_sa, i_sb, sim.x[2], sim.x[3], sim.x[4], sim.x[5]]))
    got = np.array(got)
    # Relative error per quantity, scaled by that quantity's largest magnitude over the run.
    groups = {'i_s': [0, 1], 'phi_r': [2, 3], 'theta_r': [4], 'omega_r': [5]}
    rel = {g: np.max(np.abs(got[:, ix] - ref[:, ix])) / np.max(np.abs(ref[:, ix]))
           for g, ix in groups.items()}
    # RK4's local error is ~ (hλ)^5/120 with |hλ| ≲ 0.04 (stator eigenvalues at 377 rad/s plus
    # the damping ≈ 234 s⁻¹): ≈ 1e-9 per step, accumulating to ~1e-7 over 2000 steps in the worst
    # case. Measured when written: max 4.6e-8 (φ_r; i_s 3.9e-8, ω_r 1.9e-8). Bound: 1e-6.
    assert max(rel.values()) < 1e-6, rel
    # Anti-test: a 0.1 % error in R_s is far above that bound.
    sim2 = PlantSimulator(P.with_values(R_s=P.R_s * 1.001), load, T_s=T_S)
    for k in range(n):
        vk = V_HAT * np.exp(1j * OMEGA_E * k * T_S)
        sim2.step(vk.real, vk.imag)
    i2 = np.array(sim2.state_currents()[:2])
    assert np.max(np.abs(i2 - ref[-1, :2])) / np.max(np.abs(ref[:, :2])) > 1e-5
