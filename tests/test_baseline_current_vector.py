"""
The industry's current-vector controller (im_controller.baselines), ROS-free, against its design.

The gains are motulator's designs on the thesis motor; the current loop on the locked rotor rises
at 1/α_c; the speed PI on a pure inertia is the first order α_s/(s + α_s) (sampled: its exact z
form); the closed loop on the plant follows a speed ramp as that first order, with and without
the computational delay, its observer on the plant's rotor flux.
"""
import math

from im_common.loads import LinearLoad
from im_common.params import InvalidParameter, THESIS_MOTOR
from im_controller.baselines.current_vector import (ComplexPICurrentController,
                                                    CurrentVectorController, hold_equivalent,
                                                    SpeedPI)
from im_controller.baselines.gains import BaselineGains
from im_plant.plant_sim import PlantSimulator
import numpy as np
import pytest

M = THESIS_MOTOR
T_S = 1e-4


def _magnetized(d, locked=False, load=None):
    """Return (plant, controller), the motor magnetized at the reference flux along α."""
    ctl = CurrentVectorController(M, T_S, delay=d)
    i_d = ctl.psi_R_ref / M.L_M
    x0 = [M.L_s * i_d, 0.0, M.L_sr * i_d, 0.0, 0.0, 0.0]
    plant = PlantSimulator(M, load=load, T_s=T_S, inverter={'delay': d}, x0=x0,
                           locked_rotor=locked)
    ctl.preset(complex(M.theta * M.L_sr * i_d, 0.0), complex(i_d, 0.0))
    return plant, ctl


def _psi_R(plant):
    """Return the plant's rotor flux ψ_R = θ φ_r (αβ, inverse-Γ) at t_k."""
    return M.theta * complex(plant.x[2], plant.x[3])


def _crossing(ts, ys, level):
    """Return the first time ys crosses level (linear between samples)."""
    for k in range(1, len(ys)):
        if ys[k] >= level:
            return ts[k - 1] + (level - ys[k - 1]) / (ys[k] - ys[k - 1]) * (ts[k] - ts[k - 1])
    raise AssertionError(f'never reached {level}')


# ------------------------------------------------------------------------------ the gains
def test_the_gains_are_the_designs_on_the_thesis_motor():
    g = BaselineGains()
    L_sigma = M.L_s - M.L_sr ** 2 / M.L_r
    assert L_sigma == pytest.approx(6.350e-3, abs=1e-6)
    assert M.L_sigma == pytest.approx(L_sigma, rel=1e-12)
    assert g.alpha_c == pytest.approx(2 * math.pi * 200)
    k_t, k_p, k_i = g.current_gains(M.L_sigma)
    assert (k_t, k_p, k_i) == pytest.approx((g.alpha_c * L_sigma, 2 * g.alpha_c * L_sigma,
                                             g.alpha_c ** 2 * L_sigma), rel=1e-12)
    assert (k_t, k_p, k_i) == pytest.approx((7.98, 15.96, 1.003e4), rel=2e-3)   # design a.4
    assert BaselineGains(alpha_i=100.0).current_gains(1.0) == pytest.approx(
        (g.alpha_c, g.alpha_c + 100.0, 100.0 * g.alpha_c))
    # speed: α_s = k_v/J = 100 rad/s, so k_t is the thesis's k_v = 3 N·m·s
    assert g.speed_gains(M.J) == pytest.approx((3.0, 6.0, 300.0), rel=1e-12)
    assert [g.k_comp_for(d) for d in (0, 1, 2)] == [0.5, 1.5, 2.5]
    assert BaselineGains(k_comp=0.0).k_comp_for(1) == 0.0
    ctl = CurrentVectorController(M, T_S, {'alpha_c': 3000.0}, delay=1)
    assert (ctl.current.k_t, ctl.k_comp) == pytest.approx((3000.0 * L_sigma, 1.5))
    assert ctl.psi_R_ref == pytest.approx(M.theta * 1.2)


