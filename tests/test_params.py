"""
Motor parameters: validation, schedules, derived quantities.

A validation message names the parameter.
"""
import math

from im_common.loads import make_load
from im_common.params import (chapter4_schedule, constant, InvalidParameter, MotorParams,
                              ParameterSchedule, ramp, single_variation_schedule, sinusoid,
                              THESIS_MOTOR)
import pytest

POSITIVE = ('R_s', 'R_r', 'L_s', 'L_r', 'L_sr', 'J')
NON_NEGATIVE = ('b', 'k_e', 'k_h')
NAN, INF = float('nan'), float('inf')


# ---------------------------------------------------------------------------------------------
# Rejection of impossible values
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize('name', POSITIVE)
@pytest.mark.parametrize('value', [-1.0, 0.0, NAN, INF, -INF])
def test_positive_parameters_reject_impossible_values(name, value):
    with pytest.raises(InvalidParameter, match=f"'{name}'") as exc:
        MotorParams(**{name: value})
    assert exc.value.name == name


@pytest.mark.parametrize('name', NON_NEGATIVE)
@pytest.mark.parametrize('value', [-1e-3, NAN, INF])
def test_non_negative_parameters_reject_impossible_values(name, value):
    with pytest.raises(InvalidParameter, match=f"'{name}'") as exc:
        MotorParams(**{name: value})
    assert exc.value.name == name


@pytest.mark.parametrize('name', NON_NEGATIVE)
def test_non_negative_parameters_accept_zero(name):
    assert getattr(MotorParams(**{name: 0.0}), name) == 0.0


@pytest.mark.parametrize('value', [0, -2, 1.5, True, False, '2', None])
def test_pole_pairs_must_be_a_whole_number_at_least_one(value):
    with pytest.raises(InvalidParameter, match="'pole_pairs'"):
        MotorParams(pole_pairs=value)


def test_pole_pairs_accepts_integral_float_as_int():
    p = MotorParams(pole_pairs=3.0)
    assert p.pole_pairs == 3 and isinstance(p.pole_pairs, int)


def test_non_numeric_value_is_named():
    with pytest.raises(InvalidParameter, match="'R_s'"):
        MotorParams(R_s='abc')


@pytest.mark.parametrize('L_sr_factor', [1.0, 1.0001, 2.0])
def test_sigma_not_positive_names_L_sr(L_sr_factor):
    """σ = 1 − L_sr²/(L_s L_r) ≤ 0 when L_sr ≥ √(L_s L_r): the coupling is impossible."""
    p = THESIS_MOTOR
    L_sr = math.sqrt(p.L_s * p.L_r) * L_sr_factor
    with pytest.raises(InvalidParameter, match="'L_sr'.*sigma") as exc:
        p.with_values(L_sr=L_sr)
    assert exc.value.name == 'L_sr'


def test_with_values_validates_and_keeps_the_original():
    with pytest.raises(InvalidParameter, match="'R_r'"):
        THESIS_MOTOR.with_values(R_r=-0.1)
    assert THESIS_MOTOR.R_r == 0.842


# ---------------------------------------------------------------------------------------------
# Schedules
# ---------------------------------------------------------------------------------------------
def test_schedule_validate_catches_sigma_not_positive_at_a_time():
    """L_sr grows as a ramp until L_sr² ≥ L_s L_r: validate names L_sr and the first bad time."""
    p = THESIS_MOTOR
    L_crit = math.sqrt(p.L_s * p.L_r)
    slope = 0.01                                    # H/s
    t_bad = (L_crit - p.L_sr) / slope               # σ = 0 here (≈ 0.316 s)
    sched = ParameterSchedule(p, {'L_sr': ramp(p.L_sr, slope)}, name='bad_Lsr')
    sched.validate(0.9 * t_bad)                     # fine before it
    with pytest.raises(InvalidParameter, match="'L_sr'") as exc:
        sched.validate(1.0, samples=1001)
    assert exc.value.name == 'L_sr'
    msg = str(exc.value)
    assert 'bad_Lsr' in msg
    t_reported = float(msg.split('at t = ')[1].split(' s')[0])
    # The first grid time (step 1 ms) at or after the σ = 0 crossing.
    assert t_bad <= t_reported < t_bad + 1e-3 + 1e-9


