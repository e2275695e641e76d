"""
The loss-optimal rotor-flux trajectory for a torque known ahead.

A convex program (docs/controller.md §10, "Loss-optimal flux trajectory").

In the rotor-flux frame (d along φ_r, magnitude φ ≥ 0) a torque τ(t) delivered exactly fixes the
q-currents, and the flux trajectory fixes the d-currents:

    i_ds = (φ + T_r φ̇)/L_sr,  i_qs = L_r τ/(v L_sr φ),  i_dr = −φ̇/R_r,  i_qr = −τ/(v φ).

The plant's loss books (im_common.model) count R_s|i_s|² + R_r|i_r|² (copper) and the core loss
(k_h + k_e f_e) f_e (θφ)², f_e = |v ω + R_r τ/(v φ²)|/2π (exponent 2, the project's default).
In the variable y = φ² (φ̇ = ẏ/(2√y)) every term is convex in (y, ẏ):

    p(y, ẏ) = ‖w(y, ẏ)‖²/y + k_h θ²|v ω y + R_r τ/v|/2π,
    w = ( √R_s (y + T_r ẏ/2)/L_sr,  ẏ/(2√R_r),  √C τ,  θ √k_e (v ω y + R_r τ/v)/2π ),
    C = (R_s L_r²/L_sr² + R_r)/v²,

a quadratic-over-linear (a rotated second-order cone) plus the absolute value of an affine
function. The current limit i_ds² + i_qs² ≤ I² is (y + T_r ẏ/2)² + (L_r τ/v)² ≤ I² L_sr² y, again
a rotated cone; a flux cap (saturation, the voltage limit's field weakening) is y ≤ φ_cap². So
the minimum of ∫p dt over all flux trajectories from the start flux is a second-order-cone
program: direct transcription on a grid t_0 < … < t_N, y on the nodes, ẏ by the difference and
y, τ, ω at the interval's midpoint (midpoint rule, second order). It is solved with cvxpy and
Clarabel (pinned in requirements.txt).

ROS-free; :class:`FluxPlan` samples the planned φ, φ̇, φ̈ for the reference model (a C² cubic
spline through the nodes' √y).
"""
from __future__ import annotations

import bisect
from dataclasses import dataclass, field
import math
import time
from typing import Callable, Optional, Sequence
import warnings

import numpy as np

from .reference import ModelCoefficients

TWO_PI = 2.0 * math.pi
# the grid of the controller's plan [s]: T_r/100 for the thesis motor; the losses change by
# < 1e-5 relative from 4 ms to 0.5 ms on the thesis tasks (tests/test_flux_plan.py)
PLAN_STEP = 1e-3


class PlanError(RuntimeError):
    """The convex program has no solution (a limit the torque cannot meet) or the solver failed."""


def loss_constants(c: ModelCoefficients, k_e: float = 0.0, k_h: float = 0.0) -> dict:
    """Return the coefficients of the loss rate in y = φ² (module docstring)."""
    th = c.theta
    return {'A': c.R_s / (c.L_sr * c.L_sr),
            'C': (c.R_s * c.L_r * c.L_r / (c.L_sr * c.L_sr) + c.R_r) / (c.v * c.v),
            'Te': th * th * k_e / (TWO_PI * TWO_PI), 'Th': th * th * k_h / TWO_PI}


def loss_rates(c: ModelCoefficients, y, ydot, tau, omega, k_e: float = 0.0, k_h: float = 0.0,
               sat=None):
    """
    (copper, core) loss rates [W] at y = φ², ẏ, τ, ω (arrays; y > 0 where τ ≠ 0).

    ``sat``: the magnetizing curve as (b, S) of :func:`saturation_terms` (None: linear).
    """
    y = np.asarray(y, float)
    ydot = np.asarray(ydot, float)
    tau = np.asarray(tau, float)
    omega = np.asarray(omega, float)
    k = loss_constants(c, k_e, k_h)
    with np.errstate(divide='ignore', invalid='ignore'):
        inv = np.where(y > 0.0, 1.0 / np.where(y > 0.0, y, 1.0), 0.0)
        drive = y + 0.5 * c.T_r * ydot
        if sat is not None:
            drive = drive + sat[0] * np.maximum(y, 0.0) ** (0.5 * sat[1] + 1.0)
        copper = (k['A'] * drive * drive + ydot * ydot / (4.0 * c.R_r) + k['C'] * tau * tau) * inv
        rot = c.v * omega * y + c.R_r * tau / c.v           # 2π f_e y (signed)
        core = k['Te'] * rot * rot * inv + k['Th'] * np.abs(rot)
    return copper, core


