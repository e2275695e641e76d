"""
Robust sampled gains for the induction-motor drive (seed 001 applied to seed 000).

Model. Seed 000 eq. 1.112, state x = [i_α, i_β, φ_rα, φ_rβ] (A, A, Wb, Wb), input V_αβ (V), the
mechanical speed ω_r (rad/s) a parameter, electrical speed v·ω_r:

    A = [[−γ, 0, K/T_r, vω_r K], [0, −γ, −vω_r K, K/T_r],
         [L_sr/T_r, 0, −1/T_r, −vω_r], [0, L_sr/T_r, vω_r, −1/T_r]],   B = [I/(σL_s); 0]
    T_r = L_r/R_r,  K = L_sr/(σ L_s L_r),  γ = (R_s L_r² + R_r L_sr²)/(σ L_s L_r²)   (eq. 1.113)

sampled with a zero-order hold at the node period T_s: [A_d B_d; 0 I] = exp([A B; 0 0] T_s).

Uncertainty. R_r ∈ [0.42, 1.26] Ω, L_s, L_r ∈ [0.084, 0.116] H, L_sr ∈ [0.081, 0.113] H, ω_r ∈
[−ω_max, ω_max], R_s at its nominal value; only combinations with σ = 1 − L_sr²/(L_s L_r) ≥ σ_min.
σ_min must be positive: as σ → 0 the current time constant σL_s/R_eq → 0, the sampled current mode
becomes a one-step delay with gain 1/R_eq, and a current gain K is stable only for K < R_eq ≈
0.9-1.8 Ω whatever T_s. The default σ_min = 0.05 keeps every point of the chapter-4 variation
profile (σ ∈ [0.051, 0.070]). The set is not a polytope (σ ≥ σ_min is a quadric cut) and A_d, B_d
are not affine in the parameters (exp of a matrix affine in R_r, ω_r and rational in the
inductances). The synthesis therefore uses *sampled* vertex models: (A_d, B_d) at a grid of the
parameters (``vertex_points``). What the certificate then guarantees:

- exactly: quadratic stability (with the stated rate) of every model in the convex hull of the
  sampled (A_d, B_d) pairs — including arbitrarily fast variation among them;
- not guaranteed: that every physical parameter point maps into that hull. This is checked, not
  proved, on a much denser grid (``certify_points``) with the same P and by eigenvalues.

Loops designed here (sign conventions of the YAML the nodes read):

- current loop: ΔV_k = −K (i_k − i*_k) with a 2×2 K on the measured currents only — static output
  feedback with C = [I₂ 0] (seed 001 ch. 3, G = K); closed loop A_d − B_d K C.
- observer: x̂_{k+1} = A_d x̂_k + B_d V_k + L (i_k − C x̂_k), 4×2 L; error e = x − x̂ obeys
  e_{k+1} = (A_d − L C) e_k when the observer's model equals the plant's. Designed as the dual
  state feedback problem (A_d', C') with G = L' (seed 001 ch. 2; quadratic stability of A' and A
  with a common P are equivalent: ‖P^{½} A P^{−½}‖ = ‖P^{−½} A' P^{½}‖ with the roles of P and
  P⁻¹ swapped).

Scaling. In SI units the sampled model mixes entries of size 1e-4 to 1e2 (flux→current coupling
v ω_r K T_s ≈ 60 at 1 ms). The synthesis runs in per-unit coordinates: φ_b = 1 Wb,
i_b = φ_b / L_sr (the magnetizing current, ≈ 12.3 A for the thesis motor), V_b = v ω_b φ_b with
ω_b = 2π·60/v (≈ 377 V). Gains are converted back to SI.

Decay rate. A requested rate α (1/s) becomes ρ = exp(−α T_s). Current feedback cannot move the
rotor-flux modes below |λ| = exp(−T_s R_r/L_r) (with i ≡ 0 the flux decays with T_r = L_r/R_r),
so for the current loop α is bounded by min R_r/L_r = 0.42/0.116 ≈ 3.6 1/s whatever K is.
"""
from __future__ import annotations

from dataclasses import dataclass, field
import math
from typing import Dict, List, Optional, Tuple