def test_schedule_validate_catches_negative_resistance_at_a_time():
    """R_r = 0.842 − 1.0·t crosses zero at t = 0.842 s."""
    sched = ParameterSchedule(THESIS_MOTOR, {'R_r': ramp(0.842, -1.0)}, name='bad_Rr')
    sched.validate(0.8)
    with pytest.raises(InvalidParameter, match="'R_r'") as exc:
        sched.validate(2.0, samples=2001)
    assert exc.value.name == 'R_r'
    t_reported = float(str(exc.value).split('at t = ')[1].split(' s')[0])
    assert 0.842 <= t_reported <= 0.842 + 1e-3 + 1e-9


def test_schedule_validate_catches_a_sinusoid_that_dips_negative():
    sched = ParameterSchedule(THESIS_MOTOR, {'R_s': sinusoid(0.687, 1.0, math.pi)}, name='dip')
    with pytest.raises(InvalidParameter, match="'R_s'.*at t = "):
        sched.validate(2.0)


def test_chapter4_schedule_is_valid_and_follows_the_thesis_profile():
    sched = chapter4_schedule()
    sched.validate(2.0)
    for t in (0.0, 0.37, 1.0, 1.5, 2.0):
        R_s, R_r, L_s, L_r, L_sr = sched.values(t)
        s = math.sin(math.pi * t)
        assert R_s == THESIS_MOTOR.R_s
        assert math.isclose(R_r, 0.42 * t + 0.42, rel_tol=1e-14)
        assert math.isclose(L_s, 0.1 + 0.016 * s, rel_tol=1e-14)
        assert math.isclose(L_r, 0.1 + 0.016 * s, rel_tol=1e-14)
        assert math.isclose(L_sr, 0.097 + 0.016 * s, rel_tol=1e-14)
        dL_s, dL_r, dL_sr = sched.inductance_rates(t)
        c = 0.016 * math.pi * math.cos(math.pi * t)
        assert math.isclose(dL_s, c, rel_tol=1e-12, abs_tol=1e-15)
        assert math.isclose(dL_r, c, rel_tol=1e-12, abs_tol=1e-15)
        assert math.isclose(dL_sr, c, rel_tol=1e-12, abs_tol=1e-15)
    # Rates are the derivatives of the values (central difference, error O(h²)).
    h = 1e-6
    for t in (0.2, 0.9):
        num = [(a - b) / (2 * h) for a, b in zip(sched.values(t + h)[2:], sched.values(t - h)[2:])]
        for r, n in zip(sched.inductance_rates(t), num):
            assert math.isclose(r, n, rel_tol=1e-6, abs_tol=1e-9)


def test_schedule_refuses_non_electrical_variation_and_bad_variation():
    with pytest.raises(InvalidParameter, match="'J'"):
        ParameterSchedule(THESIS_MOTOR, {'J': constant(1.0)})
    with pytest.raises(ValueError, match='unknown variation kind'):
        from im_common.params import Variation
        Variation('square', 1.0)
    with pytest.raises(ValueError, match="'amplitude'"):
        sinusoid(1.0, NAN, 1.0)
    with pytest.raises(InvalidParameter, match="'b'"):
        single_variation_schedule('b', 2.0)


def test_constant_schedule_is_the_base_motor():
    sched = ParameterSchedule(THESIS_MOTOR)
    assert sched.is_constant and sched.inductances_constant
    p = THESIS_MOTOR
    assert sched.values(3.0) == (p.R_s, p.R_r, p.L_s, p.L_r, p.L_sr)
    assert sched.inductance_rates(3.0) == (0.0, 0.0, 0.0)
    s2 = single_variation_schedule('R_r', 1.5)
    assert s2.values(0.7)[1] == pytest.approx(1.5 * p.R_r, rel=1e-15)


# ---------------------------------------------------------------------------------------------
# Derived quantities (formulas of seed 000 eq. 1.113 and ch. 4, computed here)
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize('p', [THESIS_MOTOR, chapter4_schedule().params_at(0.5),
                               MotorParams(R_s=2.0, R_r=1.1, L_s=0.3, L_r=0.25, L_sr=0.26)])