@pytest.mark.parametrize('spec, key', [
    ({'alpha_c': -1.0}, 'baseline.alpha_c'), ({'alpha_s': 0.0}, 'baseline.alpha_s'),
    ({'alpha_i': 'fast'}, 'baseline.alpha_i'), ({'alpha_c': True}, 'baseline.alpha_c'),
    ({'k_comp': -0.5}, 'baseline.k_comp'), ({'alpha_c': math.inf}, 'baseline.alpha_c'),
    ({'alpha_o': 2000.0}, 'baseline.alpha_o'), ([1.0], 'baseline')])
def test_a_bad_gain_is_one_line_naming_it(spec, key):
    with pytest.raises(InvalidParameter) as err:
        BaselineGains.from_block(spec)
    assert err.value.name == key
    assert f"'{key}'" in str(err.value) and '\n' not in str(err.value)


def test_the_law_refuses_a_bad_delay_and_a_flux_beyond_the_current_limit():
    with pytest.raises(InvalidParameter, match="'delay'"):
        CurrentVectorController(M, T_S, delay=3)
    with pytest.raises(InvalidParameter, match="'phi_r_ref'"):
        CurrentVectorController(M, T_S, phi_r_ref=1.2, current_limit=10.0)   # needs 14.7 A


def test_the_hold_equivalent_is_the_exact_solution():
    w, T = 377.0, 1e-3
    phi, gam = hold_equivalent(w, T)
    assert phi == pytest.approx(complex(math.cos(w * T), -math.sin(w * T)), abs=1e-15)
    assert gam == pytest.approx((1 - phi) / (1j * w), abs=1e-15)
    assert hold_equivalent(0.0, T) == (1.0, T)


# ------------------------------------------------------------------------------ current loop
@pytest.mark.parametrize('d', [0, 1])
def test_the_current_loop_rises_at_its_bandwidth_on_the_locked_rotor(d):
    """
    A q-axis step of 5 A on the magnetized, locked thesis motor: 63 % at 1/α_c = 0.796 ms.

    Allowed: 10 % of 1/α_c, plus half a period per period of delay. Measured 1.014/α_c (d = 0,
    k_comp = 0.5) and 0.903/α_c (d = 1, k_comp = 1.5): the locked rotor's R_s + R_R = 1.45 Ω
    (R/(α_c L_σ) = 0.18) slows the design's α_c/(s + α_c) a little, the forward-Euler
    integrator (pole 1 − α_c T_s, not e^{−α_c T_s}) quickens it by about T_s/2, and each period
    of delay, at the same gains, less damped, by about 0.9 T_s more.
    """
    plant, ctl = _magnetized(d, locked=True)
    i_d = ctl.psi_R_ref / M.L_M
    ts, iq, idd = [], [], []
    for _ in range(80):
        m = plant.measure()
        ang = -math.atan2(plant.x[3], plant.x[2])               # the true rotor-flux axes
        i = complex(m.i_alpha, m.i_beta) * complex(math.cos(ang), math.sin(ang))
        ts.append(m.t)
        iq.append(i.imag)
        idd.append(i.real)
        plant.step(*ctl.compute_current(m.t, m.i_alpha, m.i_beta, m.theta_r, m.omega_r,
                                        i_d, 5.0))
    alpha_c = ctl.gains.alpha_c
    t63 = _crossing(ts, [x / 5.0 for x in iq], 1.0 - math.exp(-1.0))
    assert abs(t63 - 1.0 / alpha_c) <= 0.1 / alpha_c + 0.5 * d * T_S, t63 * alpha_c
    assert max(iq) < 5.0 * 1.02                                 # no overshoot to speak of
    assert iq[-1] == pytest.approx(5.0, rel=5e-3)               # 8 ms: 10 time constants
    assert max(abs(x - i_d) for x in idd) < 0.01                # the d axis holds
    assert plant.trip is None


