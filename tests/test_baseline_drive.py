"""
The baseline laws in the drive (docs/baselines.md): ``controller: current_vector`` and ``vhz``.

Run through the stack's own references, flux strategies and limits, on every path (the ROS-free
loop, the graph, its node parameters), with what a drive engineer expects of each law: the
current-vector controller with the reference fed forward follows a speed ramp as the thesis law
does, and without it lags the ramp by its acceleration over the speed bandwidth (the closed form
of a type-1 loop); V/Hz's slip compensation holds the speed under load; a law refuses a task it
cannot do, and its gains block, in one line.
"""
from dataclasses import replace
import math
import os

from im_bringup.offline import simulate
from im_bringup.run_file import RunFileError, Scenario
from im_bringup.testing import assert_samples_match, run_graph
from im_common.inverter import Inverter
from im_common.validation import InvalidParameter
from im_controller.baselines.drive import BaselineDrive
from im_controller.baselines.gains import BaselineGains
from im_controller.control_law import ControllerConfig
from im_controller.trajectories import THESIS_TRAJECTORIES
import numpy as np
import pytest


def _run(**kw):
    return simulate(Scenario(**kw))


def _ramp_acceleration() -> float:
    """Return the largest acceleration of the thesis speed reference [rad/s²]."""
    traj = THESIS_TRAJECTORIES['speed']()
    return max(abs(traj.sample(t)[2]) for t in np.arange(0.0, 1.5, 1e-4))


@pytest.mark.parametrize('law', ['current_vector', 'flux_vector'])
def test_a_speed_pi_law_with_feedforward_follows_the_speed_ramp_as_the_thesis_law(law):
    """Same feedforward knowledge: the speed error of both laws stays below 0.01 rad/s."""
    thesis = _run(task='speed', strategy='constant_flux').summary
    base = _run(task='speed', strategy='constant_flux', controller=law).summary
    assert thesis['speed_err_max_rad_s'] < 0.01
    assert base['speed_err_max_rad_s'] < 0.01
    # the same motion: the energy drawn agrees within 0.5 %
    assert base['E_in_J'] == pytest.approx(thesis['E_in_J'], rel=5e-3)


def test_flux_vector_holds_the_stator_flux_so_the_rotor_flux_follows_the_strategy():
    """
    min_loss in the position task: the flux-vector law loses what the thesis law does (±1 %).

    It sets the stator flux directly, so the rotor flux follows the moving target without the
    rotor time constant's lag of the current-vector controller's i_sd* = ψ_R*/L_M.
    """
    thesis = _run(task='position', strategy='min_loss').summary
    fvc = _run(task='position', strategy='min_loss', controller='flux_vector').summary
    cvc = _run(task='position', strategy='min_loss', controller='current_vector').summary
    assert fvc['pos_err_max_rad'] < 1e-3
    assert fvc['E_loss_J'] == pytest.approx(thesis['E_loss_J'], rel=0.01)
    assert cvc['E_loss_J'] > 1.05 * fvc['E_loss_J']


def test_current_vector_as_shipped_lags_a_ramp_by_its_acceleration_over_the_bandwidth():
    """
    The 2DOF speed PI of motulator (no feedforward): ω/ω* = α_s/(s + α_s), a ramp lags a/α_s.

    The thesis speed reference's largest acceleration over α_s = 100 and 50 rad/s.
    """
    a_max = _ramp_acceleration()
    for alpha_s in (100.0, 50.0):
        s = _run(task='speed', strategy='constant_flux', controller='current_vector',
                 baseline={'feedforward': False, 'alpha_s': alpha_s}).summary
        assert s['speed_err_max_rad_s'] == pytest.approx(a_max / alpha_s, rel=0.1), alpha_s


def test_current_vector_positions_the_pendulum_and_the_thesis_law_wins_on_moving_flux():
    """
    The position task: a P loop on the angle around the speed PI, each strategy's flux.

    Both laws hold the pendulum within 1 mrad. Where the flux moves (min_energy, min_loss), the
    thesis law's reference model forces it (i_d = (φ + T_r φ̇)/L_sr) and follows it within
    0.02 Wb; the current-vector controller's i_sd* = ψ_R*/L_M lets the rotor lag by its own
    time constant, so its flux error is several times larger and it loses more energy.
    """
    for strategy in ('min_energy', 'min_loss'):
        thesis = _run(task='position', strategy=strategy).summary
        cvc = _run(task='position', strategy=strategy, controller='current_vector').summary
        assert cvc['pos_err_max_rad'] < 1e-3 and thesis['pos_err_max_rad'] < 1e-3, strategy
        assert thesis['flux_err_max_Wb'] < 0.021
        assert cvc['flux_err_max_Wb'] > 3 * thesis['flux_err_max_Wb'], strategy
        assert cvc['E_loss_J'] > 1.05 * thesis['E_loss_J'], strategy


