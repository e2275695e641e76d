"""
Polytopic uncertain linear systems and the augmented system of seed 001 (eq. 2.7, 2.9).

Sign convention used everywhere in this package (seed 001 eq. 3.3-3.4):

    u = −G y,   y = C x   ⇒   closed loop  A − B G C

so a *positive* G adds damping when B and C have the usual signs. State feedback is the special
case C = I (then G = K, eq. 2.5-2.6).

A model set is a list of vertex models ``(A_l, B_l)``. The uncertain system is the convex hull of
the augmented matrices F_l = [[A_l, −B_l], [0, 0]] (eq. 2.9), so both ways of the thesis are
covered: ``UncertainSystem.product`` builds all N·M pairs of independent vertex sets D_A × D_B (eq.
1.25-1.26), while a list of coupled pairs (A and B evaluated at the same parameter point, as for a
sampled motor model) is passed directly.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Iterable, List, Optional, Sequence, Tuple

import numpy as np

Model = Tuple[np.ndarray, np.ndarray]


def _as_matrix(x, name: str) -> np.ndarray:
    a = np.array(x, dtype=float)
    if a.ndim == 1:
        a = a.reshape(-1, 1)
    if a.ndim != 2:
        raise ValueError(f'{name} must be a matrix, got shape {a.shape}')
    if not np.all(np.isfinite(a)):
        raise ValueError(f'{name} contains NaN or inf')
    return a


@dataclass(frozen=True)
class UncertainSystem:
    """
    Polytopic uncertain system x' = A x + B u (or x⁺ = A x + B u), y = C x.

    Parameters
    ----------
    models : sequence of (A, B)
        Vertex models; (A, B) ranges over their convex hull.
    C : (r, n) array
        Output matrix (full row rank, eq. 3.1). ``None`` means state feedback (C = I).
    discrete : bool
        ``True`` for x(t+1) = A x(t) + B u(t) (eq. 2.2), ``False`` for ẋ = A x + B u (eq. 2.1).
    name : str
        A label for reports.
    family : callable, optional
        ``family(p) -> (A, B)`` for a parameter vector p; used to certify on a dense grid of the
        uncertain parameters (it is not used by the synthesis).
    bounds : sequence of (low, high), optional
        Box of the uncertain parameters passed to ``family``.

    """

    models: Tuple[Model, ...]
    C: np.ndarray
    discrete: bool
    name: str = ''
    family: Optional[Callable[[np.ndarray], Model]] = field(default=None, compare=False)
    bounds: Optional[Tuple[Tuple[float, float], ...]] = None

    def __init__(self, models: Iterable[Model], C=None, discrete: bool = False, name: str = '',
                 family=None, bounds=None):
        ms = []
        for k, (A, B) in enumerate(models):
            A = _as_matrix(A, f'A[{k}]')
            B = _as_matrix(B, f'B[{k}]')
            if A.shape[0] != A.shape[1]:
                raise ValueError(f'A[{k}] must be square, got {A.shape}')
            if B.shape[0] != A.shape[0]:
                raise ValueError(f'B[{k}] has {B.shape[0]} rows, A[{k}] has {A.shape[0]}')
            if ms and (A.shape != ms[0][0].shape or B.shape != ms[0][1].shape):
                raise ValueError(f'vertex {k} has shapes {A.shape}, {B.shape}; '
                                 f'vertex 0 has {ms[0][0].shape}, {ms[0][1].shape}')
            ms.append((A, B))
        if not ms:
            raise ValueError('an uncertain system needs at least one vertex model')
        n = ms[0][0].shape[0]
        C = np.eye(n) if C is None else _as_matrix(C, 'C')
        if C.shape[1] != n:
            raise ValueError(f'C has {C.shape[1]} columns, the state has {n}')
        if np.linalg.matrix_rank(C) < C.shape[0]:
            raise ValueError('C must have full row rank (seed 001 §3.1)')
        object.__setattr__(self, 'models', tuple(ms))
        object.__setattr__(self, 'C', C)
        object.__setattr__(self, 'discrete', bool(discrete))
        object.__setattr__(self, 'name', name)
        object.__setattr__(self, 'family', family)
        object.__setattr__(self, 'bounds', None if bounds is None else
                           tuple((float(lo), float(hi)) for lo, hi in bounds))

    @classmethod
    def product(cls, A_vertices: Sequence, B_vertices: Sequence, C=None, discrete=False,
                name: str = '', family=None, bounds=None) -> 'UncertainSystem':
        """All pairs (A_i, B_j) of independent vertex sets D_A × D_B (L = N·M, eq. 2.9)."""
        return cls([(A, B) for A in A_vertices for B in B_vertices], C, discrete, name,
                   family, bounds)

    # Sizes ----------------------------------------------------------------------------------
    @property
    def n(self) -> int:
        return self.models[0][0].shape[0]

    @property
    def m(self) -> int:
        return self.models[0][1].shape[1]

    @property
    def r(self) -> int:
        return self.C.shape[0]

    @property
    def is_state_feedback(self) -> bool:
        return self.r == self.n and np.allclose(self.C, np.eye(self.n))

    # Transformations ------------------------------------------------------------------------
    def closed_loops(self, G) -> List[np.ndarray]:
        """A_l − B_l G C for every vertex model (the thesis's sign convention, eq. 3.3)."""
        G = np.atleast_2d(np.asarray(G, dtype=float))
        return [A - B @ G @ self.C for A, B in self.models]

    def transformed(self, T: np.ndarray) -> List[Model]:
        """Vertex models in the coordinates x̃ = T x (eq. 3.26): (T A T⁻¹, T B)."""
        Ti = np.linalg.inv(T)
        return [(T @ A @ Ti, T @ B) for A, B in self.models]

    def grid_models(self, points_per_axis: int | Sequence[int]) -> List[Model]:
        """Models of ``family`` on a regular grid of ``bounds`` (corners included)."""
        if self.family is None or self.bounds is None:
            raise ValueError(f'system {self.name!r} has no parameter family to grid')
        k = len(self.bounds)
        counts = ([int(points_per_axis)] * k if np.isscalar(points_per_axis)
                  else [int(c) for c in points_per_axis])
        axes = [np.linspace(lo, hi, c) for (lo, hi), c in zip(self.bounds, counts)]
        mesh = np.meshgrid(*axes, indexing='ij')
        pts = np.stack([m.ravel() for m in mesh], axis=1)
        return [self.family(p) for p in pts]


def augmented(A: np.ndarray, B: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    """Return the augmented pair of eq. 2.7: F = [[A, −B], [0, 0]], E = [0; I] (p = n + m)."""
    n, m = B.shape
    F = np.zeros((n + m, n + m))
    F[:n, :n] = A
    F[:n, n:] = -B
    E = np.zeros((n + m, m))
    E[n:, :] = np.eye(m)
    return F, E


def with_decay(models: Sequence[Model], discrete: bool, alpha: float = 0.0,
               rho: float = 1.0) -> List[Model]:
    """
    Vertex models whose quadratic stability means a guaranteed decay rate.

    Continuous time: (A + αI, B) stable  ⇔  Re λ(A − BGC) < −α (and V = x'Px decays as e^{−2αt}).
    Discrete time:  (A/ρ, B/ρ) stable  ⇔  |λ(A − BGC)| < ρ (and V decays as ρ^{2k}).
    """
    if discrete:
        if not (0.0 < rho <= 1.0):
            raise ValueError(f'rho = {rho} must be in (0, 1]')
        return [(A / rho, B / rho) for A, B in models]
    if not alpha >= 0.0:
        raise ValueError(f'alpha = {alpha} must be >= 0')
    return [(A + alpha * np.eye(A.shape[0]), B) for A, B in models]


def complete_basis(C: np.ndarray, D: np.ndarray | None = None) -> Tuple[np.ndarray, np.ndarray]:
    """T = [C; D] (eq. 3.7). If D is None, D spans the orthogonal complement of the rows of C."""
    r, n = C.shape
    if D is None:
        if r == n:
            D = np.zeros((0, n))
        else:
            _, _, Vt = np.linalg.svd(C)
            D = Vt[r:, :]
    D = np.atleast_2d(np.asarray(D, dtype=float)).reshape(n - r, n) if n > r else np.zeros((0, n))
    T = np.vstack([C, D])
    cond = np.linalg.cond(T)
    if not np.isfinite(cond) or cond > 1e12:
        raise ValueError(f'T = [C; D] is singular (cond = {cond:.3g}); choose another D')
    return T, D
