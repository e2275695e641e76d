"""
The structured matrix W_o of seed 001 eq. 3.31 and the linear maps of the cone (2.59).

In the coordinates x̃ = T x, T = [C; D] (eq. 3.7, 3.26), the state splits into the r outputs (index
set y) and the n − r complementary coordinates (index set d); the augmented variable adds the m
inputs (index set u). The equality constraints C W₁ D' = 0 and W₂' D' = 0 (eq. 3.9, 3.29-3.30)
become the zero pattern

          y     d     u
    y  [ W1y    0    W2y ]
    d  [  0    W1d    0  ]
    u  [ W2y'   0    W3  ]

so W₂' W₁⁻¹ = [W2y' W1y⁻¹, 0] = [G, 0] (eq. 3.35) and u = −G ỹ = −G C x.

``StructuredW`` parameterizes the free entries by a vector ω (off-diagonal entries first, then the
diagonal — the thesis's ordering for the LP (4.4) — so that the diagonal can be bounded below by
zero), and gives the vertex conditions as linear maps of ω:

    continuous (eq. 2.57):  Θ_l(W) = F_l W + W F_l'
    discrete   (eq. 2.58):  Θ_l(W) = F_l W F_l' − W

restricted to the subspace E'z = 0, i.e. z = [x; 0]: the leading n × n block. Written out,

    continuous:  A W₁ − B W₂' + W₁ A' − W₂ B'                      (eq. 2.15)
    discrete:    A W₁ A' − A W₂ B' − B W₂' A' + B W₃ B' − W₁        (eq. 2.45)
"""
from __future__ import annotations

from typing import List, Sequence, Tuple

import numpy as np

from .polytope import augmented, Model


class StructuredW:
    """Free entries of W_o for sizes (n, m, r) and the linear maps built on them."""

    def __init__(self, n: int, m: int, r: int):
        if not (1 <= r <= n) or m < 1:
            raise ValueError(f'need 1 <= r <= n and m >= 1, got n={n}, m={m}, r={r}')
        self.n, self.m, self.r = n, m, r
        p = n + m
        self.p = p
        y = list(range(r))
        d = list(range(r, n))
        u = list(range(n, p))
        free = np.zeros((p, p), dtype=bool)
        for block_rows, block_cols in ((y, y), (d, d), (y, u), (u, y), (u, u)):
            for i in block_rows:
                for j in block_cols:
                    free[i, j] = True
        off = [(i, j) for j in range(p) for i in range(p) if i < j and free[i, j]]
        diag = [(i, i) for i in range(p) if free[i, i]]
        self.entries: List[Tuple[int, int]] = off + diag
        self.n_offdiag = len(off)
        self.q = len(self.entries)
        basis = np.zeros((self.q, p, p))
        for k, (i, j) in enumerate(self.entries):
            basis[k, i, j] = 1.0
            basis[k, j, i] = 1.0
        self.basis = basis
        self.free_mask = free

    # ω ↔ W -----------------------------------------------------------------------------------
    def matrix(self, omega: np.ndarray) -> np.ndarray:
        return np.tensordot(np.asarray(omega, dtype=float), self.basis, axes=1)

    def vector(self, W: np.ndarray) -> np.ndarray:
        return np.array([W[i, j] for i, j in self.entries])

    def structure_violation(self, W: np.ndarray) -> float:
        """Largest entry of W where eq. 3.31 requires a zero."""
        W = np.asarray(W, dtype=float)
        mask = ~self.free_mask
        return float(np.abs(W[mask]).max()) if mask.any() else 0.0

    # Linear maps: each returns an array of shape (q, k, k) with M(ω) = Σ_k ω_k M_k
    # ----------------
    def theta_maps(self, models: Sequence[Model], discrete: bool) -> List[np.ndarray]:
        """Θ_l restricted to E'z = 0 (the leading n × n block), one (q, n, n) array per vertex."""
        n = self.n
        maps = []
        for A, B in models:
            F, _ = augmented(A, B)
            if discrete:
                th = np.einsum('ij,kjl,ml->kim', F, self.basis, F) - self.basis
            else:
                FW = np.einsum('ij,kjl->kil', F, self.basis)
                th = FW + np.transpose(FW, (0, 2, 1))
            maps.append(th[:, :n, :n])
        return maps

    def w1_map(self, block: str = 'all') -> np.ndarray:
        """
        Return the normalized variables.

        W₁ (``'all'``, the thesis's F₀ normalization, eq. 2.23/2.30) or only W1y (``'output'``).
        """
        k = self.n if block == 'all' else self.r
        return self.basis[:, :k, :k]

    def w3_map(self) -> np.ndarray:
        return self.basis[:, self.n:, self.n:]

    def full_map(self) -> np.ndarray:
        return self.basis

    # Gain ------------------------------------------------------------------------------------
    def gain(self, W: np.ndarray) -> np.ndarray:
        """G from W₂' W₁⁻¹ = [G 0] (eq. 3.35): G = W2y' W1y⁻¹."""
        r, n = self.r, self.n
        W1y = W[:r, :r]
        W2y = W[:r, n:]
        return np.linalg.solve(W1y, W2y).T

    def lyapunov_P(self, W: np.ndarray, T: np.ndarray) -> np.ndarray:
        """P = W₁⁻¹ in original coordinates: P = T' W̃₁⁻¹ T (for A_cl' P + P A_cl < 0)."""
        W1 = W[:self.n, :self.n]
        return T.T @ np.linalg.solve(W1, T)


def apply_map(M: np.ndarray, omega: np.ndarray) -> np.ndarray:
    """Evaluate a (q, k, k) linear map at ω and symmetrize."""
    X = np.tensordot(omega, M, axes=1)
    return 0.5 * (X + X.T)
