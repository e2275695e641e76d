"""
The inverse-Γ parametrization (docs/adaptation.md §1, §7).

R_s, L_σ = σL_s, L_M, R_R are what the terminals determine; a model handed them in its own rotor
gauge θ is terminal-equivalent to the motor. Checked on the closed forms (round trip, gauge), on
the observer (fed the truth, it tracks the true magnetizing flux in its gauge) and on the closed
loop (the truth-fed bound).
"""
import math

from im_adapt.adaptation import AdaptationGains, ParameterAdapter
from im_common.loads import LinearLoad
from im_common.params import (CHAPTER4_ESTIMATES, estimate_arguments, IDENTIFIABLE_NAMES,
                              InvalidParameter, THESIS_MOTOR)
from im_controller.reference import ModelCoefficients
from im_observer.observer import RotorFluxObserver
from im_plant.plant_sim import PlantSimulator
import numpy as np
import pytest

P = THESIS_MOTOR


def _rescaled(m, k):
    """Return the same motor seen in another rotor gauge: L_sr→k L_sr, L_r→k² L_r, R_r→k² R_r."""
    return m.with_values(L_sr=k * m.L_sr, L_r=k * k * m.L_r, R_r=k * k * m.R_r)


def test_identifiable_parameters_are_gauge_invariant_and_round_trip():
    ident = P.identifiable()
    assert tuple(ident) == IDENTIFIABLE_NAMES
    assert ident['L_sigma'] == pytest.approx(P.sigma * P.L_s, rel=1e-12)
    for k in (0.8, 1.3):
        other = _rescaled(P, k).identifiable()
        for n in IDENTIFIABLE_NAMES:
            assert other[n] == pytest.approx(ident[n], rel=1e-12), n
    assert P.with_identifiable() is P
    again = P.with_identifiable(**ident)
    for n in ('R_s', 'R_r', 'L_s', 'L_r', 'L_sr'):
        assert getattr(again, n) == pytest.approx(getattr(P, n), rel=1e-12), n


def test_with_identifiable_keeps_the_gauge_and_takes_the_four_values():
    target = _rescaled(CHAPTER4_ESTIMATES, 1.1).identifiable()
    target['R_R'] *= 1.7
    m = P.with_identifiable(**target)
    assert m.theta == pytest.approx(P.theta, rel=1e-12)       # the gauge of P
    got = m.identifiable()
    for n in IDENTIFIABLE_NAMES:
        assert got[n] == pytest.approx(target[n], rel=1e-12), n
    only = P.with_identifiable(L_M=0.9 * P.L_M)                # one value: the others stay
    assert only.L_sigma == pytest.approx(P.L_sigma, rel=1e-12)
    assert only.R_R == pytest.approx(P.R_R, rel=1e-12) and only.R_s == P.R_s


@pytest.mark.parametrize('name,value', [('L_sigma', 0.0), ('L_M', -0.1), ('R_R', math.nan),
                                        ('R_s', math.inf)])
def test_a_bad_identifiable_value_is_named(name, value):
    with pytest.raises(InvalidParameter) as exc:
        P.with_identifiable(**{name: value})
    assert exc.value.name == name


def test_estimate_arguments_pick_the_parametrization_the_message_carries():
    pair = {'R_r': 0.9, 'theta': 0.95, 'L_M': 0.08, 'R_R': 0.8}
    assert estimate_arguments(pair) == {'R_r': 0.9, 'theta': 0.95}
    full = dict(pair, L_sigma=0.006)
    assert estimate_arguments(full) == {'L_sigma': 0.006, 'L_M': 0.08, 'R_R': 0.8}