def test_derived_quantities(p):
    assert p.sigma == pytest.approx(1.0 - p.L_sr ** 2 / (p.L_s * p.L_r), rel=1e-14)
    assert p.theta == pytest.approx(p.L_sr / p.L_r, rel=1e-15)
    assert p.L_M == pytest.approx(p.L_sr ** 2 / p.L_r, rel=1e-14)
    assert p.R_R == pytest.approx(p.R_r * (p.L_sr / p.L_r) ** 2, rel=1e-14)
    assert p.T_r == pytest.approx(p.L_r / p.R_r, rel=1e-15)
    assert p.v == p.pole_pairs
    # Terminal identities: σL_s + L_M = L_s (leakage + magnetizing), and 0 < σ < 1.
    assert p.sigma * p.L_s + p.L_M == pytest.approx(p.L_s, rel=1e-13)
    assert 0.0 < p.sigma < 1.0
    assert p.as_dict()['L_sr'] == p.L_sr


def test_thesis_motor_values_are_the_design_table():
    """
    Check that the defaults are the thesis motor of seed 000 §3.4.1.

    As listed in the README's parameter table.
    """
    p = THESIS_MOTOR
    assert (p.R_s, p.R_r, p.L_s, p.L_r, p.L_sr) == (0.687, 0.842, 0.08397, 0.08528, 0.08136)
    assert (p.J, p.b, p.pole_pairs, p.k_e, p.k_h) == (0.030, 0.010, 2, 0.012, 0.012)
    # Chapter 4's initial estimate θ̂ = 0.952941 is 0.081/0.085, the rounded L̂_sr/L̂_r; it is
    # within 0.2 % of θ = L_sr/L_r of the motor.
    assert 0.081 / 0.085 == pytest.approx(0.952941, abs=5e-7)
    assert p.theta == pytest.approx(0.952941, rel=2e-3)


# ---------------------------------------------------------------------------------------------
# Loads
# ---------------------------------------------------------------------------------------------
def test_make_load_unknown_kind_is_named():
    with pytest.raises(InvalidParameter, match="'load'.*'fan'|'fan'.*'load'") as exc:
        make_load('fan')
    assert exc.value.name == 'load'


@pytest.mark.parametrize('kind,kw,name', [('pendulum', {'mgl': NAN}, 'load_mgl'),
                                          ('linear', {'c1': INF}, 'load_c1'),
                                          ('linear', {'c2': NAN}, 'load_c2'),
                                          ('constant', {'tau': NAN}, 'load_tau')])
def test_make_load_non_finite_coefficient_is_named(kind, kw, name):
    with pytest.raises(InvalidParameter, match=name):
        make_load(kind, **kw)


def test_loads_follow_their_formulas():
    assert make_load('none').torque(1.0, 2.0, 3.0) == 0.0
    assert make_load('constant', tau=2.5).torque(0.0, 0.0, 0.0) == 2.5
    assert make_load('pendulum', mgl=10.0).torque(0.0, math.pi / 3, 5.0) == pytest.approx(5.0)
    assert make_load('linear', c1=1.0, c2=0.001).torque(0.0, 0.0, 135.0) == pytest.approx(1.135)


# ---------------------------------------------------------------------------------------------
# One type and range rule for every path that takes parameters (issue 23)
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize('value, default, lo, hi, needle', [
    (30, 40.0, 1e-6, 1e6, 'integer where a real number is expected; write 30.0'),
    ('abc', 40.0, None, None, 'must be a real number'),
    (True, 40.0, None, None, 'must be a real number'),
    (-5.0, 40.0, 1e-6, 1e6, 'out of range [1e-06, 1e+06]'),
    (NAN, 40.0, None, None, 'finite'),
    (2.0, 2, 1, 64, 'whole number'),
    (1, True, None, None, 'true or false'),
    (3, 'min_loss', None, None, 'string'),
])
def test_parameter_error_says_why_in_words(value, default, lo, hi, needle):
    from im_common.params import parameter_error
    assert needle in parameter_error(value, default, lo, hi)