def saturation_terms(c: ModelCoefficients, curve) -> tuple:
    """
    Return (b, S) of a power-law magnetizing curve in the plan's variable y = φ² (φ = ψ_R/θ).

    With L_M(ψ) = L_M0/(1 + (βψ)^S) the stator d-current is i_ds = (φ(1 + b φ^S) + T_r φ̇)/L_sr,
    b = (βθ)^S, so L_sr i_ds √y = y + b y^(S/2+1) + T_r ẏ/2: the linear drive term plus a convex
    power of y (docs/controller.md §10). A table curve (what commissioning writes) is fitted:
    g(φ) = L_sr i_d(φ)/φ at its points, log(g − 1) = log b + S log φ by least squares over
    the points where it saturates (g > 1); b = 0 (linear) when fewer than two do — the convex
    program needs a power (the causal min_loss takes the table itself, :func:`curve_shape`).
    """
    if getattr(curve, 'table', None) is None:
        return (curve.beta * c.theta) ** curve.S, curve.S
    g = curve_shape(c, curve)
    pts = [(math.log(psi / c.theta), math.log(g(psi / c.theta) - 1.0))
           for psi in curve.table[0][1:] if g(psi / c.theta) > 1.0 + 1e-9]
    if len(pts) < 2:
        return 0.0, 2.0
    n = len(pts)
    mx = sum(x for x, _ in pts) / n
    my = sum(y for _, y in pts) / n
    sxx = sum((x - mx) ** 2 for x, _ in pts)
    S = sum((x - mx) * (y - my) for x, y in pts) / sxx if sxx > 0.0 else 2.0
    if not S > 0.0:
        return 0.0, 2.0
    return math.exp(my - S * mx), S


def curve_shape(c: ModelCoefficients, curve):
    """
    Return the curve's shape for the causal min_loss: (b, S) of a power law, or g(φ) of a table.

    g(φ) = L_sr i_d(φ)/φ with the steady d-current i_d(φ) = i_M(θφ) of the curve (1 + bφ^S for
    the power law; any positive function for a table, whose slope at the origin need not be the
    model's 1/L_M0): the stator copper on the curve is R_s (φ g(φ)/L_sr)².
    """
    if getattr(curve, 'table', None) is None:
        return saturation_terms(c, curve)
    th, L_sr = c.theta, c.L_sr

    def g(phi: float) -> float:
        return L_sr * th * curve.inv_L(th * phi)
    return g


def static_loss_optimal_flux(c: ModelCoefficients, tau: float, omega: float, k_e: float = 0.0,
                             k_h: float = 0.0) -> float:
    """
    Return the flux minimizing the steady loss at a constant τ, ω.

    It minimizes p(y, 0) (the closed form of dp/dy
    = 0 on the side where v ω y + R_r τ/v has the sign of ω, exponent 2):

        y² = (C τ² + T_e c²)/(A + T_e v²ω² + T_h v|ω|),   c = R_r τ/v,

    exact (∂f_e/∂φ included) whenever the rotation v ω y + c keeps ω's sign at that y (always
    when τ and ω have the same sign, or ω = 0).
    """
    k = loss_constants(c, k_e, k_h)
    cc = c.R_r * tau / c.v
    vw = c.v * omega
    y2 = ((k['C'] * tau * tau + k['Te'] * cc * cc)
          / (k['A'] + k['Te'] * vw * vw + k['Th'] * abs(vw)))
    if omega == 0.0:   # p = (A y² + Cτ² + T_e c²)/y + T_h |c|: the hysteresis part is constant
        y2 = (k['C'] * tau * tau + k['Te'] * cc * cc) / k['A']
    return math.sqrt(math.sqrt(y2))