from im_common.cli import gated_logger
from im_common.model import eq112_matrices
from im_common.params import MotorParams, THESIS_MOTOR
from im_robust.polytope import UncertainSystem
from im_robust.synthesis import SynthesisResult, synthesize
import numpy as np
from scipy.linalg import expm

DEFAULT_BOX: Dict[str, Tuple[float, float]] = {
    'R_r': (0.42, 1.26), 'L_s': (0.084, 0.116), 'L_r': (0.084, 0.116), 'L_sr': (0.081, 0.113)}
PARAM_NAMES = ('R_r', 'L_s', 'L_r', 'L_sr', 'omega_r')
C_CURRENT = np.hstack([np.eye(2), np.zeros((2, 2))])
DEFAULT_SIGMA_MIN = 0.05   # below the chapter-4 profile's smallest σ (0.051)
THESIS_K1 = 40.0   # V/A, |k1| of seed 000 §3.4.6 (printed −40 in the form ΔV = K(x̂ − x*))


def zoh(A: np.ndarray, B: np.ndarray, T_s: float) -> Tuple[np.ndarray, np.ndarray]:
    """Zero-order-hold sampling; A, B may carry leading batch dimensions."""
    n, m = A.shape[-1], B.shape[-1]
    M = np.zeros(A.shape[:-2] + (n + m, n + m))
    M[..., :n, :n] = A
    M[..., :n, n:] = B
    E = expm(M * T_s)
    return E[..., :n, :n], E[..., :n, n:]


def parameter_grid(points: Dict[str, int] | int, omega_max: float,
                   box: Optional[Dict[str, Tuple[float, float]]] = None,
                   sigma_min: float = DEFAULT_SIGMA_MIN) -> np.ndarray:
    """
    Rows (R_r, L_s, L_r, L_sr, ω_r) of a regular grid of the box ∩ {σ ≥ σ_min}.

    ``points`` is a count per name of :data:`PARAM_NAMES` (or one count for all); a count of 1
    takes the middle of the interval. Grid values of L_sr beyond the σ = σ_min surface are moved
    onto it (L_sr = √((1 − σ_min) L_s L_r)), so the grid covers the stiffest admissible models
    instead of dropping them; duplicate rows are removed.
    """
    if not 0.0 < sigma_min < 1.0:
        raise ValueError(f'sigma_min = {sigma_min} must be in (0, 1): sigma -> 0 is a motor '
                         f'without leakage, whose sampled current '
                         f'loop tolerates no gain above R_eq')
    box = dict(DEFAULT_BOX if box is None else box)
    box['omega_r'] = (-abs(omega_max), abs(omega_max))
    counts = {k: points for k in PARAM_NAMES} if isinstance(points, int) else dict(points)
    axes = []
    for k in PARAM_NAMES:
        lo, hi = box[k]
        c = int(counts.get(k, 2))
        axes.append(np.array([0.5 * (lo + hi)]) if c <= 1 else np.linspace(lo, hi, c))
    mesh = np.meshgrid(*axes, indexing='ij')
    pts = np.stack([m.ravel() for m in mesh], axis=1)
    L_sr_max = np.sqrt((1.0 - sigma_min) * pts[:, 1] * pts[:, 2])
    pts[:, 3] = np.minimum(pts[:, 3], L_sr_max)
    pts = pts[pts[:, 3] >= box['L_sr'][0]]
    return np.unique(pts, axis=0)


def sampled_models(grid: np.ndarray, T_s: float, motor: MotorParams = THESIS_MOTOR
                   ) -> Tuple[np.ndarray, np.ndarray]:
    """Batched ZOH models (A_d, B_d) of shape (N, 4, 4), (N, 4, 2) at the grid rows."""
    N = grid.shape[0]
    A = np.zeros((N, 4, 4))
    B = np.zeros((N, 4, 2))
    for k, (R_r, L_s, L_r, L_sr, w) in enumerate(grid):
        A[k], B[k] = eq112_matrices(motor.R_s, R_r, L_s, L_r, L_sr, motor.pole_pairs, w)
    return zoh(A, B, T_s)


