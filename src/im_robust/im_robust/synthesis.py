"""
Robust static output-feedback synthesis by convex programming (seed 001 ch. 2-3).

The problem solved is (3.33)/(4.1): in the coordinates x̃ = T x with T = [C; D],

    minimize    f(W_o) = λ_max(W₃)                                   (eq. 2.33)
    subject to  W_o = W_o' ⪰ 0 with the zero pattern of eq. 3.31
                Θ_l(W_o) restricted to E'z = 0  ⪯ −ε I,  l = 1…L      (eq. 2.30 / 2.59)
                W₁ ⪰ I                                           (the l = 0 vertex F₀, eq. 2.23)

and the gain is G = W2y' W1y⁻¹ (eq. 3.35), u = −G y. Since W₁ ⪰ I and W ⪰ 0,
G Gᵀ ⪯ G W1y Gᵀ ⪯ W₃, so ‖G‖² ≤ f(W_o) (eq. 2.31-2.33, 3.19).

Two choices are exposed because the thesis fixes them silently:

- ``margin`` is ε, the right-hand side of the normalization z'Θz ≤ −ε (the thesis uses 1). The cone
  is homogeneous, but the objective is not: together with W₁ ⪰ I, ε sets how much of the stability
  margin the minimum-norm bound has to buy, and therefore which G comes out. ε is in the units of
  W (state units squared per second or per step), so it depends on the state scaling.
- ``normalization='thesis'`` imposes W₁ ⪰ I (F₀, eq. 2.23); ``'output'`` imposes only W1y ⪰ I,
  which is all the bound ‖G‖² ≤ λ_max(W₃) needs (GGᵀ ⪯ W2y' W1y⁻¹ W2y ⪯ W₃).

Every returned gain passes :func:`im_robust.certificate.certify`; otherwise the result carries no
gain (``G is None``) and says why.
"""
from __future__ import annotations

from dataclasses import dataclass, field
import sys
import time
from typing import Dict, List, Optional, Sequence

import numpy as np

from .certificate import Certificate, certify
from .polytope import complete_basis, Model, UncertainSystem, with_decay
from .structure import apply_map, StructuredW

SOLVERS = ('clarabel', 'scs', 'cutting-plane')


@dataclass
class SynthesisResult:
    """
    Outcome of a synthesis.

    status : ``'certified'`` (G is set and certified), ``'infeasible'`` (the solver proved the
    convex problem infeasible — for the cutting plane: within its box bounds), ``'uncertified'``
    (the solver returned a point but the gain failed the independent check; G is None and the
    candidate is kept in ``rejected_G``) or ``'failed'`` (solver error, iteration limit).
    """

    status: str
    solver: str
    solver_status: str
    G: Optional[np.ndarray] = None
    objective: Optional[float] = None
    W: Optional[np.ndarray] = None
    T: Optional[np.ndarray] = None
    D: Optional[np.ndarray] = None
    certificate: Optional[Certificate] = None
    iterations: Optional[int] = None
    wall_s: float = 0.0
    message: str = ''
    rejected_G: Optional[np.ndarray] = None
    history: Dict[str, List[float]] = field(default_factory=dict)

    @property
    def norm_G(self) -> Optional[float]:
        return None if self.G is None else float(np.linalg.norm(self.G, 2))

    def summary(self) -> dict:
        return {'status': self.status, 'solver': self.solver, 'solver_status': self.solver_status,
                'G': None if self.G is None else np.asarray(self.G).tolist(),
                'norm_G': self.norm_G, 'objective': self.objective,
                'iterations': self.iterations, 'wall_s': self.wall_s, 'message': self.message,
                'certificate': None if self.certificate is None else self.certificate.summary()}


@dataclass
class Problem:
    """The data of (3.33) in transformed coordinates, shared by both solvers."""

    system: UncertainSystem
    T: np.ndarray
    D: np.ndarray
    structure: StructuredW
    models: List[Model]          # transformed, decay-scaled vertex models
    theta: List[np.ndarray]      # (q, n, n) maps
    w1: np.ndarray               # (q, k, k) normalization map
    w3: np.ndarray               # (q, m, m)
    full: np.ndarray             # (q, p, p)
    margin: float
    alpha: float
    rho: float
    normalization: str