@dataclass
class FluxPlan:
    """A solved plan: nodes ``t``, ``y`` = φ² at the nodes, its losses and how it was found."""

    t: np.ndarray
    y: np.ndarray
    copper_J: float
    core_J: float
    solve_s: float
    status: str
    current_limit_active: bool = False
    torque_shortfall: float = 0.0       # ∫|τ demanded − τ planned| dt [N·m·s] the limits forbid
    flux_cap_active: bool = False
    _spline: object = field(default=None, repr=False)

    @property
    def loss_J(self) -> float:
        return self.copper_J + self.core_J

    @property
    def phi(self) -> np.ndarray:
        return np.sqrt(np.maximum(self.y, 0.0))

    def sample(self, t: float):
        """
        (φ, φ̇, φ̈) of the plan at t.

        A C² cubic spline through the nodes' φ (natural ends), evaluated in plain Python (a
        few µs per call); before the first node the first value, beyond the last node the
        last value, both with zero rates.
        """
        if self._spline is None:
            from scipy.interpolate import CubicSpline  # heavy: scipy only for a spline plan
            sp = CubicSpline(self.t, self.phi, bc_type='natural')
            self._spline = (self.t.tolist(), sp.c.T.tolist())
        x, coef = self._spline
        if t >= x[-1]:
            return float(self.phi[-1]), 0.0, 0.0
        if t <= x[0]:
            return float(self.phi[0]), 0.0, 0.0
        k = bisect.bisect_right(x, t) - 1
        a3, a2, a1, a0 = coef[k]
        d = t - x[k]
        return (((a3 * d + a2) * d + a1) * d + a0, (3.0 * a3 * d + 2.0 * a2) * d + a1,
                6.0 * a3 * d + 2.0 * a2)

    @property
    def end(self) -> float:
        return float(self.t[-1])


def plan_flux(c: ModelCoefficients, t: Sequence[float], tau_mid: Sequence[float],
              omega_mid: Sequence[float], phi0: float, *, k_e: float = 0.0, k_h: float = 0.0,
              phi_end: Optional[float] = None, phi_cap: Optional[Sequence[float]] = None,
              i_max: Optional[float] = None, sat=None) -> FluxPlan:
    """
    Plan the loss-optimal flux trajectory for given torques and speeds on a grid.

    Minimize the losses (copper, plus the core loss when k_e or k_h > 0) over every flux trajectory
    on the grid ``t`` (N+1 nodes) that delivers the torques ``tau_mid`` at the speeds ``omega_mid``
    (N interval midpoints), from φ(t_0) = ``phi0``; the end flux is free unless ``phi_end``.
    ``phi_cap`` (a number or N+1 node values) bounds φ; ``i_max`` bounds the stator current. Where
    the limits make the exact torque impossible, the program is re-solved delivering as much of it
    as they allow (``torque_shortfall``). ``sat``: the motor's magnetizing curve as (b, S) of
    :func:`saturation_terms` (None: the linear model). Raises :class:`PlanError` when no solution
    is found.
    """
    t = np.asarray(t, float)
    tau = np.asarray(tau_mid, float)
    om = np.asarray(omega_mid, float)
    n = len(t) - 1
    if n < 1 or tau.shape != (n,) or om.shape != (n,) or not np.all(np.diff(t) > 0.0):
        raise ValueError('plan_flux: t must increase and tau_mid, omega_mid have one value per '
                         'interval')
    if not (math.isfinite(phi0) and phi0 >= 0.0):
        raise ValueError(f'plan_flux: start flux phi0 = {phi0!r} must be >= 0')
    h = np.diff(t)
    cap = None
    if phi_cap is not None:
        cap = np.array(np.broadcast_to(np.asarray(phi_cap, float), (n + 1,)))
    try:
        plan = _solve(c, t, h, tau, om, phi0, k_e, k_h, phi_end, cap, i_max, True, sat)
    except PlanError:
        if i_max is None and cap is None:
            raise
        # the limits leave part of the torque undeliverable (a load on a demagnetized machine,
        # a torque beyond the current limit): re-solve delivering as much of it as they allow
        plan = _solve(c, t, h, tau, om, phi0, k_e, k_h, phi_end, cap, i_max, False, sat)
    return plan


