"""
The thesis's own solver: a cutting-plane method with one LP per iteration (seed 001 §4.1).

Problem (4.2): minimize t over (t, ω) in C_f = {W_o(ω) ∈ C, λ_max(W₃) ≤ t}. Every constraint of
(3.33) is "an extreme eigenvalue of an affine matrix function of ω has a sign", so at a point that
violates it the eigenvector v gives a linear inequality that the point violates and every feasible
point satisfies (the separating hyperplane of Theorem 2.2.3, eq. 2.25-2.29 and 2.60-2.61):

    Θ_l:        v' Θ_l(W(ω)) v ≤ −ε          (v: top eigenvector of Θ_l) W₁ ⪰ I:     v' W₁(ω) v ≥ 1
    (v: bottom eigenvector of W₁) W ⪰ 0:      v' W(ω) v ≥ 0                (v: bottom eigenvector
    of W) epigraph:   v' W₃(ω) v ≤ t               (v: top eigenvector of W₃) — the (Z^k, γ^k) cut
    of (4.3)

Each iteration solves the LP over the cuts collected so far (HiGHS through scipy.optimize.linprog
instead of the thesis's dual simplex with warm start, eq. 4.5-4.8), then adds cuts at its solution.
The LP optimum is a lower bound on the optimum of (3.33); its point lies outside C_f until the end
(an outer approximation, Kelley's method).

Bounds. The first LPs have only a handful of cuts and are unbounded, so every entry of ω is boxed:
|ω_k| ≤ ``bound``, the diagonal in [0, bound] (the thesis: "ω_{r+1} … ω_g ≥ 0", eq. 4.4) and
t ∈ [0, bound]. The box is part of the problem actually solved:

- too small: the optimum of (3.33) lies outside it and the LP becomes infeasible (reported as
  ``infeasible`` — but it only proves there is no solution *in the box*), or the iterate converges
  to a box-constrained point that is not the optimum of (3.33);
- too large: the first iterates sit on the far corners, the cuts there are steep, many more
  iterations are needed, and HiGHS's absolute tolerances (1e-7) act on numbers of size ``bound``.

The iteration count therefore depends on ``bound``, on the tolerances and on which cuts are added
(``cuts='deepest'`` adds the single most violated constraint cut, as the thesis's ρ* = max ρ_l,
plus the epigraph cut when λ_max(W₃) > t; ``'all'`` adds one per violated family and vertex) —
compare counts with the thesis's 211/103/77 with that in mind.
"""
from __future__ import annotations

from dataclasses import dataclass, field
import sys
import time
from typing import Dict, List, Optional

import numpy as np
from scipy.optimize import linprog

from .structure import apply_map


@dataclass
class CuttingPlaneResult:
    status: str                      # 'optimal' | 'infeasible' | 'max_iterations' | 'lp_error'
    omega: Optional[np.ndarray]
    t: Optional[float]
    iterations: int
    history: Dict[str, List[float]] = field(default_factory=dict)