@dataclass(frozen=True)
class Scaling:
    """Per-unit bases: x = S x̃, V = S_u Ṽ, i = S_y ĩ."""

    i_base: float
    phi_base: float
    v_base: float

    @classmethod
    def for_motor(cls, motor: MotorParams = THESIS_MOTOR) -> 'Scaling':
        phi_b = 1.0
        omega_b = 2.0 * math.pi * 60.0 / motor.pole_pairs
        return cls(phi_b / motor.L_sr, phi_b, motor.pole_pairs * omega_b * phi_b)

    @property
    def S(self) -> np.ndarray:
        return np.diag([self.i_base, self.i_base, self.phi_base, self.phi_base])

    @property
    def S_u(self) -> np.ndarray:
        return self.v_base * np.eye(2)

    @property
    def S_y(self) -> np.ndarray:
        return self.i_base * np.eye(2)


def current_loop_system(A_d: np.ndarray, B_d: np.ndarray, scaling: Scaling,
                        name: str = 'current loop') -> UncertainSystem:
    """
    Return the per-unit (Ã, B̃, C̃) of the current loop.

    Ã = S⁻¹ A_d S, B̃ = S⁻¹ B_d S_u, C̃ = S_y⁻¹ C S.
    """
    S, Si = scaling.S, np.linalg.inv(scaling.S)
    models = [(Si @ A @ S, Si @ B @ scaling.S_u) for A, B in zip(A_d, B_d)]
    C = np.linalg.inv(scaling.S_y) @ C_CURRENT @ S
    return UncertainSystem(models, C, discrete=True, name=name)


def observer_dual_system(A_d: np.ndarray, scaling: Scaling,
                         name: str = 'observer error (dual)') -> UncertainSystem:
    """Dual of the per-unit error dynamics: models (Ã', C̃'), state feedback (C = I)."""
    S, Si = scaling.S, np.linalg.inv(scaling.S)
    Ct = np.linalg.inv(scaling.S_y) @ C_CURRENT @ S
    models = [((Si @ A @ S).T, Ct.T) for A in A_d]
    return UncertainSystem(models, None, discrete=True, name=name)


@dataclass
class GainDesign:
    """A designed gain in SI units with its certificate (``gain`` is None unless certified)."""

    loop: str
    T_s: float
    decay_rate: float            # requested α (1/s)
    rho: float                   # exp(−α T_s)
    gain: Optional[np.ndarray]
    result: SynthesisResult
    vertex_models: int
    certificate_models: int
    dense_spectral_radius: Optional[float] = None
    dense_rate: Optional[float] = None       # −ln(spectral radius)/T_s over the dense grid
    D: Optional[np.ndarray] = None
    notes: List[str] = field(default_factory=list)

    @property
    def certified(self) -> bool:
        return self.gain is not None

    def summary(self) -> dict:
        c = self.result.certificate
        return {
            'loop': self.loop, 'T_s': self.T_s, 'decay_rate': self.decay_rate, 'rho': self.rho,
            'status': self.result.status, 'solver_status': self.result.solver_status,
            'certified': self.certified,
            'gain': None if self.gain is None else self.gain.tolist(),
            'vertex_models': self.vertex_models, 'certificate_models': self.certificate_models,
            'lyapunov_rho_vertices': None if c is None else float(c.rate),
            'lyapunov_rho_dense': None if c is None or c.grid_margin is None
            else float(self.rho - c.grid_margin),
            'dense_spectral_radius': self.dense_spectral_radius,
            'dense_decay_rate': self.dense_rate,
            'wall_s': self.result.wall_s, 'message': self.result.message, 'notes': self.notes,
        }


CURRENT_VERTEX_POINTS = {'R_r': 2, 'L_s': 2, 'L_r': 2, 'L_sr': 2, 'omega_r': 17}
OBSERVER_VERTEX_POINTS = {'R_r': 2, 'L_s': 3, 'L_r': 3, 'L_sr': 3, 'omega_r': 17}
DEFAULT_CERTIFY_POINTS = {'R_r': 5, 'L_s': 5, 'L_r': 5, 'L_sr': 5, 'omega_r': 41}