def _solve(c, t, h, tau_ref, om, phi0, k_e, k_h, phi_end, cap, i_max, exact: bool,
           sat=None) -> FluxPlan:
    """
    One second-order-cone program of :func:`plan_flux`.

    ``exact``: the torque is delivered exactly; else it is a variable between 0 and the demand
    (same sign) whose shortfall costs 1000 × the least steady copper loss per N·m (2√(AC)), so
    every achievable torque is delivered. ``sat`` (b, S): the drive term gets b y^(S/2+1) through
    an epigraph variable u ≥ drive + b y_m^(S/2+1) (a relaxation where the d-current would be
    negative; exact elsewhere, and the books below are the exact ones).
    """
    import cvxpy as cp  # heavy: cvxpy only when a flux plan is solved
    n = len(h)
    k = loss_constants(c, k_e, k_h)
    y = cp.Variable(n + 1, nonneg=True)
    s = cp.Variable(n)                       # epigraph of ‖w‖²/y_m per interval
    ym = 0.5 * (y[:-1] + y[1:])
    yd = cp.multiply(1.0 / h, y[1:] - y[:-1])
    drive = ym + 0.5 * c.T_r * yd
    cons = [y[0] == phi0 * phi0]
    if sat is not None:
        u = cp.Variable(n)
        cons.append(u >= drive + sat[0] * cp.power(ym, 0.5 * sat[1] + 1.0))
        drive = u
    tau, mag, penalty = _delivered_torque(tau_ref, h, k, exact, cons)
    rows = [math.sqrt(k['A']) * drive, yd / (2.0 * math.sqrt(c.R_r)), math.sqrt(k['C']) * tau]
    rot = cp.multiply(c.v * om, ym) + (c.R_r / c.v) * tau
    core = k['Te'] > 0.0 or k['Th'] > 0.0
    if k['Te'] > 0.0:
        rows.append(math.sqrt(k['Te']) * rot)
    w = cp.vstack(rows)
    # ‖w‖² ≤ s·y_m  ⇔  ‖(2w, s − y_m)‖ ≤ s + y_m
    cons.append(cp.SOC(s + ym, cp.vstack([2.0 * w, cp.reshape(s - ym, (1, n), order='C')]),
                       axis=0))
    cost = s
    if k['Th'] > 0.0:
        cost = cost + k['Th'] * cp.abs(rot)
    if phi_end is not None:
        cons.append(y[-1] == phi_end * phi_end)
    _limit_constraints(c, y, ym, drive, tau, cap, i_max, cons)
    prob = cp.Problem(cp.Minimize(h @ cost + penalty), cons)
    solve_s = _run_solver(prob)
    if prob.status not in ('optimal', 'optimal_inaccurate') or y.value is None:
        raise PlanError(f'flux plan: no flux trajectory delivers the torque within the limits '
                        f'(solver status {prob.status})')
    tau_v = np.asarray(tau_ref if exact else np.sign(tau_ref) * mag.value, float)
    yv = np.maximum(np.asarray(y.value, float), 0.0)
    yv[0] = phi0 * phi0
    ymv = 0.5 * (yv[:-1] + yv[1:])
    ydv = np.diff(yv) / h
    cu, co = loss_rates(c, ymv, ydv, tau_v, om, k_e, k_h, sat)
    plan = FluxPlan(t=t, y=yv, copper_J=float(h @ cu), core_J=float(h @ co) if core else 0.0,
                    solve_s=solve_s, status=prob.status,
                    torque_shortfall=float(h @ np.abs(tau_ref - tau_v)))
    _mark_active_limits(plan, c, yv, ymv, ydv, tau_v, cap, i_max, sat)
    return plan