def build_problem(system: UncertainSystem, *, D=None, alpha: float = 0.0, rho: float = 1.0,
                  margin: float = 1.0, normalization: str = 'thesis') -> Problem:
    """
    Build the problem: steps 1-2 of the algorithm of §3.3.

    T = [C; D], S = diag(T, I), extreme models S F_l S⁻¹.
    """
    if normalization not in ('thesis', 'output'):
        raise ValueError("normalization must be 'thesis' or 'output'")
    if not margin > 0:
        raise ValueError(f'margin = {margin} must be > 0')
    T, D = complete_basis(system.C, D)
    models = with_decay(system.models, system.discrete, alpha, rho)
    Ti = np.linalg.inv(T)
    models = [(T @ A @ Ti, T @ B) for A, B in models]
    st = StructuredW(system.n, system.m, system.r)
    return Problem(system, T, D, st, models, st.theta_maps(models, system.discrete),
                   st.w1_map('all' if normalization == 'thesis' else 'output'), st.w3_map(),
                   st.full_map(), float(margin), float(alpha), float(rho), normalization)


def constraint_violation(prob: Problem, omega: np.ndarray) -> Dict[str, float]:
    """Largest violation of each constraint family of (3.33) at ω (≤ 0 means satisfied)."""
    th = max(np.linalg.eigvalsh(apply_map(M, omega)).max() for M in prob.theta) + prob.margin
    w1 = 1.0 - np.linalg.eigvalsh(apply_map(prob.w1, omega)).min()
    psd = -np.linalg.eigvalsh(apply_map(prob.full, omega)).min()
    return {'theta': float(th), 'w1': float(w1), 'psd': float(psd),
            'objective': float(np.linalg.eigvalsh(apply_map(prob.w3, omega)).max())}


def _solve_sdp(prob: Problem, solver: str, verbose: bool = False):
    import cvxpy as cp  # heavy: cvxpy only when an LMI is solved
    st = prob.structure
    q = st.q
    omega = cp.Variable(q)
    t = cp.Variable()

    def expr(M):
        k = M.shape[1]
        X = cp.reshape(M.reshape(q, k * k).T @ omega, (k, k), order='C')
        return 0.5 * (X + X.T)

    n, m = st.n, st.m
    cons = [expr(prob.full) >> 0,
            expr(prob.w1) >> np.eye(prob.w1.shape[1]),
            expr(prob.w3) << t * np.eye(m)]
    for M in prob.theta:
        cons.append(expr(M) << -prob.margin * np.eye(n))
    cp_prob = cp.Problem(cp.Minimize(t), cons)
    name = {'clarabel': 'CLARABEL', 'scs': 'SCS'}[solver]
    kwargs = {'eps': 1e-8, 'max_iters': 100000} if solver == 'scs' else {}
    cp_prob.solve(solver=name, verbose=verbose, **kwargs)
    iters = None
    try:
        iters = int(cp_prob.solver_stats.num_iters)
    except Exception:
        pass
    val = None if omega.value is None else np.asarray(omega.value, dtype=float)
    return cp_prob.status, val, iters