@pytest.mark.parametrize('d', [0, 1, 2])
def test_the_current_controller_is_its_z_form_on_the_ideal_inductance(d):
    """
    On the ideal inductance the sampled step response is the z form of the equations.

    On L_σ di/dt = u (R = 0, ω_c = 0) with the delay d and the realized voltage ½(V_{k−d−1} +
    V_{k−d}) in the anti-windup, i/i* = N/D with a = α_c T_s, N = a z(z − 1 + a) and
    D = z^{d+1}(z − 1)(z − 1 + a) − (a/2)(z² − 1) + a z(2z − 2 + a); d = 0 with the voltage
    itself fed back would be a/(z − 1 + a), the design's pole discretized forward.
    """
    g = BaselineGains()
    L = M.L_sigma
    pi = ComplexPICurrentController(*g.current_gains(L), T_S)
    line, i = [0j] * (d + 1), 0j            # from rest: the line holds zeros (the z form's)
    out = []
    for _ in range(60):
        out.append(i)
        line.append(pi.output(1.0, i))
        u_now, u_prev = line[-1 - d], line[-2 - d]
        pi.update(0.5 * (u_prev + u_now), 0.0)
        i += T_S / L * u_now
    a = g.alpha_c * T_S
    z1 = np.poly1d([1.0, -1.0])
    D = (np.poly1d([1.0] + [0.0] * (d + 1)) * z1 * np.poly1d([1.0, a - 1.0])
         - 0.5 * a * np.poly1d([1.0, 0.0, -1.0]) + a * np.poly1d([1.0, 0.0])
         * np.poly1d([2.0, a - 2.0]))
    N = a * np.poly1d([1.0, 0.0]) * np.poly1d([1.0, a - 1.0])
    den, num = D.coeffs, np.concatenate([np.zeros(len(D.coeffs) - len(N.coeffs)), N.coeffs])
    y = []                                                      # the step response of N/D
    for k in range(60):
        acc = sum(num[j] for j in range(len(num)) if k - j >= 0)
        acc -= sum(den[j] * y[k - j] for j in range(1, len(den)) if k - j >= 0)
        y.append(acc / den[0])
    assert np.allclose([x.real for x in out], y, atol=1e-12)
    assert max(abs(x.imag) for x in out) == 0.0
    assert out[-1].real == pytest.approx(1.0, abs=2e-3)


# ------------------------------------------------------------------------------ speed loop
def test_the_speed_pi_on_a_pure_inertia_is_the_first_order_design():
    g = BaselineGains()
    J, a = M.J, g.alpha_s * T_S
    pi = SpeedPI(*g.speed_gains(J), T_S)
    w, ws = 0.0, []
    for _ in range(600):
        ws.append(w)
        tau = pi.output(10.0, w)
        pi.update(tau)
        w += T_S * tau / J                                      # exact for the held torque
    ks = np.arange(600)
    assert np.allclose(ws, 10.0 * (1.0 - (1.0 - a) ** ks), rtol=0, atol=1e-9)
    # the continuous design α_s/(s + α_s), sampled: within a/(2e) of the step
    cont = 10.0 * (1.0 - np.exp(-g.alpha_s * T_S * ks))
    assert np.max(np.abs(np.array(ws) - cont)) < 10.0 * a / (2 * math.e) * 1.05


def test_the_speed_pi_rejects_a_load_step_and_does_not_wind_up():
    g = BaselineGains()
    J = M.J
    pi = SpeedPI(*g.speed_gains(J), T_S, tau_max=5.0)
    w, ws = 0.0, []
    for k in range(3000):
        ws.append(w)
        tau = pi.output(0.0, w)
        pi.update(tau)
        w += T_S * (tau - 1.0) / J                              # a 1 N·m load from t = 0
    k_min = int(np.argmin(ws))
    # ω/τ_L = −s/(J(s + α_s)²): the dip −τ_L/(J α_s e) at t = 1/α_s
    assert ws[k_min] == pytest.approx(-1.0 / (J * g.alpha_s * math.e), rel=0.01)
    assert k_min * T_S == pytest.approx(1.0 / g.alpha_s, rel=0.02)
    assert abs(ws[-1]) < 1e-4
    # a step far beyond the torque limit: the limited torque drives the integrator, no overshoot
    pi = SpeedPI(*g.speed_gains(J), T_S, tau_max=5.0)
    w, peak = 0.0, 0.0
    for _ in range(12000):
        tau = pi.output(100.0, w)
        pi.update(tau)
        w += T_S * tau / J
        peak = max(peak, w)
    assert peak < 100.0 * 1.001 and w == pytest.approx(100.0, abs=1e-3)


