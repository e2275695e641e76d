"""
Gain-norm reduction at a fixed guaranteed decay rate (an addition to seed 001, not in it).

The thesis minimizes the *bound* λ_max(W₃) ≥ ‖G‖², not ‖G‖ itself, and the bound is loose when
W1y ≫ I. Minimizing ‖G‖ over quadratically stabilizing gains is not convex (it is bilinear in G
and P), but each half is: for fixed P, the Lyapunov inequalities are affine in G; for fixed G they
are affine in P. This module alternates

    P-step:  maximize δ over I ⪯ P ⪯ κ I  with the vertex inequalities at rate α (or ρ) and margin
    δ G-step:  minimize ‖G‖ with that P fixed and margin δ_min

starting from a certified gain. The current G stays feasible in the next G-step as long as the
P-step margin is at least δ_min, so ‖G‖ never increases; every iterate is re-certified by
:func:`im_robust.certificate.certify` and only certified iterates are kept. It is a local method:
it finds *a* smaller certified gain, not the smallest one.
"""
from __future__ import annotations

from dataclasses import dataclass, field
import sys
from typing import List, Optional

import numpy as np

from .certificate import Certificate, certify
from .polytope import UncertainSystem


@dataclass
class RefineResult:
    G: np.ndarray
    norm_G: float
    certificate: Certificate
    iterations: int
    norms: List[float] = field(default_factory=list)


def _lyap_blocks(cp, Acl, P, discrete, alpha, rho, margin):
    n = Acl.shape[0]
    I = np.eye(n)  # noqa: E741 (the identity matrix, as in the equations)
    if discrete:
        return cp.bmat([[rho * rho * P - margin * I, Acl.T @ P], [P @ Acl, P]]) >> 0
    Aa = Acl + alpha * I
    return Aa.T @ P + P @ Aa << -margin * I


def reduce_gain_norm(system: UncertainSystem, G0, *, alpha: float = 0.0, rho: float = 1.0,
                     iterations: int = 25, kappa: float = 1e4, min_margin: float = 1e-4,
                     grid_models=None, rel_tol: float = 1e-4,
                     progress: bool = False) -> Optional[RefineResult]:
    """
    Alternate P- and G-steps from a certified G0; return the smallest certified gain found.

    Returns None when G0 itself cannot be certified at the requested rate.
    """
    import cvxpy as cp  # heavy: cvxpy only when an LMI is solved
    G = np.atleast_2d(np.asarray(G0, dtype=float))
    best_cert = certify(system, G, alpha=alpha, rho=rho, grid_models=grid_models)
    if not best_cert.certified:
        return None
    best = RefineResult(G.copy(), float(np.linalg.norm(G, 2)), best_cert, 0,
                        [float(np.linalg.norm(G, 2))])
    n = system.n
    I = np.eye(n)  # noqa: E741 (the identity matrix, as in the equations)
    for k in range(1, iterations + 1):
        P = cp.Variable((n, n), symmetric=True)
        delta = cp.Variable()
        cons = [P >> I, P << kappa * I]
        cons += [_lyap_blocks(cp, A - B @ G @ system.C, P, system.discrete, alpha, rho, delta)
                 for A, B in system.models]
        cp.Problem(cp.Maximize(delta), cons).solve(solver='CLARABEL')
        if P.value is None or delta.value is None or delta.value < min_margin:
            break
        Pv = 0.5 * (P.value + P.value.T)
        Gv = cp.Variable(G.shape)
        g = cp.Variable()
        cons = [cp.sigma_max(Gv) <= g]
        cons += [_lyap_blocks(cp, A - B @ Gv @ system.C, Pv, system.discrete, alpha, rho,
                              min_margin)
                 for A, B in system.models]
        cp.Problem(cp.Minimize(g), cons).solve(solver='CLARABEL')
        if Gv.value is None:
            break
        G_new = np.asarray(Gv.value, dtype=float).reshape(G.shape)
        cert = certify(system, G_new, alpha=alpha, rho=rho, grid_models=grid_models)
        norm_new = float(np.linalg.norm(G_new, 2))
        if progress:
            print(f'[im_robust] norm reduction it {k}: ||G|| = {norm_new:.6g}, '
                  f'certified = {cert.certified}', file=sys.stderr)
        if not cert.certified:
            break
        improved = norm_new < best.norm_G * (1 - rel_tol)
        G = G_new
        if norm_new < best.norm_G:
            best = RefineResult(G_new, norm_new, cert, k, best.norms + [norm_new])
        if not improved:
            break
    return best
