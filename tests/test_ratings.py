"""
Motor ratings in nameplate units (issue 24, part 2).

Converted once to the model's power-invariant frame, the rated flux from the equivalent circuit,
and the ratings as the drive's default limits, protection and flux level — explicit values
override, unrated motors run as the thesis did.
"""
import math
import os

from im_common.params import (clarke, CURRENT_TRIP_MARGIN, default_limits, describe_defaults,
                              InvalidParameter, load_motor_file, MotorParams, rated_flux,
                              shipped_motors_dir, SPEED_TRIP_MARGIN, THESIS_MOTOR,
                              vector_magnitude)
from im_common.steady_state import params_steady_state
from im_controller.control_law import ControllerConfig
from im_plant.plant_sim import PlantSimulator
import numpy as np
import pytest

#: the thesis motor's electrical values with a user's nameplate: 220 V, 5 A, 60 Hz, 1750 rpm
PLATE = {'rated_voltage_rms_line': 220.0, 'rated_current_rms': 5.0, 'rated_frequency': 60.0,
         'rated_speed_rpm': 1750.0, 'rated_power': 2200.0}
RATED = THESIS_MOTOR.with_values(**PLATE)


def _balanced(rms: float, phase: float, t: np.ndarray, w: float = 2 * math.pi * 60.0):
    """Return a balanced three-phase set of phase RMS value ``rms``."""
    return [math.sqrt(2.0) * rms * np.cos(w * t + phase - 2.0 * math.pi * k / 3.0)
            for k in range(3)]


def test_a_balanced_set_of_known_rms_is_a_vector_of_sqrt3_times_it_through_the_transform():
    """
    Check the transform against the closed form for a balanced set.

    Closed form: x_k = √2 X cos(ωt − 2πk/3) → |x_αβ| = √3 X at every instant, and the
    transform keeps the power (Σ v_k i_k = v·i); so a star of phase voltage V_LL/√3 and line
    current I is a voltage vector of magnitude V_LL and a current vector of √3 I, and the model's
    v·i at unity power factor is the nameplate's √3 V_LL I.
    """
    t = np.linspace(0.0, 0.05, 997)
    V_LL, I_L, pf_angle = 220.0, 5.0, 0.4
    v_abc = _balanced(V_LL / math.sqrt(3.0), 0.0, t)
    i_abc = _balanced(I_L, -pf_angle, t)
    v_ab, i_ab = clarke(*v_abc), clarke(*i_abc)
    assert np.allclose(np.hypot(*v_ab), V_LL, rtol=1e-12)
    assert np.allclose(np.hypot(*i_ab), math.sqrt(3.0) * I_L, rtol=1e-12)
    p_abc = sum(v * i for v, i in zip(v_abc, i_abc))
    assert np.allclose(v_ab[0] * i_ab[0] + v_ab[1] * i_ab[1], p_abc, rtol=1e-12)
    assert np.allclose(p_abc, math.sqrt(3.0) * V_LL * I_L * math.cos(pf_angle), rtol=1e-12)
    # the motor's rating properties are the same conversion
    assert RATED.rated_voltage == pytest.approx(np.hypot(*v_ab)[0], rel=1e-12)
    assert RATED.rated_current == pytest.approx(np.hypot(*i_ab)[0], rel=1e-12)
    assert RATED.rated_current == vector_magnitude(5.0) == pytest.approx(8.660254, rel=1e-6)
    assert RATED.rated_speed == pytest.approx(1750.0 * 2 * math.pi / 60.0, rel=1e-15)
    assert RATED.rated_torque == pytest.approx(2200.0 / RATED.rated_speed, rel=1e-15)


@pytest.mark.parametrize('name', ['thesis', 'krause_3hp', 'krause_50hp'])
def test_rated_flux_is_the_models_own_steady_state_at_rated_voltage_frequency_and_speed(name):
    """
    Check the rated flux against the plant model's own steady state.

    The derived rated flux equals |Φ_r| of the plant model's phasor steady state (a formulation
    that shares no code with the inverse-Γ formula) at the rated voltage-vector magnitude, 2πf
    and the rated speed.
    """
    m = load_motor_file(os.path.join(shipped_motors_dir(), f'{name}.yaml'))
    ss = params_steady_state(m, m.rated_voltage, 2 * math.pi * m.rated_frequency, m.rated_speed)
    assert rated_flux(m) == pytest.approx(abs(ss.Phi_r), rel=1e-9)
    assert rated_flux(m.with_values(rated_flux=0.7)) == 0.7          # stated wins
    assert rated_flux(THESIS_MOTOR) is None


