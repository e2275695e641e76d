"""
The loss-optimal flux trajectory (im_controller.flux_plan).

The convex program against closed forms, its discretisation by refinement, and the limits as
constraints.
"""
import math

from im_common.params import THESIS_MOTOR as M
from im_controller.flux import flux_min_loss
from im_controller.flux_plan import (FluxPlan, grid, loss_rates, plan_along, plan_flux,
                                     static_loss_optimal_flux)
from im_controller.reference import ModelCoefficients, steady_losses
import numpy as np
import pytest

C = ModelCoefficients.from_params(M)


@pytest.mark.parametrize('tau,omega', [(5.0, 100.0), (-5.88, 0.0), (2.5, 180.0), (-3.0, -50.0)])
def test_static_closed_form_minimizes_the_models_steady_loss(tau, omega):
    """
    dp/dy = 0 in closed form.

    The brute-force minimum of reference.steady_losses (the project's own steady loss, copper +
    core with f_e from the slip) over a fine flux grid.
    """
    phi = static_loss_optimal_flux(C, tau, omega, M.k_e, M.k_h)
    grid_ = np.linspace(0.05, 1.5, 290001)
    losses = [steady_losses(C, tau, p, omega, M.k_e, M.k_h) for p in grid_]
    best = grid_[int(np.argmin(losses))]
    assert phi == pytest.approx(best, abs=1e-5)
    # min_loss's map ignores ∂f_e/∂φ: its loss is within 0.1 % of the exact optimum's
    approx = flux_min_loss(C, tau, omega, 0.0, 10.0, M.k_e, M.k_h)
    best_loss = steady_losses(C, tau, phi, omega, M.k_e, M.k_h)
    assert best_loss <= steady_losses(C, tau, approx, omega, M.k_e, M.k_h) <= 1.001 * best_loss


@pytest.mark.parametrize('core', [False, True])
def test_a_constant_torque_held_long_is_planned_at_the_static_optimum(core):
    """
    Constant τ, ω over 4 s from a far-off start flux, end free.

    Away from both ends the optimal trajectory sits on the static loss-optimal flux (the closed
    form).
    """
    tau, omega = 5.0, 100.0
    k = {'k_e': M.k_e, 'k_h': M.k_h} if core else {}
    plan = plan_along(C, lambda t: (tau, omega), 0.0, 4.0, 1.0, 2e-3, **k)
    expect = static_loss_optimal_flux(C, tau, omega, **k)
    phi_mid = plan.sample(2.0)[0]
    assert phi_mid == pytest.approx(expect, rel=1e-4)
    assert abs(plan.phi[0] - expect) > 0.3        # it did have to move there
    # the plan's losses are its own books: the rates integrated along its trajectory
    h = np.diff(plan.t)
    ym = 0.5 * (plan.y[1:] + plan.y[:-1])
    cu, co = loss_rates(C, ym, np.diff(plan.y) / h, np.full(len(h), tau), np.full(len(h), omega),
                        **k)
    assert plan.loss_J == pytest.approx(h @ (cu + co), rel=1e-12)
    # and it is below holding the start flux or jumping to the optimum
    steady = steady_losses(C, tau, expect, omega, *(M.k_e, M.k_h) if core else (0.0, 0.0))
    assert plan.loss_J < 4.0 * steady + 1.0


def _pendulum_like(t):
    """Return a smooth (C¹) torque through zero and back to a hold, with speed: a position move."""
    s = max(0.0, t - 0.3)
    return (30.0 * s * s * math.exp(-4.0 * s) * math.cos(3.0 * s)
            - 2.0 * (1.0 - math.exp(-5.0 * s * s)), 20.0 * s * s * math.exp(-3.0 * s))