def _current_D_candidates() -> List[np.ndarray]:
    """
    Choices of D for T = [C; D] tried in turn (step 4 of §3.3: redefine D when C is empty).

    Per-unit coordinates: [0 I] (rotor flux), then rotor-current-like and stator-flux-like mixes.
    """
    Z, I = np.zeros((2, 2)), np.eye(2)  # noqa: E741 (the identity matrix, as in the equations)
    return [np.hstack([Z, I]), np.hstack([-I, I]), np.hstack([I, I]), np.hstack([-0.5 * I, I])]


_log = gated_logger('im_controller.gain_design.motor')


def design_current_gain(T_s: float = 1e-3, *, omega_max: float = 200.0, decay_rate: float = 0.0,
                        motor: MotorParams = THESIS_MOTOR, sigma_min: float = DEFAULT_SIGMA_MIN,
                        vertex_points=None, certify_points=None, margin: float = 1e-6,
                        design_extra_rate: float = 1.0, progress: bool = False) -> GainDesign:
    """
    Robust 2×2 current gain K (ΔV = −K(i − i*)) at the period T_s with |λ| < exp(−α T_s).

    Solves seed 001 (3.33) with ``normalization='output'`` and a small ε (``margin``; the rate is
    the margin that matters here) in per-unit coordinates, trying the D of
    :func:`_current_D_candidates` in turn. The synthesis asks for α + ``design_extra_rate`` at the
    vertex models and the certificate checks α on the dense grid: without that reserve the
    minimum-norm solution sits on the boundary at the vertices and the dense-grid models just
    outside their hull fail.
    """
    sc = Scaling.for_motor(motor)
    rho = math.exp(-decay_rate * T_s)
    rho_design = math.exp(-(decay_rate + design_extra_rate) * T_s)
    vg = parameter_grid(vertex_points or CURRENT_VERTEX_POINTS, omega_max, sigma_min=sigma_min)
    cg = parameter_grid(certify_points or DEFAULT_CERTIFY_POINTS, omega_max, sigma_min=sigma_min)
    A_v, B_v = sampled_models(vg, T_s, motor)
    A_c, B_c = sampled_models(cg, T_s, motor)
    sysm = current_loop_system(A_v, B_v, sc)
    dense = current_loop_system(A_c, B_c, sc).models
    last = None
    for D in _current_D_candidates():
        _log(progress, f'current loop T_s = {T_s:g} s, rho = {rho:.6f}: {len(vg)} vertex models, '
                       f'D = {D.tolist()} ...')
        res = synthesize(sysm, D=D, solver='clarabel', rho=rho_design, margin=margin,
                         normalization='output', grid_models=dense, certify_rho=rho)
        _log(progress, f'  {res.status} ({res.solver_status}), {res.wall_s:.1f} s')
        rank = {'certified': 0, 'uncertified': 1, 'failed': 2, 'infeasible': 3}
        if last is None or rank[res.status] < rank[last.status]:
            last = res          # keep the most informative attempt
        if res.status == 'certified':
            break
    design = GainDesign('current', T_s, decay_rate, rho, None, last, len(vg), len(cg), D=last.D)
    if last.status == 'certified':
        K = sc.S_u @ last.G @ np.linalg.inv(sc.S_y)
        design.gain = K
        loops = A_c - B_c @ (K @ C_CURRENT)
        r = float(np.abs(np.linalg.eigvals(loops)).max())
        design.dense_spectral_radius = r
        design.dense_rate = -math.log(r) / T_s
    if decay_rate > 0.42 / 0.116:
        design.notes.append('decay rates above min R_r/L_r (about 3.6 1/s) cannot be reached by '
                            'current feedback: the rotor-flux modes are fixed by T_r')
    return design