def test_the_ratings_are_the_drives_defaults_and_an_explicit_value_overrides():
    cfg = ControllerConfig(params=RATED, strategy='constant_flux')
    phi_n = rated_flux(RATED)
    assert (cfg.v_limit, cfg.current_limit) == (220.0, pytest.approx(math.sqrt(3.0) * 5.0))
    assert cfg.phi_d == cfg.phi_max == phi_n and cfg.phi_min == pytest.approx(phi_n / 6.0)
    assert 0.5 < phi_n < 0.6                        # not the thesis's 1.2 Wb on every motor
    assert set(cfg.from_ratings) == {'v_limit', 'current_limit', 'phi_d', 'phi_min', 'phi_max'}
    line = describe_defaults(cfg.from_ratings)
    assert "from the motor's ratings" in line
    assert 'current_limit = 8.66 (rated current 5 A RMS' in line
    # explicit values win, None is "no limit" even on a rated motor, and say nothing of ratings
    own = ControllerConfig(params=RATED, v_limit=300.0, current_limit=None, phi_d=0.5)
    assert (own.v_limit, own.current_limit, own.phi_d) == (300.0, None, 0.5)
    assert set(own.from_ratings) == {'phi_min', 'phi_max'}
    # a copy with a new value no longer claims it came from the ratings
    assert 'current_limit' not in cfg.replace(current_limit=12.0).from_ratings
    plant = PlantSimulator(RATED)
    assert plant.v_limit == 220.0
    assert plant.current_trip == pytest.approx(CURRENT_TRIP_MARGIN * math.sqrt(3.0) * 5.0)
    assert plant.speed_trip == pytest.approx(SPEED_TRIP_MARGIN * RATED.rated_speed)
    assert PlantSimulator(RATED, current_trip=None, v_limit=None).current_trip is None


def test_a_motor_without_ratings_runs_as_the_thesis_did():
    """Unset ratings: no limits, no trips, the thesis's flux levels (make reproduce unchanged)."""
    assert default_limits(THESIS_MOTOR) == {}
    cfg = ControllerConfig()
    assert (cfg.phi_d, cfg.phi_min, cfg.phi_max, cfg.v_limit, cfg.current_limit) == (
        1.2, 0.2, 1.2, None, None)
    assert cfg.from_ratings == {}
    p = PlantSimulator()
    assert (p.v_limit, p.current_trip, p.speed_trip) == (None, None, None)


def test_node_parameters_left_at_their_default_take_the_ratings_and_zero_is_none():
    """
    Check that -1 node parameters take the ratings and 0 means none.

    The controller's and plant's -1 parameters (their default) go through the same defaults;
    0 keeps meaning 'none'.
    """
    from im_controller.parameters import config_from_parameters, declare_controller
    from im_plant.parameters import declare_plant, simulator_from_parameters

    class FakeNode:

        def __init__(self, **given):
            self.given = given

        def param(self, name, default, *args, **kwargs):
            return self.given.get(name, default)

    values = declare_controller(FakeNode())
    assert values['current_limit'] == values['v_limit'] == values['phi_d'] == -1.0
    cfg = config_from_parameters(RATED, values, 1e-4)
    assert cfg.current_limit == pytest.approx(8.660254, rel=1e-6) and cfg.v_limit == 220.0
    assert config_from_parameters(THESIS_MOTOR, values, 1e-4).current_limit is None
    none = config_from_parameters(RATED, dict(values, current_limit=0.0), 1e-4)
    assert none.current_limit is None and 'current_limit' not in none.from_ratings
    with pytest.raises(ValueError, match="'current_limit' = -2.0"):
        config_from_parameters(RATED, dict(values, current_limit=-2.0), 1e-4)
    pv = declare_plant(FakeNode(motor=None))
    pv['motor'] = RATED
    sim = simulator_from_parameters(pv, 1e-4)
    assert sim.current_trip == pytest.approx(CURRENT_TRIP_MARGIN * RATED.rated_current)
    assert simulator_from_parameters(dict(pv, current_trip=0.0), 1e-4).current_trip is None


def test_min_energy_on_a_motor_rated_below_its_draw_stays_within_the_rating_by_default():
    """
    Check that min_energy stays within a small motor's rating by default.

    The user's case: the thesis's speed task with min_energy on a motor whose nameplate says
    5 A (8.66 A as a vector). Without ratings the drive draws far more; with them, by default,
    the stator current stays within the rated current, the voltage within the rated voltage,
    and the configuration says the limits came from the ratings.
    """
    from im_bringup.offline import Scenario, simulate
    unrated = simulate(Scenario(task='speed', strategy='min_energy', duration=1.0,
                                motor=THESIS_MOTOR), record_every=5)
    rated = simulate(Scenario(task='speed', strategy='min_energy', duration=1.0, motor=RATED),
                     record_every=5)
    i_unrated = np.hypot(unrated.trace['i_alpha'], unrated.trace['i_beta']).max()
    i_rated = np.hypot(rated.trace['i_alpha'], rated.trace['i_beta']).max()
    assert i_unrated > 1.3 * RATED.rated_current            # what it drew before
    assert i_rated <= RATED.rated_current * 1.02             # within the rating (2 % transients)
    assert rated.summary['trip'] is None
    cfg = Scenario(task='speed', strategy='min_energy', motor=RATED).controller_config()
    assert 'current_limit' in cfg.from_ratings


def test_an_inconsistent_nameplate_is_refused_by_name(tmp_path):
    with pytest.raises(InvalidParameter, match='rated_speed_rpm'):
        MotorParams(rated_frequency=50.0, rated_speed_rpm=1500.0)    # synchronous, 2 pole pairs
    with pytest.raises(InvalidParameter, match='rated_current_rms'):
        MotorParams(rated_current_rms=-1.0)
