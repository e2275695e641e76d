"""
Limits of the control law (issue 10).

Smooth magnetizing floor, torque/current/speed bounds, field weakening, the anti-windup that cannot
latch, live reconfiguration, profiles.
"""
import math

from im_common.loads import NoLoad
from im_common.params import InvalidParameter, THESIS_MOTOR
from im_controller.control_law import ControllerConfig, DriveController, smooth_floor
from im_controller.parameters import live_changes, LIVE_PARAMETERS
from im_controller.profiles import from_parameters, from_samples, from_setpoints, load_profile
from im_observer.observer import RotorFluxObserver
from im_plant.plant_sim import PlantSimulator
import pytest


def test_smooth_floor_is_c2_and_exact_above_three_eps():
    eps = 0.02
    assert smooth_floor(0.0, 0.0, 0.0, eps) == (eps, 0.0, 0.0)
    assert smooth_floor(0.5, 1.0, 2.0, eps) == (0.5, 1.0, 2.0)
    # f, f', f'' continuous at 3 eps: the chain rule values match on both sides
    lo = smooth_floor(3 * eps * (1 - 1e-9), 1.0, 0.0, eps)
    hi = smooth_floor(3 * eps, 1.0, 0.0, eps)
    assert lo[0] == pytest.approx(hi[0], abs=1e-9)
    assert lo[1] == pytest.approx(hi[1], abs=1e-7)
    assert lo[2] == pytest.approx(hi[2], abs=1e-5)
    # monotone and never below eps on the way up
    prev = 0.0
    for k in range(1, 101):
        f = smooth_floor(3 * eps * k / 100, 1.0, 0.0, eps)[0]
        assert f >= eps and f >= prev
        prev = f


def _loop(cfg, n, setpoints=(), plant_kw=None, x0=None):
    """Plant + observer + controller in the lock-step order; returns per-step (t, |V|, ω, τ*)."""
    plant = PlantSimulator(THESIS_MOTOR, NoLoad(), T_s=cfg.T_s, x0=x0, **(plant_kw or {}))
    obs = RotorFluxObserver(cfg.params, x0=(0.0, 0.0, 0.0, 0.0))
    ctl = DriveController(cfg)
    for kind, value, t in setpoints:
        ctl.set_setpoint(kind, value, t)
    x_hat = obs.state
    out = []
    for _ in range(n):
        m = plant.measure()
        v_a, v_b = ctl.compute(m.t, m.i_alpha, m.i_beta, m.theta_r, m.omega_r, x_hat[2], x_hat[3])
        out.append((m.t, math.hypot(v_a, v_b), m.omega_r, ctl.reference['tau_ref'],
                    ctl.reference['phi_d_ref']))
        plant.step(v_a, v_b)
        x_hat = obs.step(cfg.T_s, v_a, v_b, m.i_alpha, m.i_beta, m.omega_r)
    return out, ctl


def test_torque_mode_start_up_magnetizes_without_a_spike():
    """
    Torque mode from a demagnetized machine (issue 10, item 2).

    The start-up voltage stays below the voltage the run needs once the torque is applied.
    """
    cfg = ControllerConfig(mode='torque', profile='setpoint', strategy='constant_flux')
    out, _ = _loop(cfg, 4000, setpoints=[('torque', 5.0, 0.2)])
    v_start = max(r[1] for r in out if r[0] < 0.2)
    v_run = max(r[1] for r in out if r[0] >= 0.2)
    assert v_start <= 1.5 * v_run, (v_start, v_run)
    # the flux reference rises monotonically from the floor: no step, no dip
    phis = [r[4] for r in out if r[0] < 0.2]
    assert all(b >= a - 1e-12 for a, b in zip(phis, phis[1:]))


