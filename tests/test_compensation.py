"""
Inverter-error compensation (docs/compensation.md).

The model, its agreement with the switched inverter, its one-line errors, and what it does to the
drive at low speed on the real plant.
"""
import math

from im_bringup.run_file import RunFileError, Scenario
from im_common.compensation import (compensation_from_dict, from_inverter, InverterErrorModel)
from im_common.inverter import Inverter, phase_values
from im_common.params import clarke
from im_common.validation import InvalidParameter
import pytest

INV = {'V_dc': 340.0, 'pwm_frequency': 10000.0, 'deadtime': 2.0e-6, 'v_on': 1.0, 'r_on': 0.02}


def test_the_error_is_the_clarke_transform_of_each_legs_loss():
    m = InverterErrorModel(v_dead=7.8, r_on=0.0, current_band=0.2)
    # the current along phase a: i_a > 0, i_b = i_c < 0, every leg beyond the band
    ea, eb = m.error(10.0, 0.0)
    assert ea == pytest.approx(2.0 * math.sqrt(2.0 / 3.0) * 7.8, rel=1e-12)
    assert eb == pytest.approx(0.0, abs=1e-12)
    # any angle: each leg's sign, transformed; the error is odd in the current
    for ang in (0.3, 1.9, 4.0):
        ia, ib = 5.0 * math.cos(ang), 5.0 * math.sin(ang)
        signs = [math.copysign(1.0, x) for x in phase_values(ia, ib)]
        want = clarke(*(7.8 * s for s in signs))
        assert m.error(ia, ib) == pytest.approx(want, rel=1e-12)
        assert m.error(-ia, -ib) == pytest.approx((-want[0], -want[1]), rel=1e-12)
    # within the band the sign ramps: half the band, half the loss; r_on adds r_on i
    half = InverterErrorModel(v_dead=4.0, r_on=0.0, current_band=2.0)
    assert half.phase_errors(1.0, -0.5, -0.5) == pytest.approx((2.0, -1.0, -1.0))
    r = InverterErrorModel(v_dead=0.0, r_on=0.05)
    assert r.error(3.0, -2.0) == pytest.approx((0.15, -0.1), rel=1e-12)
    # the command and what the motor got undo each other
    v = m.command(20.0, -5.0, 10.0, 0.0)
    assert m.motor_voltage(*v, 10.0, 0.0) == pytest.approx((20.0, -5.0), rel=1e-12)


def test_the_exact_model_is_what_the_switched_inverter_loses():
    """
    Period by period, the plant's mean pole voltage is the command less the model's error.

    The devices' r_on acts in the plant as a resistance in series with R_s (docs/plant.md §1):
    the pole voltage holds the dead time and v_on, and the model's r_on·i is that series drop.
    """
    from im_plant.plant_sim import PlantSimulator
    spec = dict(INV, r_on=0.0)
    assert from_inverter(Inverter.from_block(INV)).r_on == 0.02
    model = from_inverter(Inverter.from_block(spec))
    assert model.v_dead == pytest.approx(2e-6 * 1e4 * 340.0 + 1.0)
    sim = PlantSimulator(T_s=1e-4, locked_rotor=True, inverter=spec, v_limit=None,
                         current_trip=None, x0=(0.0, 0.0, 0.0, 0.0, 0.0, 0.0))
    for _ in range(400):                # a DC current vector at 11°: every phase far from zero
        sim.step(30.0 * math.cos(0.2), 30.0 * math.sin(0.2))
    worst = 0.0
    for _ in range(20):
        i_a, i_b, _, _ = sim.state_currents()
        assert min(abs(x) for x in phase_values(i_a, i_b)) > 1.0
        cmd = (30.0 * math.cos(0.2), 30.0 * math.sin(0.2))
        sim.step(*cmd)
        got = sim.v_applied
        want = model.motor_voltage(*cmd, i_a, i_b)
        worst = max(worst, math.hypot(got[0] - want[0], got[1] - want[1]))
    assert worst < 1e-9 * model.v_dead


def test_a_run_file_resolves_it_and_refuses_what_it_cannot_use():
    sc = Scenario.from_mapping({'task': 'speed', 'duration': 0.01, 'inverter': INV,
                                'compensation': 'inverter'})
    assert sc.compensation == {'v_dead': pytest.approx(7.8), 'r_on': 0.02, 'current_band': 0.2}
    p = sc.node_parameters()
    for node in ('controller', 'observer', 'adapter'):
        assert p[node]['comp_v_dead'] == pytest.approx(7.8) and p[node]['comp_r_on'] == 0.02
    assert 'comp_v_dead' not in p['plant']
    assert Scenario.from_mapping(sc.to_mapping()).compensation == sc.compensation
    given = Scenario.from_mapping({'task': 'speed', 'compensation': {'v_dead': 5.0}})
    assert given.controller_config().compensation == InverterErrorModel(5.0)
    for spec, where in (('inverter', 'compensation'), ({'v_dead': -1.0}, 'compensation.v_dead'),
                        ({'r_on': 0.1}, 'compensation.v_dead'),
                        ({'v_dead': 1.0, 'deadband': 2}, 'compensation.deadband')):
        with pytest.raises(RunFileError) as exc:
            Scenario.from_mapping({'task': 'speed', 'compensation': spec})
        assert where in str(exc.value) and '\n' not in str(exc.value)
    with pytest.raises(InvalidParameter, match='must be false, inverter'):
        compensation_from_dict(3.0, Inverter.from_block(INV))
    assert compensation_from_dict(False) is None


@pytest.mark.slow
def test_compensation_removes_the_low_speed_current_distortion():
    """
    10 rad/s against half the rated torque, thesis motor, real plant: the study's first rows.

    The dead time and device drops bend the current the controller asks for; with the
    compensation the current follows its reference within a few hundredths of what it missed.
    """
    from im_bringup.offline import simulate
    from im_studies.study_real_plant import figures, hold
    off = figures(simulate(hold('thesis', sensorless=False, compensation=False)))
    on = figures(simulate(hold('thesis', sensorless=False, compensation=True)))
    assert off['trip'] is None and on['trip'] is None
    assert off['current_distortion_A'] > 0.2                     # what the inverter does
    assert on['current_distortion_A'] < off['current_distortion_A'] / 10.0
    # the encoder's counts (2048 lines) leave a floor under the speed error
    assert on['speed_err_rms'] < off['speed_err_rms'] / 4.0


@pytest.mark.slow
def test_on_the_real_plant_with_compensation_a_load_step_and_a_reversal_hold_sensorless():
    """
    Check the study's load-step and reversal rows (thesis motor; docs/compensation.md).

    Half the rated torque stepped on at 100 rad/s: back within 2 rad/s in 0.3 s; without the
    compensation not within the run. A ±150 rad/s reversal through zero under 2 N·m: within 2
    rad/s after the ramp.
    """
    from im_bringup.offline import simulate
    from im_studies.study_real_plant import figures, load_step, reversal, SETTLE
    on = simulate(load_step('thesis', True)).summary
    off = simulate(load_step('thesis', False)).summary
    assert on['trip'] is None and on['speed_recovery_s'] <= 0.3 and on['speed_dip_rad_s'] > 2.0
    assert not off['speed_recovery_s'] <= 0.3              # NaN: never back within the run
    sc, end = reversal('thesis')
    rev = figures(simulate(sc, record_every=10), after=end + SETTLE)
    assert rev['trip'] is None and rev['speed_err_max'] < 2.0
