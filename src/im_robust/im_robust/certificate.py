"""
Independent certificates for a static output-feedback gain.

A gain G is *certified* for an uncertain system when a single P = P' ≻ 0 satisfies, in the original
coordinates and with the thesis's sign convention A_cl = A − B G C (seed 001 eq. 3.3-3.4),

    continuous:  A_cl' P + P A_cl ⪯ −2 α_c P   with α_c > α   at every vertex model
    discrete:    A_cl' P A_cl     ⪯  ρ_c² P    with ρ_c < ρ   at every vertex model

checked with numpy eigenvalues (not by trusting a solver's status). α_c is the guaranteed decay
rate of V = x'Px (1/s), ρ_c the guaranteed contraction per step. By convexity (eq. 2.22 and Lemma
2.3.1), this holds on the convex hull of the vertex models. The same P is then checked on a dense
grid of the uncertain parameters, together with the eigenvalues of every grid model: for models
that are not affine in the parameters (a sampled motor model) the grid check is what ties the
vertices to the physical parameter box — it is evidence, not proof, between grid points.

P comes from the synthesis (P = W₁⁻¹) when that passes; otherwise from a fresh analysis SDP that
only sees G and the vertex models.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import List, Optional, Sequence

import numpy as np

from .polytope import Model, UncertainSystem


@dataclass
class Certificate:
    """
    Outcome of :func:`certify`.

    ``margin`` is α_c − α (continuous, 1/s) or ρ − ρ_c (discrete); ``rate`` is α_c or ρ_c.
    ``grid_margin`` is the same quantity over the dense grid with the same P, and
    ``grid_worst_eig`` the largest real part (continuous) or modulus (discrete) of the closed-loop
    eigenvalues there.
    """

    certified: bool
    discrete: bool
    rate: float
    margin: float
    P: Optional[np.ndarray]
    P_source: str
    vertex_rates: List[float] = field(default_factory=list)
    grid_points: int = 0
    grid_margin: Optional[float] = None
    grid_worst_eig: Optional[float] = None
    reason: str = ''

    def summary(self) -> dict:
        return {'certified': bool(self.certified), 'discrete': self.discrete,
                'rate': float(self.rate), 'margin': float(self.margin), 'P_source': self.P_source,
                'P_condition': None if self.P is None else float(np.linalg.cond(self.P)),
                'grid_points': int(self.grid_points),
                'grid_margin': None if self.grid_margin is None else float(self.grid_margin),
                'grid_worst_eig': (None if self.grid_worst_eig is None
                                   else float(self.grid_worst_eig)),
                'reason': self.reason}


def _sym_sqrt_and_inv(P: np.ndarray):
    w, V = np.linalg.eigh(0.5 * (P + P.T))
    if w.min() <= 0 or not np.all(np.isfinite(w)):
        return None, None
    return (V * np.sqrt(w)) @ V.T, (V / np.sqrt(w)) @ V.T


def lyapunov_rates(closed_loops: Sequence[np.ndarray], P: np.ndarray,
                   discrete: bool) -> np.ndarray:
    """Per-model α_c (continuous) or ρ_c (discrete) for the quadratic function x'Px."""
    Ph, Pih = _sym_sqrt_and_inv(P)
    if Ph is None:
        return np.full(len(closed_loops), np.nan)
    out = []
    for Acl in closed_loops:
        M = Ph @ Acl @ Pih
        if discrete:
            out.append(np.linalg.norm(M, 2))
        else:
            out.append(-np.linalg.eigvalsh(0.5 * (M + M.T)).max())
    return np.array(out)


def _worst(rates: np.ndarray, discrete: bool) -> float:
    if rates.size == 0 or not np.all(np.isfinite(rates)):
        return np.inf if discrete else -np.inf
    return float(rates.max() if discrete else rates.min())


def _margin(rate: float, discrete: bool, alpha: float, rho: float) -> float:
    return (rho - rate) if discrete else (rate - alpha)


def analysis_lmi(closed_loops: Sequence[np.ndarray], discrete: bool, alpha: float = 0.0,
                 rho: float = 1.0, solver: str = 'CLARABEL') -> Optional[np.ndarray]:
    """
    Return a common P for the closed loops at the required rate, or None (fresh SDP, G only).

    Minimizes the condition number bound s of I ⪯ P ⪯ s I subject to the Lyapunov inequalities with
    a unit margin (the problem is homogeneous in P, so the margin only fixes the scale).
    """
    import cvxpy as cp  # heavy: cvxpy only when an LMI is solved
    n = closed_loops[0].shape[0]
    P = cp.Variable((n, n), symmetric=True)
    s = cp.Variable()
    I = np.eye(n)  # noqa: E741 (the identity matrix, as in the equations)
    cons = [P >> I, P << s * I]
    for Acl in closed_loops:
        if discrete:
            Ar = Acl / rho
            cons.append(cp.bmat([[P - 1e-6 * I, Ar.T @ P], [P @ Ar, P]]) >> 0)
        else:
            Aa = Acl + alpha * I
            cons.append(Aa.T @ P + P @ Aa << -1e-3 * I)
    prob = cp.Problem(cp.Minimize(s), cons)
    try:
        prob.solve(solver=solver)
    except Exception:  # solver failure is a non-certificate, not a crash
        return None
    if P.value is None or prob.status not in ('optimal', 'optimal_inaccurate'):
        return None
    return 0.5 * (P.value + P.value.T)