def _quad(M: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Coefficients c_k = v' M_k v of the linear function ω ↦ v' M(ω) v."""
    return np.einsum('i,kij,j->k', v, M, v)


def solve_cutting_plane(prob, *, bound: float = 1e5, tol: float = 1e-6,
                        max_iterations: int = 20000,
                        cuts: str = 'deepest', progress: bool = False,
                        progress_every: int = 200) -> CuttingPlaneResult:
    """
    Kelley cutting-plane solution of (3.33) for a :class:`~im_robust.synthesis.Problem`.

    Parameters
    ----------
    prob : Problem
        The problem built by :func:`im_robust.synthesis.build_problem`.
    bound : float
        Box on every free entry of W_o and on t (see module notes).
    tol : float
        Stop when every constraint is violated by at most ``tol``·max(1, ε) and the epigraph gap
        λ_max(W₃) − t is at most ``tol``·max(1, t).
    max_iterations : int
        Iterations before giving up (status ``'max_iterations'``).
    cuts : str
        ``'deepest'`` (thesis) or ``'all'``.
    progress : bool
        Print iteration progress on stderr, every ``progress_every`` iterations.
    progress_every : int
        Iterations between two progress lines.

    """
    if cuts not in ('deepest', 'all'):
        raise ValueError("cuts must be 'deepest' or 'all'")
    st = prob.structure
    q = st.q
    nvar = q + 1                      # ω, then t
    c = np.zeros(nvar)
    c[-1] = 1.0
    bounds = ([(-bound, bound)] * st.n_offdiag + [(0.0, bound)] * (q - st.n_offdiag)
              + [(0.0, bound)])
    rows: List[np.ndarray] = []
    rhs: List[float] = []

    def add(coef_omega, coef_t, b):
        row = np.zeros(nvar)
        row[:q] = coef_omega
        row[-1] = coef_t
        scale = np.abs(row).max()
        if scale > 0:                     # normalize the row: the LP sees O(1) coefficients
            rows.append(row / scale)
            rhs.append(b / scale)

    _initial_cuts(prob, add)

    feas_tol = tol * max(1.0, prob.margin)
    hist: Dict[str, List[float]] = {'lower_bound': [], 'infeasibility': []}
    t0 = time.perf_counter()
    omega = None
    t = None
    for it in range(1, max_iterations + 1):
        lp = linprog(c, A_ub=np.array(rows), b_ub=np.array(rhs), bounds=bounds, method='highs')
        if lp.status == 2:
            return CuttingPlaneResult('infeasible', None, None, it, hist)
        if lp.status != 0:
            return CuttingPlaneResult('lp_error', omega, t, it, hist)
        omega, t = lp.x[:q], float(lp.x[-1])
        candidates = _constraint_cuts(prob, omega)
        w, V = np.linalg.eigh(apply_map(prob.w3, omega))
        gap = w[-1] - t
        infeas = max([cand[0] for cand in candidates], default=0.0)
        hist['lower_bound'].append(t)
        hist['infeasibility'].append(infeas)
        if progress and (it % progress_every == 0 or it == 1):
            _progress(it, t, infeas, gap, t0)
        if infeas <= feas_tol and gap <= tol * max(1.0, abs(t)):
            return CuttingPlaneResult('optimal', omega, t, it, hist)
        if cuts == 'deepest' and candidates:
            candidates = [max(candidates, key=lambda cnd: cnd[0])]
        if gap > tol * max(1.0, abs(t)):
            candidates.append((gap, _quad(prob.w3, V[:, -1]), -1.0, 0.0))
        for _, co, ct, b in candidates:
            add(co, ct, b)
    return CuttingPlaneResult('max_iterations', omega, t, max_iterations, hist)


def _initial_cuts(prob, add) -> None:
    """Add the first cuts: diagonal of W₁ ≥ 1 (normalization) and t ≥ (W₃)_ii."""
    k1 = prob.w1.shape[1]
    for i in range(k1):
        e = np.zeros(k1)
        e[i] = 1.0
        add(-_quad(prob.w1, e), 0.0, -1.0)
    m = prob.structure.m
    for i in range(m):
        e = np.zeros(m)
        e[i] = 1.0
        add(_quad(prob.w3, e), -1.0, 0.0)


def _constraint_cuts(prob, omega: np.ndarray) -> list:
    """Return (violation, cut on ω, on t, right-hand side) of each constraint ``omega`` breaks."""
    candidates = []
    for M in prob.theta:
        w, V = np.linalg.eigh(apply_map(M, omega))
        viol = w[-1] + prob.margin
        if viol > 0:
            candidates.append((viol, _quad(M, V[:, -1]), 0.0, -prob.margin))
    w, V = np.linalg.eigh(apply_map(prob.w1, omega))
    if 1.0 - w[0] > 0:
        candidates.append((1.0 - w[0], -_quad(prob.w1, V[:, 0]), 0.0, -1.0))
    w, V = np.linalg.eigh(apply_map(prob.full, omega))
    if -w[0] > 0:
        candidates.append((-w[0], -_quad(prob.full, V[:, 0]), 0.0, 0.0))
    return candidates


def _progress(it: int, t: float, infeas: float, gap: float, t0: float) -> None:
    """Print one progress line of the iteration on stderr."""
    print(f'[im_robust] cutting plane it {it:6d}  t = {t:.6g}  infeasibility = '
          f'{infeas:.3g}  gap = {gap:.3g}  ({time.perf_counter() - t0:.1f} s)',
          file=sys.stderr)