def _delivered_torque(tau_ref, h, k: dict, exact: bool, cons: list):
    """
    Return (τ, mag, penalty): the torque the program delivers, per interval.

    ``exact``: τ = ``tau_ref`` (mag None, penalty 0). Else a variable mag (appended to
    ``cons``: 0 ≤ mag ≤ |τ_ref|) of the demand's sign, whose shortfall costs 1000 × the least
    steady copper loss per N·m (2√(AC)) over the grid's intervals ``h``.
    """
    import cvxpy as cp  # heavy: cvxpy only when a flux plan is solved
    if exact:
        return cp.Constant(tau_ref), None, 0.0
    mag = cp.Variable(len(h), nonneg=True)
    cons.append(mag <= np.abs(tau_ref))
    tau = cp.multiply(np.sign(tau_ref), mag)
    penalty = 2e3 * math.sqrt(k['A'] * k['C']) * (h @ (np.abs(tau_ref) - mag))
    return tau, mag, penalty


def _limit_constraints(c, y, ym, drive, tau, cap, i_max, cons: list) -> None:
    """Append the flux cap (y ≤ cap² at its finite nodes) and the current limit to ``cons``."""
    import cvxpy as cp  # heavy: cvxpy only when a flux plan is solved
    n = ym.shape[0]
    if cap is not None:
        idx = np.nonzero(np.isfinite(cap))[0]
        if len(idx):
            cons.append(y[idx] <= cap[idx] ** 2)
    if i_max is not None:
        q = (i_max * c.L_sr) ** 2
        g = (c.L_r / c.v) * tau
        # (y_m + T_r ẏ/2)² + (L_r τ/v)² ≤ q y_m  ⇔  ‖(2 drive, 2 L_r τ/v, y_m − q)‖ ≤ y_m + q
        cons.append(cp.SOC(ym + q, cp.vstack([2.0 * cp.reshape(drive, (1, n), order='C'),
                                              2.0 * cp.reshape(g, (1, n), order='C'),
                                              cp.reshape(ym - q, (1, n), order='C')]), axis=0))


def _run_solver(prob) -> float:
    """Solve ``prob`` with Clarabel; return the solve's wall time [s]; PlanError if it fails."""
    import cvxpy as cp  # heavy: cvxpy only when a flux plan is solved
    t0 = time.perf_counter()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter('ignore')          # the status says it: 'optimal_inaccurate'
            prob.solve(solver=cp.CLARABEL)
    except cp.error.SolverError as exc:
        raise PlanError(f'flux plan: the solver failed ({exc})') from None
    return time.perf_counter() - t0


def _mark_active_limits(plan: FluxPlan, c, yv, ymv, ydv, tau_v, cap, i_max, sat) -> None:
    """Set ``plan``'s current_limit_active / flux_cap_active: the solution within 1e-4 of them."""
    if i_max is not None:
        dv = ymv + 0.5 * c.T_r * ydv
        if sat is not None:
            dv = dv + sat[0] * ymv ** (0.5 * sat[1] + 1.0)
        i2 = (dv ** 2 + (c.L_r * tau_v / c.v) ** 2) / (c.L_sr ** 2 * np.maximum(ymv, 1e-300))
        plan.current_limit_active = bool(np.max(i2) > (1.0 - 1e-4) * i_max * i_max)
    if cap is not None:
        plan.flux_cap_active = bool(np.any(yv > (1.0 - 1e-4) * cap * cap))


def grid(t0: float, t1: float, step: float) -> np.ndarray:
    """Nodes from t0 to t1 with intervals of at most ``step``."""
    n = max(1, int(math.ceil((t1 - t0) / step - 1e-9)))
    return np.linspace(t0, t1, n + 1)


def plan_along(c: ModelCoefficients, path: Callable[[float], tuple], t0: float, t1: float,
               phi0: float, step: float = 1e-3, **kwargs) -> FluxPlan:
    """
    Plan the flux along a path of torque and speed.

    :func:`plan_flux` for a path ``path(t) -> (τ, ω)`` sampled at the midpoints of a grid of
    ``step`` from t0 to t1.
    """
    t = grid(t0, t1, step)
    mid = 0.5 * (t[:-1] + t[1:])
    tau, om = np.array([path(x) for x in mid], float).T
    return plan_flux(c, t, tau, om, phi0, **kwargs)