def test_vhz_holds_the_speed_under_load_by_its_slip_compensation():
    """Observer-based V/Hz on the speed task: at the end (steady, loaded) on the reference."""
    r = _run(task='speed', strategy='constant_flux', controller='vhz')
    t = np.asarray(r.trace['t'])
    late = t > 1.3
    err = np.asarray(r.trace['omega_r'])[late] - np.asarray(r.trace['omega_ref'])[late]
    assert np.abs(err).max() < 0.05
    assert np.abs(np.asarray(r.trace['tau_L'])[late]).min() > 1.0     # it is loaded there
    # V/Hz sets a frequency, not a torque: it follows the ramp less tightly than the PI
    assert r.summary['speed_err_max_rad_s'] > 0.1


def test_the_flux_strategy_sets_a_baseline_laws_flux():
    """min_loss lowers the flux of a lightly loaded drive, whichever law makes the voltage."""
    for law in ('current_vector', 'vhz'):
        const = _run(task='speed', strategy='constant_flux', controller=law, duration=0.5)
        low = _run(task='speed', strategy='min_loss', controller=law, duration=0.5)
        phi_c = np.asarray(const.trace['phi_d_ref'])[-1]
        phi_l = np.asarray(low.trace['phi_d_ref'])[-1]
        assert phi_l < 0.9 * phi_c, law
        assert low.summary['E_loss_J'] < const.summary['E_loss_J'], law


def test_a_law_refuses_a_task_it_cannot_do_in_one_line():
    with pytest.raises(InvalidParameter, match=r"'controller'.*vhz cannot do the 'position' "
                                               r'task: it does speed'):
        Scenario(task='position', controller='vhz')
    with pytest.raises(InvalidParameter, match=r"'law'.*vhz cannot do the 'torque' task"):
        ControllerConfig(law='vhz', mode='torque', profile='setpoint')
    with pytest.raises(InvalidParameter, match='torque_limit.*vhz makes no torque reference'):
        BaselineDrive('vhz', ControllerConfig().params, 1e-4, torque_limit=5.0)


@pytest.mark.parametrize('doc, key', [
    ({'controller': 'current_vector', 'baseline': {'alpha_psi': 10.0}}, 'baseline.alpha_psi'),
    ({'controller': 'current_vector', 'baseline': {'alpha_s': -1.0}}, 'baseline.alpha_s'),
    ({'controller': 'vhz', 'task': 'speed', 'baseline': {'alpha_c': 10.0}}, 'baseline.alpha_c'),
    ({'controller': 'nominal', 'baseline': {'alpha_s': 10.0}}, 'baseline'),
    # the thesis law's gains would be ignored by a baseline: refused, not dropped
    ({'controller': 'current_vector', 'controller_options': {'k_v': 3.0}},
     'controller_options.k_v: is a gain of the thesis law; controller current_vector takes its '
     "gains from 'baseline:'"),
    ({'controller': 'flux_vector', 'current_gain': [[40.0, 0.0], [0.0, 40.0]]}, 'current_gain'),
])
def test_a_bad_baseline_block_is_one_line_naming_its_key(doc, key):
    with pytest.raises(RunFileError) as err:
        Scenario.from_mapping(doc, source='run.yaml')
    line = str(err.value)
    assert '\n' not in line and line.startswith(f'run.yaml: {key}'), line


def test_baseline_gains_come_from_the_bandwidths_and_the_motor():
    """k_t = α_c L_σ, k_p = 2 α_c L_σ, k_i = α_c² L_σ; the speed PI's on J."""
    sc = Scenario(task='speed', controller='current_vector', baseline={'alpha_c': 2000.0})
    b = BaselineDrive('current_vector', sc.controller_config().params, 1e-4,
                      sc.controller_config().baseline)
    L = b.motor.L_sigma
    assert (b.ctl.current.k_t, b.ctl.current.k_p, b.ctl.current.k_i) == pytest.approx(
        (2000.0 * L, 4000.0 * L, 4e6 * L))
    assert b.ctl.speed.k_p == pytest.approx(2 * BaselineGains().alpha_s * b.motor.J)


@pytest.mark.parametrize('controller, task', [('current_vector', 'position'),
                                              ('flux_vector', 'speed'), ('vhz', 'speed')])