def synthesize(system: UncertainSystem, *, D=None, solver: str = 'clarabel', alpha: float = 0.0,
               rho: float = 1.0, margin: float = 1.0, normalization: str = 'thesis',
               grid_models: Optional[Sequence[Model]] = None,
               certify_alpha: Optional[float] = None,
               certify_rho: Optional[float] = None, progress: bool = False,
               **cutting_plane_options) -> SynthesisResult:
    """
    Solve (3.33) and certify the gain.

    Parameters
    ----------
    system : UncertainSystem
        Vertex models, output matrix C, time domain.
    D : (n − r, n) array, optional
        Completes T = [C; D]; default: orthonormal complement of the rows of C.
    solver : str
        ``'clarabel'``, ``'scs'`` or ``'cutting-plane'`` (§4.1, LPs by HiGHS).
    alpha, rho : float
        Required decay: continuous Re λ < −α (vertices A + αI), discrete |λ| < ρ (vertices A/ρ).
    margin : float
        ε of the normalization z'Θz ≤ −ε (thesis: 1).
    normalization : str
        ``'thesis'`` (W₁ ⪰ I) or ``'output'`` (W1y ⪰ I).
    grid_models : sequence of (A, B), optional
        Dense-grid models for the certificate.
    certify_alpha, certify_rho : float, optional
        Rate the certificate demands (default: alpha, rho).
    progress : bool
        Print iteration progress on stderr (cutting plane).
    cutting_plane_options
        Passed to :func:`im_robust.cutting_plane.solve_cutting_plane`.

    """
    if solver not in SOLVERS:
        raise ValueError(f'solver must be one of {SOLVERS}, got {solver!r}')
    t0 = time.perf_counter()
    prob = build_problem(system, D=D, alpha=alpha, rho=rho, margin=margin,
                         normalization=normalization)
    history: Dict[str, List[float]] = {}
    if solver == 'cutting-plane':
        # heavy: cutting_plane imports scipy.optimize, only for this solver
        from .cutting_plane import solve_cutting_plane
        cp_res = solve_cutting_plane(prob, progress=progress, **cutting_plane_options)
        solver_status, omega, iters, history = (cp_res.status, cp_res.omega, cp_res.iterations,
                                                cp_res.history)
        ok_status = ('optimal',)
        infeasible_status = ('infeasible',)
    else:
        try:
            solver_status, omega, iters = _solve_sdp(prob, solver)
        except Exception as exc:  # a solver crash is reported, not raised
            return SynthesisResult('failed', solver, f'error: {exc}', T=prob.T, D=prob.D,
                                   wall_s=time.perf_counter() - t0, message=str(exc))
        ok_status = ('optimal', 'optimal_inaccurate')
        infeasible_status = ('infeasible', 'infeasible_inaccurate')
    res = SynthesisResult('failed', solver, solver_status, T=prob.T, D=prob.D, iterations=iters,
                          history=history)
    if solver_status in infeasible_status:
        res.status = 'infeasible'
        res.message = ('the convex problem (3.33) is infeasible for this D: no certified gain '
                       '(output feedback conditions are only sufficient; another D may work)')
        if solver == 'cutting-plane':
            res.message += '; the cutting-plane LP proves this only inside its box bounds'
        res.wall_s = time.perf_counter() - t0
        return res
    if omega is None or solver_status not in ok_status:
        res.message = f'solver returned {solver_status!r} without a usable point'
        res.wall_s = time.perf_counter() - t0
        return res
    if not _certify_point(res, system, prob, omega, solver_status,
                          alpha if certify_alpha is None else certify_alpha,
                          rho if certify_rho is None else certify_rho, grid_models):
        res.wall_s = time.perf_counter() - t0
        return res
    res.wall_s = time.perf_counter() - t0
    if progress:
        print(f'[im_robust] {system.name or "system"} {solver}: {res.status} '
              f'({res.wall_s:.2f} s)', file=sys.stderr)
    return res


def _certify_point(res: SynthesisResult, system: UncertainSystem, prob: Problem, omega,
                   solver_status, alpha: float, rho: float, grid_models) -> bool:
    """
    Fill ``res`` from the solver's point ``omega``: W, the objective, the gain, its certificate.

    The certificate demands the rates ``alpha``, ``rho``. Returns False (``res`` uncertified)
    when W₁ is singular: no gain.
    """
    st = prob.structure
    W = st.matrix(omega)
    res.W = W
    res.objective = float(np.linalg.eigvalsh(W[st.n:, st.n:]).max())
    try:
        G = st.gain(W)
        P = st.lyapunov_P(W, prob.T)
    except np.linalg.LinAlgError as exc:
        res.status = 'uncertified'
        res.message = f'W1 is singular: {exc}'
        return False
    cert = certify(system, G, alpha=alpha, rho=rho, P=P, grid_models=grid_models)
    res.certificate = cert
    viol = constraint_violation(prob, omega)
    res.history.setdefault('final_violation', [viol['theta'], viol['w1'], viol['psd']])
    if cert.certified:
        res.status = 'certified'
        res.G = G
        res.message = f'certified by {cert.P_source} P'
    else:
        res.status = 'uncertified'
        res.rejected_G = G
        res.message = f'solver said {solver_status!r} but the certificate failed: {cert.reason}'
    return True