def design_observer_gain(T_s: float = 1e-3, *, omega_max: float = 200.0, decay_rate: float = 0.0,
                         motor: MotorParams = THESIS_MOTOR, sigma_min: float = DEFAULT_SIGMA_MIN,
                         vertex_points=None, certify_points=None, margin: float = 1e-6,
                         design_extra_rate: float = 2.0, progress: bool = False) -> GainDesign:
    """Robust 4×2 observer injection L at the period T_s with |λ(A_d − L C)| < exp(−α T_s)."""
    sc = Scaling.for_motor(motor)
    rho = math.exp(-decay_rate * T_s)
    rho_design = math.exp(-(decay_rate + design_extra_rate) * T_s)
    vg = parameter_grid(vertex_points or OBSERVER_VERTEX_POINTS, omega_max, sigma_min=sigma_min)
    cg = parameter_grid(certify_points or DEFAULT_CERTIFY_POINTS, omega_max, sigma_min=sigma_min)
    A_v, _ = sampled_models(vg, T_s, motor)
    A_c, _ = sampled_models(cg, T_s, motor)
    sysm = observer_dual_system(A_v, sc)
    dense = observer_dual_system(A_c, sc).models
    _log(progress, f'observer T_s = {T_s:g} s, rho = {rho:.6f}: {len(vg)} vertex models ...')
    res = synthesize(sysm, solver='clarabel', rho=rho_design, margin=margin,
                     normalization='thesis', grid_models=dense, certify_rho=rho)
    _log(progress, f'  {res.status} ({res.solver_status}), {res.wall_s:.1f} s')
    design = GainDesign('observer', T_s, decay_rate, rho, None, res, len(vg), len(cg))
    if res.status == 'certified':
        L_pu = res.G.T                                   # dual gain G = L̃'
        L = sc.S @ L_pu @ np.linalg.inv(sc.S_y)
        design.gain = L
        loops = A_c - L @ C_CURRENT
        r = float(np.abs(np.linalg.eigvals(loops)).max())
        design.dense_spectral_radius = r
        design.dense_rate = -math.log(r) / T_s
    return design


# ---------------------------------------------------------------------------------------------
# The thesis's continuous gains, sampled
# ---------------------------------------------------------------------------------------------
def thesis_continuous_gains(motor: MotorParams = THESIS_MOTOR) -> Tuple[np.ndarray, np.ndarray]:
    """
    K_c = k1·I (V/A) and the observer injection L_c (1/s on the current error), seed 000.

    The observer (eq. 3.27) is D x̂' + (C + R) x̂ = M V + F (x − x̂) with F = diag(k_e I₂, 0) and D
    = diag(σL_s I₂, (1/L_r) I₂); in explicit form the injection is D⁻¹F = [k_e/(σ L_s) I₂; 0] with
    k_e = 1/σ (§3.4.6), evaluated with the observer's nominal σ̂, L̂_s.
    """
    K_c = THESIS_K1 * np.eye(2)
    k_e = 1.0 / motor.sigma
    L_c = np.vstack([k_e / (motor.sigma * motor.L_s) * np.eye(2), np.zeros((2, 2))])
    return K_c, L_c


def thesis_gains_sampled(T_s: float, motor: MotorParams = THESIS_MOTOR
                         ) -> Tuple[np.ndarray, np.ndarray]:
    """
    Return K and the discrete observer injection L of a continuous one.

    K (unchanged: a static voltage gain) and L = Γ L_c with Γ = ∫₀^{T_s} e^{Aτ} dτ of the nominal
    model at ω_r = 0 (the injection held over the period like the voltage).
    """
    K_c, L_c = thesis_continuous_gains(motor)
    A, _ = eq112_matrices(motor.R_s, motor.R_r, motor.L_s, motor.L_r, motor.L_sr,
                          motor.pole_pairs, 0.0)
    _, Gamma_L = zoh(A, L_c, T_s)
    return K_c, Gamma_L