@pytest.mark.parametrize('phi0,rate', [(0.3, 0.35), (0.0, 0.7)])
def test_the_discretisation_converges_under_refinement(phi0, rate):
    """
    Halving the grid.

    The midpoint rule converges at second order from a magnetized start (the change shrinks ≈
    4×); from a demagnetized one, where φ = √y leaves 0 with a kink, more slowly, still
    monotonically, and at 1 ms both are within 1e-6 of the limit's scale.
    """
    costs = [plan_along(C, _pendulum_like, 0.0, 1.5, phi0, h, k_e=M.k_e, k_h=M.k_h).loss_J
             for h in (8e-3, 4e-3, 2e-3, 1e-3)]
    diffs = np.abs(np.diff(costs))
    assert np.all(diffs[1:] < diffs[:-1] * rate)
    assert diffs[-1] < 1e-6 * costs[-1]


def test_a_tight_current_limit_becomes_a_constraint_of_the_plan():
    free = plan_along(C, _pendulum_like, 0.0, 1.5, 0.0, 2e-3)
    t = free.t
    mid = 0.5 * (t[1:] + t[:-1])
    tau = np.array([_pendulum_like(x)[0] for x in mid])
    om = np.array([_pendulum_like(x)[1] for x in mid])

    def peak_current(plan: FluxPlan) -> float:
        ym = 0.5 * (plan.y[1:] + plan.y[:-1])
        yd = np.diff(plan.y) / np.diff(plan.t)
        i2 = ((ym + 0.5 * C.T_r * yd) ** 2 + (C.L_r * tau / C.v) ** 2) / (C.L_sr ** 2 * ym)
        return math.sqrt(i2.max())

    peak = peak_current(free)
    loose = plan_flux(C, t, tau, om, 0.0, i_max=1.5 * peak)
    assert not loose.current_limit_active and loose.loss_J == pytest.approx(free.loss_J, rel=1e-6)
    tight = plan_flux(C, t, tau, om, 0.0, i_max=0.95 * peak)
    assert tight.current_limit_active and tight.torque_shortfall == 0.0
    assert peak_current(tight) <= 0.95 * peak * (1 + 1e-6)
    assert tight.loss_J > free.loss_J
    # a torque on a demagnetized machine at t = 0 is beyond any current: the plan delivers what
    # the limit allows (and says how much it could not)
    short = plan_flux(C, grid(0.0, 0.5, 1e-3), np.full(500, 4.0), np.zeros(500), 0.0, i_max=8.0)
    assert short.torque_shortfall > 0.0
    with pytest.raises(Exception):
        plan_flux(C, grid(0.0, 0.5, 1e-3), np.full(500, 4.0), np.zeros(500), 0.0,
                  phi_end=0.5, phi_cap=0.3)      # an end above the cap: no solution at all


def test_the_flux_cap_is_respected():
    plan = plan_along(C, lambda t: (8.0, 50.0), 0.0, 1.0, 0.2, 2e-3, phi_cap=0.5)
    assert plan.flux_cap_active and plan.phi.max() <= 0.5 * (1 + 1e-6)


def test_sample_is_the_plan_and_smooth():
    plan = plan_along(C, _pendulum_like, 0.0, 1.5, 0.3, 1e-3, k_e=M.k_e, k_h=M.k_h)
    for j in (0, 1, 400, 777, 1499):
        assert plan.sample(plan.t[j])[0] == pytest.approx(plan.phi[j], abs=1e-12)
    # φ̇ and φ̈ are the derivatives of φ (central differences)
    for t in (0.45, 0.8, 1.2):
        e = 1e-6
        p0, d0, a0 = plan.sample(t)
        assert d0 == pytest.approx((plan.sample(t + e)[0] - plan.sample(t - e)[0]) / (2 * e),
                                   rel=1e-5, abs=1e-8)
        assert a0 == pytest.approx((plan.sample(t + e)[1] - plan.sample(t - e)[1]) / (2 * e),
                                   rel=1e-4, abs=1e-6)
    assert plan.sample(10.0) == (plan.phi[-1], 0.0, 0.0)


def test_bad_input_is_named():
    with pytest.raises(ValueError, match='phi0'):
        plan_flux(C, [0.0, 1.0], [1.0], [0.0], -0.1)
    with pytest.raises(ValueError, match='one value per interval'):
        plan_flux(C, [0.0, 1.0, 2.0], [1.0], [0.0], 0.1)