# ------------------------------------------------------------------------------ closed loop
W_END, T1, T_RAMP = 100.0, 0.05, 0.1


def _first_order(t, alpha):
    """Return α/(s + α)'s response to the ramp 0 → W_END over [T1, T1 + T_RAMP]."""
    slope = W_END / T_RAMP

    def r(x):
        return 0.0 if x <= 0 else slope * (x - (1.0 - math.exp(-alpha * x)) / alpha)

    return r(t - T1) - r(t - T1 - T_RAMP)


@pytest.mark.parametrize('d', [0, 1])
def test_the_closed_loop_follows_a_speed_ramp_as_the_first_order_design(d):
    """
    Magnetized start, linear load 1 N·m + 0.001 ω, ramp 0 → 100 rad/s over 0.1 s.

    The speed is α_s/(s + α_s)'s response within 0.5 rad/s (measured 0.27, d = 0; 0.28, d = 1:
    the load's 1 N·m dip at the start and the current loop's lag); the steady error is below
    1e-3 rad/s at 0.4 s; the observer's rotor flux is the plant's within 1 % all along
    (measured 0.3 %, while accelerating) and 1e-3 at the end.
    """
    plant, ctl = _magnetized(d, load=LinearLoad(1.0, 0.001))
    dev = flux_err = 0.0
    for _ in range(int(0.4 / T_S)):
        m = plant.measure()
        w_ref = W_END * min(max(m.t - T1, 0.0) / T_RAMP, 1.0)
        v = ctl.compute(m.t, m.i_alpha, m.i_beta, m.theta_r, m.omega_r, w_ref)
        psi = _psi_R(plant)
        last = abs(ctl.psi_R_hat - psi) / abs(psi)         # estimate and plant at t_k
        flux_err = max(flux_err, last)
        dev = max(dev, abs(m.omega_r - _first_order(m.t, ctl.gains.alpha_s)))
        plant.step(*v)
    assert plant.trip is None
    assert dev < 0.5
    assert abs(m.omega_r - W_END) < 1e-3
    assert flux_err < 0.01
    assert last < 1e-3
    # the torque the reference asks for balances the load at the end (to the observer's
    # angle error, 1e-4 rad, times i_sd*/i_sq* = 8: measured 1.1e-3)
    assert ctl.tau_ref == pytest.approx(1.0 + 0.001 * W_END + M.b * W_END, rel=3e-3)


def test_the_closed_loop_magnetizes_from_rest_with_the_delay():
    """Unmagnetized start, 0.3 s of magnetization at ω* = 0, then the ramp: no trip, settled."""
    d = 1
    ctl = CurrentVectorController(M, T_S, delay=d)
    plant = PlantSimulator(M, load=LinearLoad(1.0, 0.001), T_s=T_S, inverter={'delay': d})
    t_mag = 0.3
    for _ in range(int((t_mag + 0.3) / T_S)):
        m = plant.measure()
        w_ref = W_END * min(max(m.t - t_mag, 0.0) / T_RAMP, 1.0)
        plant.step(*ctl.compute(m.t, m.i_alpha, m.i_beta, m.theta_r, m.omega_r, w_ref))
        if m.t == pytest.approx(t_mag):
            # 3 rotor time constants: 95 % of the flux, the observer on it
            assert abs(_psi_R(plant)) == pytest.approx(ctl.psi_R_ref, rel=0.06)
            assert abs(ctl.psi_R_hat - _psi_R(plant)) < 1e-3 * ctl.psi_R_ref
    assert plant.trip is None
    assert abs(m.omega_r - W_END) < 1e-3