def test_model_coefficients_follow_the_inverse_gamma_estimates():
    nominal = ModelCoefficients.from_params(P)
    same = ModelCoefficients.from_params(P, **P.identifiable())
    for f in ('R_s', 'R_r', 'L_s', 'L_r', 'L_sr'):
        assert getattr(same, f) == pytest.approx(getattr(nominal, f), rel=1e-12), f
    truth = _rescaled(CHAPTER4_ESTIMATES, 0.9)
    c = ModelCoefficients.from_params(P, **truth.identifiable())
    # what the torque constant and the flux model use: L_M = L_sr²/L_r, R_R, σL_s
    assert c.L_sr ** 2 / c.L_r == pytest.approx(truth.L_M, rel=1e-12)
    assert c.R_r * (c.L_sr / c.L_r) ** 2 == pytest.approx(truth.R_R, rel=1e-12)
    assert c.L_s - c.L_sr ** 2 / c.L_r == pytest.approx(truth.L_sigma, rel=1e-12)
    with pytest.raises(ValueError, match='either'):
        ModelCoefficients.from_params(P, R_r=0.9, L_M=0.08)
    with pytest.raises(ValueError, match="'L_r'"):
        ModelCoefficients.from_params(P, L_r=0.1)
    with pytest.raises(ValueError, match='L_sigma'):
        ModelCoefficients.from_params(P, L_sigma=-1.0)


def test_observer_fed_the_true_identifiable_parameters_tracks_the_magnetizing_flux():
    """
    A V/f-driven motor unlike the observer's model.

    Fed the truth's (R_s, L_σ, L_M, R_R), the observer's flux in its own gauge is the true φ_M
    = θ φ_r divided by its θ; left with its nominal model it is off by more than ten times as
    much.
    """
    truth = _rescaled(CHAPTER4_ESTIMATES, 1.08)        # another gauge and other values than P
    T_s = 1e-4
    runs = {}
    for fed in (True, False):
        sim = PlantSimulator(truth, LinearLoad(3.0, 0.01), T_s=T_s)
        obs = RotorFluxObserver(P)
        if fed:
            obs.set_estimates(**truth.identifiable())
        ang, err, ref = 0.0, [], []
        for k in range(8000):
            t = k * T_s
            w = 2 * math.pi * 20.0 * min(1.0, t / 0.2)
            ang += w * T_s
            mag = 6 * truth.R_s + w * 0.8
            va, vb = mag * math.cos(ang), mag * math.sin(ang)
            m = sim.measure()
            sim.step(va, vb)
            x = obs.step(T_s, va, vb, m.i_alpha, m.i_beta, m.omega_r)
            if k >= 6000:
                phi_M = truth.theta * np.array(sim.x[2:4])
                err.append(np.hypot(*(P.theta * np.array(x[2:4]) - phi_M)))
                ref.append(np.hypot(*phi_M))
        runs[fed] = max(err) / np.mean(ref)
    assert runs[True] < 1e-3
    assert runs[False] > 10 * runs[True]


def test_observer_refuses_mixed_or_unknown_estimates_naming_them():
    obs = RotorFluxObserver(P)
    with pytest.raises(InvalidParameter) as exc:
        obs.set_estimates(R_r=0.9, L_M=0.08)
    assert exc.value.name == 'R_r'
    with pytest.raises(InvalidParameter) as exc:
        obs.set_estimates(L_r=0.1)
    assert exc.value.name == 'L_r'
    with pytest.raises(InvalidParameter) as exc:
        obs.set_estimates(L_M=float('nan'))
    assert exc.value.name == 'L_M'


def test_the_adapters_feed_decides_what_the_controller_takes():
    pair = ParameterAdapter(CHAPTER4_ESTIMATES, AdaptationGains(feed='thesis_pair'),
                            0.842, 0.952941)
    assert 'L_sigma' not in pair.estimates()
    assert AdaptationGains(law='thesis').feed == 'thesis_pair'          # 'auto', thesis law
    ig = ParameterAdapter(CHAPTER4_ESTIMATES, AdaptationGains(), 0.842, 0.952941)
    assert ig.gains.feed == 'inverse_gamma'                            # 'auto', improved law
    e = ig.estimates()
    assert e['L_sigma'] == pytest.approx(CHAPTER4_ESTIMATES.L_sigma, rel=1e-6)
    assert set(estimate_arguments(e)) == {'L_sigma', 'L_M', 'R_R'}
    for bad in ({'feed': 'everything'}, {'feed': 'inverse_gamma', 'law': 'thesis'}):
        with pytest.raises(InvalidParameter) as exc:
            AdaptationGains(**bad)
        assert exc.value.name == 'feed'