def delayed_closed_loop(A_d: np.ndarray, B_d: np.ndarray, F: np.ndarray, delay: int = 0
                        ) -> np.ndarray:
    """
    Return the closed loop of x_{k+1} = A_d x_k + B_d u_{k−d}, u_k = −F x_k as one matrix.

    The computational delay d (docs/plant.md §10) as states: z_k = [x_k; u_{k−1}; ...; u_{k−d}]
    (what the DSP has already sent), so z_{k+1} = M z_k with the first block row
    [A_d, 0, ..., B_d], the second [−F, 0, ...] and the shift below; d = 0 is A_d − B_d F.
    A_d, B_d may carry leading batch dimensions.
    """
    if delay == 0:
        return A_d - B_d @ F
    n, m = A_d.shape[-1], B_d.shape[-1]
    M = np.zeros(A_d.shape[:-2] + (n + delay * m, n + delay * m))
    M[..., :n, :n] = A_d
    M[..., :n, n + (delay - 1) * m:] = B_d
    M[..., n:n + m, :n] = -F
    for j in range(1, delay):
        M[..., n + j * m:n + (j + 1) * m, n + (j - 1) * m:n + j * m] = np.eye(m)
    return M


def thesis_gain_stability(T_s: float, *, omega_max: float = 200.0,
                          motor: MotorParams = THESIS_MOTOR,
                          points=None, sigma_min: float = DEFAULT_SIGMA_MIN,
                          delay: int = 0, K: Optional[np.ndarray] = None) -> Dict[str, float]:
    """
    Return the worst spectral radius of the sampled loop with the thesis's gains.

    Of the current loop and of the observer error. ``delay``: the plant's computational delay
    [periods] (:func:`delayed_closed_loop`); the observer, fed the voltage the motor got, keeps
    its error dynamics. ``K``: another current gain (2×2, e.g. a certified one) in the thesis's.
    """
    grid = parameter_grid(points or DEFAULT_CERTIFY_POINTS, omega_max, sigma_min=sigma_min)
    A_d, B_d = sampled_models(grid, T_s, motor)
    K_t, L = thesis_gains_sampled(T_s, motor)
    K = K_t if K is None else np.asarray(K, dtype=float)
    r_cur = float(np.abs(np.linalg.eigvals(delayed_closed_loop(A_d, B_d, K @ C_CURRENT,
                                                               delay))).max())
    r_obs = float(np.abs(np.linalg.eigvals(A_d - L @ C_CURRENT)).max())
    return {'T_s': T_s, 'current_loop_rho': r_cur, 'observer_rho': r_obs,
            'stable': bool(r_cur < 1.0 and r_obs < 1.0)}


def thesis_gain_stability_limit(*, omega_max: float = 200.0, motor: MotorParams = THESIS_MOTOR,
                                T_min: float = 1e-5, T_max: float = 2e-3, samples: int = 60,
                                points=None, refine_steps: int = 12,
                                delay: int = 0) -> Dict[str, object]:
    """
    Largest T_s at which the thesis's gains (K = 40 I, k_e = 1/σ) keep every model stable.

    ``delay``: the plant's computational delay [periods] (:func:`thesis_gain_stability`).

    Grid search over log-spaced T_s in [T_min, T_max], then bisection between the last stable and
    the first unstable sample, separately for the current loop and the observer. "Stable" means
    every eigenvalue inside the unit circle at every point of the parameter grid (eigenvalues only:
    this is not a quadratic-stability certificate, and it says nothing between grid points).
    """
    grid_T = np.geomspace(T_min, T_max, samples)
    table = [thesis_gain_stability(float(T), omega_max=omega_max, motor=motor, points=points,
                                   delay=delay) for T in grid_T]
    out: Dict[str, object] = {'omega_max': omega_max, 'table': table}
    for key in ('current_loop_rho', 'observer_rho'):
        stable = [row[key] < 1.0 for row in table]
        if not stable[0]:
            out[key.replace('_rho', '_limit')] = None
            continue
        k = next((i for i, s in enumerate(stable) if not s), None)
        if k is None:
            out[key.replace('_rho', '_limit')] = float(T_max)
            continue
        lo, hi = float(grid_T[k - 1]), float(grid_T[k])
        for _ in range(refine_steps):
            mid = math.sqrt(lo * hi)
            if thesis_gain_stability(mid, omega_max=omega_max, motor=motor,
                                     points=points, delay=delay)[key] < 1.0:
                lo = mid
            else:
                hi = mid
        out[key.replace('_rho', '_limit')] = lo
    limits = [out.get('current_loop_limit'), out.get('observer_limit')]
    out['limit'] = None if any(v is None for v in limits) else min(limits)
    return out