def test_a_torque_demand_on_a_demagnetized_machine_waits_for_the_flux():
    """
    Torque asked for at t = 0.

    The torque reference grows with the flux (|i_q*| ≤ 2 i_d*/√σ with zero torque at the floor
    flux), so the first steps need no voltage step.
    """
    cfg = ControllerConfig(mode='torque', profile='setpoint', strategy='constant_flux',
                           setpoint_duration=0.01)
    out, _ = _loop(cfg, 3000, setpoints=[('torque', 5.0, 0.0)])
    late, _ = _loop(cfg, 20, setpoints=[('torque', 5.0, 0.2)])
    assert out[0][3] == 0.0
    # the first step is the magnetizing step alone (the torque asked for adds nothing yet), and
    # the start-up needs less than the run does once the shaft turns
    assert out[0][1] == pytest.approx(late[0][1], rel=1e-12)
    assert max(r[1] for r in out[:20]) <= max(r[1] for r in out if r[0] >= 0.2)
    assert out[-1][3] == pytest.approx(5.0)


def test_torque_limit_bounds_the_demand():
    cfg = ControllerConfig(mode='torque', profile='setpoint', strategy='constant_flux',
                           torque_limit=3.0)
    out, _ = _loop(cfg, 3000, setpoints=[('torque', 20.0, 0.05)])
    assert max(abs(r[3]) for r in out) <= 3.0 + 1e-12
    assert out[-1][3] == pytest.approx(3.0)


def test_current_limit_bounds_the_reference_current():
    cfg = ControllerConfig(mode='torque', profile='setpoint', strategy='constant_flux',
                           current_limit=20.0)
    ctl = DriveController(cfg)
    # on the reference, magnetized: φ* = 1.2, i_d* = φ/L_sr = 14.75 A
    from im_controller.control_law import steady_operating_point
    op = steady_operating_point(cfg, 0.0, 0.0, 0.0)
    ctl.compute(0.0, op['i_alpha'], op['i_beta'], 0.0, 0.0, op['phi_alpha'], op['phi_beta'])
    ctl.set_setpoint('torque', 100.0, 0.0)
    for k in range(1, 200):
        ctl.compute(k * 1e-4, op['i_alpha'], op['i_beta'], 0.0, 0.0, op['phi_alpha'],
                    op['phi_beta'])
    r = ctl.reference
    assert math.hypot(r['i_d_ref'], r['i_q_ref']) == pytest.approx(20.0, rel=1e-6)
    assert r['torque_limited']


def test_the_fluxes_within_a_current_limit_are_the_roots_of_a_quadratic():
    """
    Check the flux range under a current limit against its closed form.

    Closed form: at either end of the range the steady currents of τ are exactly i_max, inside it
    they are below, outside above; beyond any flux's reach the range is the single flux of most
    torque per ampere, i_d = i_q.
    """
    from im_controller.flux import flux_range_within_current
    c = DriveController(ControllerConfig()).coefficients

    def current(phi, tau):
        return math.hypot(phi / c.L_sr, c.L_r * tau / (c.v * c.L_sr * phi))

    mtpa = c.L_sr * 20.0 / math.sqrt(2.0)
    for tau in (0.5, 5.0, 20.0, -20.0):
        lo, hi = flux_range_within_current(c, tau, 20.0)
        assert lo < mtpa < hi
        for phi in (lo, hi):
            assert current(phi, tau) == pytest.approx(20.0, rel=1e-9)
        assert current(0.99 * lo, tau) > 20.0 and current(1.01 * hi, tau) > 20.0
        assert current(0.5 * (lo + hi), tau) < 20.0
    assert flux_range_within_current(c, 1e3, 20.0) == pytest.approx((mtpa, mtpa))