def test_the_graph_runs_a_baseline_as_the_ros_free_loop(controller, task):
    """
    The controller node takes ``law`` and the ``baseline.*`` gains: the graph equals the loop.

    A gain off its default (α_c, α_τ) shows the node parameters reach the law.
    """
    baseline = {'alpha_c': 1500.0} if controller == 'current_vector' else {'alpha_tau': 100.0}
    if controller == 'flux_vector':
        baseline = {'alpha_tau': 500.0}
    sc = Scenario(task=task, strategy='min_loss', controller=controller, baseline=baseline,
                  duration=0.05)
    g = run_graph(scenario=sc)
    off = simulate(sc)
    assert g.summary['ok'], g.summary['failures']
    for key in ('E_in_J', 'E_copper_J'):
        assert g.summary[key] == pytest.approx(off.summary[key], rel=1e-9, abs=1e-12), key
    assert_samples_match(g.trace, off.trace, ('omega_r', 'theta_r'), 500)
    default = simulate(Scenario(task=task, strategy='min_loss', controller=controller,
                                duration=0.05))
    assert not math.isclose(default.summary['E_in_J'], off.summary['E_in_J'], rel_tol=1e-9)


def test_a_baseline_runs_sensorless_on_the_stacks_speed_estimate():
    """``sensorless: true``: the current-vector controller takes the speed observer's ω̂."""
    sensored = _run(task='speed', strategy='min_loss', controller='current_vector').summary
    s = _run(task='speed', strategy='min_loss', controller='current_vector',
             sensorless=True).summary
    assert not s['trip'] and s['speed_err_max_rad_s'] < 0.5
    assert s['speed_err_max_rad_s'] > sensored['speed_err_max_rad_s']    # the estimate lags
    assert s['E_loss_J'] == pytest.approx(sensored['E_loss_J'], rel=0.02)


RUNS = os.path.join(os.path.dirname(os.path.abspath(__file__)), '..', 'src', 'im_bringup',
                    'config', 'runs')


@pytest.mark.slow
@pytest.mark.parametrize('motor', ['thesis', 'krause_3hp'])
def test_the_shipped_baseline_run_files_hold_a_load_step_on_the_real_plant(motor):
    """
    Each baseline runs ``config/runs/baseline_real_<motor>.yaml`` (docs/comparison.md §2).

    Sensored and sensorless, behind the switched inverter with one period of delay, the
    compensation on. No run trips; the PI laws never leave ±2 rad/s of the reference after the
    step, V/Hz (no speed loop) comes back within it by its slip compensation.
    """
    base = Scenario.from_file(os.path.join(RUNS, f'baseline_real_{motor}.yaml'))
    assert base.delay == 1 and base.inverter.switched and base.compensation is not None
    assert base.law == 'current_vector' and base.iron_loss and base.sensors is not None
    for law in ('current_vector', 'flux_vector', 'vhz'):
        for sensorless in (False, True):
            s = simulate(replace(base, controller=law, sensorless=sensorless)).summary
            what = f'{motor}, {law}, sensorless={sensorless}: {s}'
            assert not s['trip'] and s['balance_relative'] < 1e-6, what
            assert s['E_dc_J'] > s['E_in_J'] and s['load_step_t'] == 0.5, what
            if law == 'vhz':
                assert 0.0 < s['speed_recovery_s'] < 0.3 and s['speed_err_rms_rad_s'] < 2.0, what
            else:
                assert s['speed_recovery_s'] == 0.0 and s['speed_err_rms_rad_s'] < 0.4, what


def test_the_graph_books_the_dc_link_as_the_ros_free_loop():
    """
    A shipped run file's 50 ms on the graph: the inverter's losses and the DC link's energy.

    With switching losses on (e_sw): the plant node appends E_switching to /im/truth/energy and
    the recording's summary books it as the ROS-free loop does.
    """
    base = Scenario.from_file(os.path.join(RUNS, 'baseline_real_krause_3hp.yaml'))
    inv = Inverter.from_block(dict(base.inverter.describe(), e_sw=2e-4, v_sw=300.0, i_sw=10.0))
    sc = replace(base, duration=0.05, inverter=inv)
    g = run_graph(scenario=sc)
    off = simulate(sc)
    assert g.summary['ok'], g.summary['failures']
    for key in ('E_in_J', 'E_inverter_J', 'E_dc_J', 'E_switching_J'):
        assert g.summary[key] == pytest.approx(off.summary[key], rel=1e-9), key
    assert 0.0 < g.summary['E_switching_J'] < g.summary['E_inverter_J']
    assert g.summary['E_dc_J'] == pytest.approx(g.summary['E_in_J'] + g.summary['E_inverter_J'])