@pytest.mark.parametrize('value, default', [(30.0, 40.0), (2, 2), (False, True), ('x', 'y'),
                                            ([1.0, 2.0], [0.0])])
def test_parameter_error_accepts_the_declared_type(value, default):
    from im_common.params import parameter_error
    assert parameter_error(value, default, 0, 100) is None


def test_motor_file_integer_for_a_real_is_refused_as_the_nodes_refuse_it(tmp_path):
    """
    Check that a motor file obeys one rule on every path.

    A motor file read by ``scenario --motor`` and the same file given to a node with
    ``--params-file`` obey one rule: ``J: 1`` is an integer where a real number is declared.
    """
    from im_common.params import load_motor_file
    p = tmp_path / 'm.yaml'
    p.write_text('/**:\n  ros__parameters:\n    R_s: 0.687\n    R_r: 0.842\n    L_s: 0.08397\n'
                 '    L_r: 0.08528\n    L_sr: 0.08136\n    pole_pairs: 2\n    J: 1\n    b: 0.01\n')
    with pytest.raises(InvalidParameter) as e:
        load_motor_file(str(p))
    assert 'J' in str(e.value) and 'write 1.0' in str(e.value) and str(p) in str(e.value)


# ---------------------------------------------------------------------------------------------
# Defaults a motor file without some fields runs with: one warning line each, once
# ---------------------------------------------------------------------------------------------
def _motor_file(path, **fields):
    from im_common.yamlio import parameters_yaml
    path.write_text(parameters_yaml({'/**': fields}))
    return str(path)


def test_a_motor_file_without_ratings_or_core_loss_says_each_default_once(tmp_path, caplog,
                                                                          monkeypatch):
    """
    Issue: such a file ran with no limits (399 V), 1.2 Wb and k_e = k_h = 0.012, silently.

    Now one warning line per default, naming the file and the field, once per process.
    """
    from im_common import params
    from im_common.params import load_motor_file, REQUIRED_MOTOR_FIELDS
    monkeypatch.setattr(params, '_WARNED', set())
    bare = {k: getattr(THESIS_MOTOR, k) for k in REQUIRED_MOTOR_FIELDS}
    path = _motor_file(tmp_path / 'bare.yaml', **bare)
    caplog.set_level('WARNING', logger='im_common.params')
    m = load_motor_file(path)
    lines = [r.getMessage() for r in caplog.records]
    assert all(r.levelname == 'WARNING' and '\n' not in r.getMessage() for r in caplog.records)
    assert [ln.split(': ')[1] for ln in lines] == [
        'no k_e', 'no k_h', 'no rated_voltage_rms_line', 'no rated_current_rms',
        'no rated_speed_rpm', 'no rated_flux (nor rated_voltage_rms_line, rated_frequency, '
        'rated_speed_rpm to derive it)']
    assert all(ln.startswith(f'{path}: ') for ln in lines)
    assert '0.012' in lines[0] and '1.2 Wb' in lines[-1]
    assert (m.k_e, m.k_h, m.rated_voltage, m.rated_current) == (0.012, 0.012, 0.0, 0.0)
    caplog.clear()
    load_motor_file(path)                           # once: not again for the same file
    assert not caplog.records
    # written out, a core-loss coefficient is the file's own (0: no core loss): no line for it;
    # with a nameplate, no limit line
    plate = {'rated_voltage_rms_line': 220.0, 'rated_current_rms': 4.9, 'rated_frequency': 60.0,
             'rated_speed_rpm': 1750.0, 'rated_power': 2200.0}
    path = _motor_file(tmp_path / 'rated.yaml', **bare, **plate, k_e=0.0, k_h=0.0)
    load_motor_file(path)
    assert not caplog.records


def test_the_shipped_motor_files_are_complete():
    import os
    from im_common.params import load_motor_file, motor_defaults, shipped_motors_dir
    from im_common.yamlio import read_yaml_file
    d = shipped_motors_dir()
    for name in sorted(os.listdir(d)):
        path = os.path.join(d, name)
        given = read_yaml_file(path, 'motor file')['/**']['ros__parameters']
        assert motor_defaults(given, load_motor_file(path)) == [], name