@pytest.mark.parametrize('strategy,tau,limit,side', [
    ('min_energy', 25.0, 22.0, 0),      # its own flux (i_q/i_d = 1/√σ) is far below: raised
    ('min_loss', 15.0, 15.5, 1),        # its own flux is above the most torque per ampere: lowered
])
def test_under_a_current_limit_the_optimizing_strategies_choose_a_flux_that_fits(
        strategy, tau, limit, side):
    """
    Check each strategy's flux target under a current limit.

    Under a current limit the flux target of min_energy / min_loss is the nearest to its own
    optimum whose steady current for τ fits in 0.9 × the limit; constant flux keeps φ_d.
    """
    from im_controller.flux import FluxStrategy, flux_range_within_current
    c = DriveController(ControllerConfig()).coefficients
    own = FluxStrategy(strategy).target(c, tau, 0.0)
    assert math.hypot(own / c.L_sr, c.L_r * tau / (c.v * c.L_sr * own)) > 0.9 * limit

    def target(cfg):
        ctl = DriveController(cfg)
        ctl.compute(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        ctl.set_setpoint('torque', tau, 0.0)
        for k in range(1, 800):
            ctl.compute(k * 1e-4, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        return ctl.reference['phi_target']

    limited = ControllerConfig(mode='torque', profile='setpoint', strategy=strategy,
                               current_limit=limit)
    expected = flux_range_within_current(c, tau, 0.9 * limit)[side]
    assert target(limited) == pytest.approx(expected, rel=1e-9)
    assert (target(limited) - own) * (1 if side == 0 else -1) > 0
    held = ControllerConfig(mode='torque', profile='setpoint', strategy='constant_flux',
                            phi_d=0.5, current_limit=limit)
    assert target(held) == 0.5
    with pytest.raises(InvalidParameter, match='current_margin'):
        ControllerConfig(current_margin=1.5)


def test_speed_limit_stops_pushing_beyond_it():
    cfg = ControllerConfig(mode='torque', profile='setpoint', strategy='constant_flux',
                           speed_limit=50.0)
    out, _ = _loop(cfg, 20000, setpoints=[('torque', 10.0, 0.1)])
    # unloaded, 10 N·m would reach far more than 50 rad/s in 2 s (J = 0.03)
    w_max = max(r[2] for r in out)
    assert 50.0 <= w_max < 55.0
    assert all(r[3] <= 1e-12 for r in out if r[2] > 50.0)


def test_field_weakening_caps_the_flux_inversely_with_speed():
    cfg = ControllerConfig(mode='speed', profile='setpoint', strategy='constant_flux',
                           v_limit=311.0)
    ctl = DriveController(cfg)
    c = ctl.coefficients
    base = 0.85 * 311.0 * c.L_sr / (c.L_s * 1.2 * c.v)     # speed where the cap reaches φ_d
    assert ctl.flux_cap(0.5 * base) > 1.2
    assert ctl.flux_cap(2 * base) == pytest.approx(ctl.flux_cap(base) / 2)
    assert DriveController(ControllerConfig(v_limit=None)).flux_cap(1e4) == math.inf
    assert DriveController(ControllerConfig(v_limit=311.0,
                                            field_weakening=False)).flux_cap(1e4) == math.inf


def test_voltage_saturation_does_not_freeze_the_torque_filter():
    """
    The latch of issue 10: one unsaturated step between saturated ones froze the PD filter's input.

    Now the filter takes every input: after a saturated stretch its state follows the latest PD
    demand, not one from the past.
    """
    cfg = ControllerConfig(mode='speed', profile='setpoint', strategy='constant_flux',
                           v_limit=50.0)
    ctl = DriveController(cfg)
    from im_controller.control_law import steady_operating_point
    op = steady_operating_point(ControllerConfig(mode='speed', profile='setpoint',
                                                 strategy='constant_flux'), 0.0, 0.0, 100.0)
    i = (op['i_alpha'], op['i_beta'])
    ctl.compute(0.0, *i, 0.0, 100.0, op['phi_alpha'], op['phi_beta'])
    assert ctl.reference['saturated']           # 100 rad/s at 1.2 Wb needs ~240 V
    for k in range(1, 400):                     # shaft 20 rad/s slow for 40 ms
        t = k * 1e-4
        ctl.compute(t, *i, 80.0 * t, 80.0, op['phi_alpha'], op['phi_beta'])
    assert ctl.reference['saturated']
    # the PD demand of the latest step: speed error only, θ* back-calculated onto the shaft
    u_pd = -cfg.k_v * (80.0 - 100.0)
    assert ctl.pd_filter.u == pytest.approx(u_pd, rel=1e-3)
    assert ctl.pd_filter.y == pytest.approx(u_pd, rel=1e-2)


def test_reconfigure_keeps_state_and_is_continuous():
    """
    Mid-run changes of a gain and of a flux level.

    The run state is kept and the command moves only by what the change implies — ΔK·|i − i*|
    for k₁; for φ_min the flux filter's acceleration change p₁p₂Δφ_tgt through d i_d*/dt =
    (T_r/L_sr) d²φ*/dt² into σL_s di/dt.
    """
    from im_common.loads import PendulumLoad
    cfg = ControllerConfig(mode='position', profile='thesis', strategy='min_energy')
    T_s = cfg.T_s
    plant = PlantSimulator(THESIS_MOTOR, PendulumLoad(10.0), T_s=T_s, theta0=-0.5 * math.pi)
    obs = RotorFluxObserver(cfg.params, x0=(0.0, 0.0, 0.0, 0.0))
    ctl = DriveController(cfg)
    c = ctl.coefficients
    x_hat = obs.state
    volts, bounds = [], {}
    m_prev = None
    for k in range(5600):
        if k in (5000, 5500):
            ref = dict(ctl.reference)
            err = math.hypot(m_prev.i_alpha - ref['i_alpha_ref'],
                             m_prev.i_beta - ref['i_beta_ref'])
            if k == 5000:
                ctl.reconfigure({'k1': 60.0})
                bounds[k] = 20.0 * err
            else:
                d_tgt = abs(max(0.3, ref['phi_target']) - ref['phi_target'])
                ctl.reconfigure({'phi_min': 0.3})
                assert ctl.config.magnetizing_floor == pytest.approx(0.03)
                bounds[k] = 1.01 * c.sigma_L_s * d_tgt / (c.L_sr * 1e-3)
            assert ref['rho'] != 0.0
        m = plant.measure()
        v = ctl.compute(m.t, m.i_alpha, m.i_beta, m.theta_r, m.omega_r, x_hat[2], x_hat[3])
        volts.append(v)
        m_prev = m
        plant.step(*v)
        x_hat = obs.step(T_s, v[0], v[1], m.i_alpha, m.i_beta, m.omega_r)
    assert ctl.config.k1 == 60.0 and ctl.config.phi_min == 0.3

    def step(k):
        return math.hypot(volts[k][0] - volts[k - 1][0], volts[k][1] - volts[k - 1][1])

    ordinary = max(step(k) for k in range(4000, 5000))
    for k, bound in bounds.items():
        assert step(k) <= 2 * ordinary + bound, (k, step(k), ordinary, bound)
    assert bounds[5500] > 0.0     # the φ_min change did move the target (the check is not idle)


def test_reconfigure_refuses_invalid_values_and_keeps_the_old_configuration():
    ctl = DriveController(ControllerConfig())
    old = ctl.config
    with pytest.raises(InvalidParameter, match="'k1'"):
        ctl.reconfigure({'k1': -1.0})
    with pytest.raises(InvalidParameter, match="'phi_max'"):
        ctl.reconfigure({'phi_min': 0.5, 'phi_max': 0.4})
    with pytest.raises(InvalidParameter, match="'mode'"):
        ctl.reconfigure({'mode': 'speed'})
    assert ctl.config is old


def test_live_parameters_convert_like_the_node():
    values = {'mode': 'position', 'profile': 'thesis', 'strategy': 'min_energy', 'phi_d': 1.2,
              'phi_min': 0.2, 'phi_max': 1.2, 'k1': 40.0, 'k_p': -1.0, 'k_v': -1.0,
              'load_known': True, 'load': 'pendulum', 'load_mgl': 10.0, 'load_c1': 1.0,
              'load_c2': 0.001, 'load_tau': 0.0, 'v_limit': 0.0, 'current_gain': [0.0],
              'gain_period': 0.0, 'flux_coupling': 'cancel', 'hold_compensation': True,
              'torque_filter_bandwidth': 1000.0, 'flux_preview': -1.0, 'core_loss_exponent': 2.0,
              'setpoint_duration': 0.5, 'setpoints': [0.0], 'torque_limit': 0.0,
              'current_limit': 0.0, 'speed_limit': 0.0, 'field_weakening': True,
              'voltage_margin': 0.85}
    ch = live_changes(THESIS_MOTOR, values, {'v_limit': 0.0, 'torque_limit': 5.0}, 1e-4)
    assert ch == {'v_limit': None, 'torque_limit': 5.0}
    with pytest.raises(ValueError, match="'mode' is read-only"):
        live_changes(THESIS_MOTOR, values, {'mode': 'speed'}, 1e-4)
    assert 'mode' not in LIVE_PARAMETERS and 'k1' in LIVE_PARAMETERS


def test_profiles_yaml_csv_and_parameters(tmp_path):
    p = tmp_path / 'p.yaml'
    p.write_text('setpoints:\n  - {t: 0.0, velocity: 100.0}\n'
                 '  - {t: 0.2, velocity: 180.0, duration: 0.3}\n')
    prof = load_profile(str(p))
    assert prof.mode == 'speed' and prof.start_value == 100.0
    assert prof.setpoints == ((0.0, 100.0, None), (0.2, 180.0, 0.3))
    assert from_parameters(prof.as_parameters()['setpoints']) == prof.setpoints
    c = tmp_path / 'p.csv'
    c.write_text('t,position\n0.0,0.0\n0.5,1.0\n1.0,0.5\n')
    prof = load_profile(str(c))
    assert prof.mode == 'position' and prof.end_time == pytest.approx(1.0)
    # the sampled reference passes through every sample at its time
    ctl = DriveController(ControllerConfig(mode='position', profile='setpoint',
                                           setpoints=prof.setpoints, load='none'))
    seen = {}
    for k in range(12001):
        t = k * 1e-4
        ctl.compute(t, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        if k in (5000, 10000):
            seen[k] = ctl.reference['theta_ref']
    assert seen[5000] == pytest.approx(1.0, abs=1e-9)
    assert seen[10000] == pytest.approx(0.5, abs=1e-9)


@pytest.mark.parametrize('text, where', [
    ('setpoints: []\n', 'setpoints'),
    ('setpoints:\n  - {t: 0.0, speed: 1.0}\n', 'setpoints[0].speed'),
    ('setpoints:\n  - {t: 0.0, velocity: 1.0}\n  - {t: 0.1, position: 1.0}\n',
     'setpoints[1].position'),
    ('setpoints:\n  - {t: 0.5, velocity: 1.0}\n  - {t: 0.1, velocity: 1.0}\n',
     'setpoints[1].t'),
    ('setpoints:\n  - {velocity: 1.0}\n', 'setpoints[0].t'),
    ('setpoints:\n  - {t: 0.0, velocity: .nan}\n', 'setpoints[0].velocity'),
    ('steps: []\n', 'setpoints'),
])
def test_bad_profile_files_name_the_entry(tmp_path, text, where):
    p = tmp_path / 'bad.yaml'
    p.write_text(text)
    with pytest.raises(InvalidParameter) as e:
        load_profile(str(p))
    assert str(p) in str(e.value) and where in str(e.value)
    assert '\n' not in str(e.value)


def test_bad_csv_profiles(tmp_path):
    for text, where in (('t,speed\n0,1\n', 'header'), ('t,velocity\n0,1\n0,2\n', 'row 2 t'),
                        ('t,velocity\n0,x\n', 'line 2')):
        p = tmp_path / 'bad.csv'
        p.write_text(text)
        with pytest.raises(InvalidParameter, match=where):
            load_profile(str(p))
    with pytest.raises(InvalidParameter, match='cannot read profile file'):
        load_profile(str(tmp_path / 'missing.yaml'))
    with pytest.raises(InvalidParameter):
        from_samples('velocity', [])
    with pytest.raises(InvalidParameter, match="profile 'setpoint'"):
        ControllerConfig(setpoints=((0.0, 1.0, None),))
    assert from_setpoints([{'t': 0.0, 'effort': 2.0}]).mode == 'torque'