def certify(system: UncertainSystem, G, *, alpha: float = 0.0, rho: float = 1.0,
            P: Optional[np.ndarray] = None, grid_models: Optional[Sequence[Model]] = None,
            tol: float = 1e-9, max_condition: float = 1e12) -> Certificate:
    """
    Check G on every vertex model with a common P, then on ``grid_models`` with the same P.

    Parameters
    ----------
    system : UncertainSystem
        Vertex models, output matrix C, time domain.
    G : (m, r) array
        Gain of u = −G y.
    alpha, rho : float
        Required decay rate (continuous, 1/s) or contraction bound (discrete).
    P : array, optional
        Candidate Lyapunov matrix (e.g. from the synthesis); if it fails, a fresh analysis SDP is
        tried.
    grid_models : sequence of (A, B), optional
        Dense-grid models checked with the same P and by their eigenvalues.
    tol : float
        Required strict margin (relative to 1 for discrete; in 1/s for continuous).
    max_condition : float
        Largest condition number of P accepted.

    """
    G = np.atleast_2d(np.asarray(G, dtype=float))
    if G.shape != (system.m, system.r):
        raise ValueError(f'G has shape {G.shape}, expected ({system.m}, {system.r})')
    if not np.all(np.isfinite(G)):
        return Certificate(False, system.discrete, np.nan, -np.inf, None, 'none',
                           reason='G contains NaN or inf')
    d = system.discrete
    loops = system.closed_loops(G)

    def attempt(Pc, source):
        if Pc is None:
            return None
        Pc = 0.5 * (Pc + Pc.T)
        if not np.all(np.isfinite(Pc)):
            return None
        w = np.linalg.eigvalsh(Pc)
        if w.min() <= 0 or w.max() / w.min() > max_condition:
            return None
        rates = lyapunov_rates(loops, Pc, d)
        worst = _worst(rates, d)
        return Certificate(_margin(worst, d, alpha, rho) > tol, d, worst,
                           _margin(worst, d, alpha, rho), Pc, source, list(map(float, rates)))

    cert = attempt(P, 'synthesis')
    if cert is None or not cert.certified:
        fresh = attempt(analysis_lmi(loops, d, alpha, rho), 'analysis-lmi')
        if fresh is not None and (cert is None or fresh.margin > cert.margin):
            cert = fresh
    if cert is None:
        return Certificate(False, d, np.nan, -np.inf, None, 'none',
                           reason='no positive definite P satisfies the vertex inequalities')
    if not cert.certified:
        cert.reason = (f'vertex Lyapunov margin {cert.margin:.3g} <= {tol:g} '
                       f'({"rho_c" if d else "alpha_c"} = {cert.rate:.6g})')
    if grid_models is not None and cert.P is not None:
        g_loops = [A - B @ G @ system.C for A, B in grid_models]
        rates = lyapunov_rates(g_loops, cert.P, d)
        cert.grid_points = len(g_loops)
        cert.grid_margin = _margin(_worst(rates, d), d, alpha, rho)
        eig = [np.linalg.eigvals(Acl) for Acl in g_loops]
        cert.grid_worst_eig = float(max(np.abs(e).max() for e in eig) if d
                                    else max(e.real.max() for e in eig))
        eig_ok = cert.grid_worst_eig < (rho if d else -alpha)
        if cert.certified and not (cert.grid_margin > tol and eig_ok):
            cert.certified = False
            cert.reason = (f'dense grid: Lyapunov margin {cert.grid_margin:.3g}, '
                           f'worst eigenvalue {cert.grid_worst_eig:.6g}')
    return cert


def best_rate(system: UncertainSystem, G, *, lo: float | None = None, hi: float | None = None,
              iterations: int = 30) -> float:
    """Largest certifiable α (continuous) or smallest ρ (discrete) for a fixed G, by bisection."""
    G = np.atleast_2d(np.asarray(G, dtype=float))
    loops = system.closed_loops(G)
    d = system.discrete

    def ok(v):
        P = analysis_lmi(loops, d, alpha=0.0 if d else v, rho=v if d else 1.0)
        if P is None:
            return False
        rates = lyapunov_rates(loops, P, d)
        return _margin(_worst(rates, d), d, 0.0 if d else v, v if d else 1.0) > 0
    if d:
        lo_, hi_ = (lo or 0.0), (hi or 1.0)   # find smallest ok rho in (lo, hi]
        if not ok(hi_):
            return np.nan
        for _ in range(iterations):
            mid = 0.5 * (lo_ + hi_)
            if mid <= 0:
                break
            if ok(mid):
                hi_ = mid
            else:
                lo_ = mid
        return hi_
    lo_ = lo or 0.0
    if not ok(lo_):
        return np.nan
    if hi is not None:
        hi_ = hi
    else:
        hi_ = max(1.0, 2.0 * max(np.abs(np.linalg.eigvals(L)).max() for L in loops))
    for _ in range(iterations):
        mid = 0.5 * (lo_ + hi_)
        if ok(mid):
            lo_ = mid
        else:
            hi_ = mid
    return lo_
