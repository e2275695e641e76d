"""
Drive gains at the node period, posed the way the controller and observer use them.

The 4-state designs of :mod:`im_controller.gain_design.motor` ask one static gain to make the whole
(i, φ_r) ZOH model quadratically stable over the parameter box and ω_r ∈ [−ω_max, ω_max]. At 1 ms
that is infeasible (no common Lyapunov function, flux modes fixed by T_r). The controller does not
need it: it feeds forward the back-EMF and flux terms (seed 000 eq. 3.29), so the current gain only
has to stabilize the *stator-current error* subsystem. This module designs and certifies that (see
docs/robust.md, "Drive gains at the node period"):

Current loop. With V = V* + ΔV, ΔV_k = −K e_k, e = i − i*, the current error obeys

    σL_s de/dt = −R_eq e + ΔV + w,     R_eq = R_s + R_r (L_sr/L_r)²,

where w collects the model mismatch and the flux-error coupling (bounded; not part of the
certificate). In αβ the stator-current block of eq. 1.112 has no speed term, so the subsystem is
isotropic and independent of ω_r: its ZOH model at T_s is

    e_{k+1} = a e_k + b (ΔV_k + w̄_k),   a = exp(−R_eq T_s/σL_s),   b = (1 − a)/R_eq,

a 2×2 model (a I, b I) that depends on the parameters only through (R_eq, σL_s). K is designed by
seed 001's synthesis (state feedback, discrete, |λ| < ρ) over these models at a grid of the
parameter box ∩ {σ ≥ σ_min} and certified by :func:`im_robust.certificate.certify` on a dense grid.

Observer. The observer's discrete path (``injection_gain`` L) predicts with the plant copy and adds
L (i_k − î_k). With L = [ℓ I; 0] its current-error part is e⁺ = (a − ℓ) e (+ flux coupling): the
same scalar problem with b replaced by 1 (models (a I, I)). The full 4-state error
(A_d(p, ω) − L C) is then certified with the library's certificate: box-wide (one P for every
parameter point and speed) when that passes, otherwise per frozen parameter point with one P
common to every speed in [−ω_max, ω_max] (arbitrary speed variation, constant parameters).

Thesis's gains at the node period. Where they certify (100 µs) they are kept:
:func:`thesis_current_design` certifies K = 40 I on the same subsystem, and
:func:`certify_thesis_observer` certifies the observer in the thesis's structure (k_e = 1/σ̂ plus
the speed-scheduled skew injection). Its one-period error map is taken from
:class:`im_observer.observer.RotorFluxObserver` itself. Because the skew injection is held over
the period there is no common P over the speeds, so the certificate is per frozen parameter point
with an affine speed-dependent P(ω), valid for a bounded speed change per period. Where they do
not certify (1 ms), the synthesis above is used.

Scaling: per unit with i_b = 1 Wb/L_sr, V_b = v·ω_b·1 Wb
(:class:`im_controller.gain_design.motor.Scaling`).
"""
from __future__ import annotations

from dataclasses import dataclass, field
import math
import time
from typing import Dict, List, Optional, Sequence

from im_common.cli import gated_logger
from im_common.model import eq112_matrices
from im_common.params import MotorParams, THESIS_MOTOR
from im_observer.observer import RotorFluxObserver
from im_robust.certificate import analysis_lmi, best_rate, Certificate, certify
from im_robust.polytope import UncertainSystem
from im_robust.synthesis import SynthesisResult, synthesize
import numpy as np

from .motor import (C_CURRENT, DEFAULT_SIGMA_MIN, delayed_closed_loop, parameter_grid,
                    sampled_models, Scaling, THESIS_K1, zoh)

#: parameter grid of the (R_eq, σL_s) vertex models and of the dense certificate grid
SUBSYSTEM_VERTEX_POINTS = {'R_r': 2, 'L_s': 3, 'L_r': 3, 'L_sr': 5, 'omega_r': 1}
SUBSYSTEM_CERTIFY_POINTS = {'R_r': 7, 'L_s': 9, 'L_r': 9, 'L_sr': 13, 'omega_r': 1}
#: observer 4-state certificate: parameter points, speed vertices, dense speed grid
OBSERVER_PARAM_POINTS = {'R_r': 3, 'L_s': 3, 'L_r': 3, 'L_sr': 3, 'omega_r': 1}
OBSERVER_OMEGA_VERTICES = 17
OBSERVER_OMEGA_DENSE = 41
DEFAULT_RATE_FRACTION = 0.9
DEFAULT_OBSERVER_RATE = 1.0     # 1/s, 4-state observer error (flux modes decay with T_r)
FLUX_COUPLING_BUDGET = 0.1      # share of 1/T_r the held flux-coupling residual may use


_log = gated_logger('im_controller.gain_design.drive')


# ---------------------------------------------------------------------------------------------
# The current-error subsystem
# ---------------------------------------------------------------------------------------------
def subsystem_points(points=None, *, sigma_min: float = DEFAULT_SIGMA_MIN, box=None,
                     motor: MotorParams = THESIS_MOTOR) -> np.ndarray:
    """Rows (R_eq [Ω], σL_s [H]) at a grid of the parameter box ∩ {σ ≥ σ_min} (ω irrelevant)."""
    g = parameter_grid(points or SUBSYSTEM_VERTEX_POINTS, 0.0, box=box, sigma_min=sigma_min)
    R_r, L_s, L_r, L_sr = g[:, 0], g[:, 1], g[:, 2], g[:, 3]
    R_eq = motor.R_s + R_r * (L_sr / L_r) ** 2
    sLs = L_s - L_sr ** 2 / L_r
    return np.unique(np.round(np.stack([R_eq, sLs], axis=1), 12), axis=0)


def subsystem_ab(pts: np.ndarray, T_s: float):
    """ZOH scalars a = exp(−R_eq T_s/σL_s), b = (1 − a)/R_eq [A/(V·step)] at rows (R_eq, σL_s)."""
    R_eq, sLs = pts[:, 0], pts[:, 1]
    a = np.exp(-R_eq * T_s / sLs)
    return a, -np.expm1(-R_eq * T_s / sLs) / R_eq


def current_error_radius(pts: np.ndarray, T_s: float, K, delay: int = 0) -> np.ndarray:
    """
    Return the spectral radius of the sampled current-error loop at each row (R_eq, σL_s).

    e_{k+1} = a e_k − b K e_{k−d}, a = e^{−R_eq T_s/σL_s}, b = (1 − a)/R_eq (:func:`subsystem_ab`),
    K the 2×2 voltage gain [V/A] (the thesis's 40 I, a certified one) and d the plant's
    computational delay (docs/plant.md §10): the roots of z^{d+1} − a z^d + b k for K = k I. One
    delay halves the stable period: b k < 1 instead of a − b k > −1 (docs/plant.md §10).
    """
    a, b = subsystem_ab(np.atleast_2d(pts), T_s)
    eye = np.eye(2)
    M = delayed_closed_loop(a[:, None, None] * eye, b[:, None, None] * eye,
                            np.asarray(K, dtype=float), delay)
    return np.abs(np.linalg.eigvals(M)).max(axis=1)


def current_error_limit(pts: np.ndarray, K, delay: int = 0, *, T_min: float = 1e-6,
                        T_max: float = 1e-2, tol: float = 1e-9) -> float:
    """
    Return the longest period [s] at which the current-error loop is stable at every row of pts.

    Bisection on :func:`current_error_radius` < 1 (stable at T_min, unstable at T_max assumed,
    else ValueError); ``tol`` [s].
    """
    def stable(T):
        return bool(current_error_radius(pts, T, K, delay).max() < 1.0)
    lo, hi = T_min, T_max
    if not stable(lo) or stable(hi):
        raise ValueError(f'no stability limit between {T_min:g} s and {T_max:g} s')
    while hi - lo > tol:
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if stable(mid) else (lo, mid)
    return lo


def current_error_system(pts: np.ndarray, T_s: float, *, injection: str = 'voltage',
                         motor: MotorParams = THESIS_MOTOR, name: str = '') -> UncertainSystem:
    """
    Per-unit 2×2 models of the current error.

    (a I, b̃ I) for a voltage gain, (a I, I) for the observer's direct current-error injection.
    State feedback (C = I).
    """
    sc = Scaling.for_motor(motor)
    a, b = subsystem_ab(pts, T_s)
    if injection == 'voltage':
        b = b * sc.v_base / sc.i_base
    elif injection == 'direct':
        b = np.ones_like(a)
    else:
        raise ValueError(f"injection must be 'voltage' or 'direct', got {injection!r}")
    I = np.eye(2)  # noqa: E741 (the identity matrix, as in the equations)
    return UncertainSystem([(ak * I, bk * I) for ak, bk in zip(a, b)], None, discrete=True,
                           name=name or f'current error ({injection}) T_s={T_s:g}')


def _gain_to_si(G: np.ndarray, injection: str, motor: MotorParams) -> np.ndarray:
    sc = Scaling.for_motor(motor)
    return G * (sc.v_base / sc.i_base) if injection == 'voltage' else G.copy()


@dataclass
class LoopDesign:
    """A certified 2×2 gain of the current-error subsystem (SI), or None with the reason."""

    loop: str                      # 'current' (V/A) or 'observer-current' (dimensionless)
    T_s: float
    injection: str
    decay_rate: float              # requested α [1/s]: certified |λ| and Lyapunov ρ < exp(−α T_s)
    best_rate: Optional[float]     # largest α for which the synthesis is feasible [1/s]
    gain: Optional[np.ndarray]
    result: Optional[SynthesisResult]
    vertex_models: int
    certificate_models: int
    sigma_min: float
    range_R_eq: tuple = ()
    range_sigma_L_s: tuple = ()
    dense_spectral_radius: Optional[float] = None
    notes: List[str] = field(default_factory=list)
    source: str = 'synthesis'      # or 'thesis gain' (the thesis's gain, certified as it is)

    @property
    def certified(self) -> bool:
        return self.gain is not None

    @property
    def certificate(self) -> Optional[Certificate]:
        return None if self.result is None else self.result.certificate

    @property
    def rho(self) -> float:
        return math.exp(-self.decay_rate * self.T_s)

    def summary(self) -> dict:
        c = self.certificate
        rho_dense = None if c is None or c.grid_margin is None else float(self.rho - c.grid_margin)
        return {
            'loop': self.loop, 'T_s': self.T_s, 'injection': self.injection, 'source': self.source,
            'status': 'no design' if self.result is None else self.result.status,
            'certified': self.certified,
            'gain': None if self.gain is None else self.gain.tolist(),
            'decay_rate_requested': self.decay_rate, 'rho_requested': self.rho,
            'best_feasible_rate': self.best_rate,
            'lyapunov_rho_vertices': None if c is None else float(c.rate),
            'lyapunov_rho_dense': rho_dense,
            'certified_rate_dense': None if rho_dense is None or rho_dense <= 0
            else -math.log(rho_dense) / self.T_s,
            'dense_spectral_radius': self.dense_spectral_radius,
            'vertex_models': self.vertex_models, 'certificate_models': self.certificate_models,
            'sigma_min': self.sigma_min, 'R_eq_range': list(self.range_R_eq),
            'sigma_L_s_range': list(self.range_sigma_L_s),
            'message': '' if self.result is None else self.result.message, 'notes': self.notes,
        }


def _feasible(system: UncertainSystem, rho: float) -> bool:
    res = synthesize(system, solver='clarabel', rho=rho, margin=1e-6, normalization='thesis')
    return res.status == 'certified'


def best_feasible_rate(system: UncertainSystem, T_s: float, *, iterations: int = 11) -> float:
    """
    Return the largest decay rate α for which a certified current gain exists.

    Largest α [1/s] (bisection on ρ = exp(−α T_s)) for which (3.33) yields a certified gain on the
    vertex models; 0 if even ρ = 1 fails.
    """
    if not _feasible(system, 1.0):
        return 0.0
    lo, hi = 0.0, 1.0     # ρ: infeasible ≤ lo, feasible ≥ hi
    for _ in range(iterations):
        mid = 0.5 * (lo + hi)
        if _feasible(system, mid):
            hi = mid
        else:
            lo = mid
    return -math.log(hi) / T_s


def design_subsystem_gain(T_s: float, *, injection: str = 'voltage',
                          decay_rate: Optional[float] = None,
                          rate_fraction: float = DEFAULT_RATE_FRACTION,
                          sigma_min: float = DEFAULT_SIGMA_MIN, motor: MotorParams = THESIS_MOTOR,
                          vertex_points=None, certify_points=None, design_reserve: float = 0.02,
                          progress: bool = False) -> LoopDesign:
    """
    Certified 2×2 gain of the current-error subsystem at T_s.

    ``decay_rate`` None: ``rate_fraction`` × the largest feasible rate (bisection). The synthesis
    is asked for (1 + ``design_reserve``)·α at the vertex models and the certificate checks α at
    the vertices and on the dense grid (the sampled (a, b) curve bulges out of the hull of its
    samples).
    """
    if not (math.isfinite(T_s) and T_s > 0):
        raise ValueError(f'T_s = {T_s!r} must be a positive period in seconds')
    loop = 'current' if injection == 'voltage' else 'observer-current'
    vp = subsystem_points(vertex_points, sigma_min=sigma_min, motor=motor)
    cp = subsystem_points(certify_points or SUBSYSTEM_CERTIFY_POINTS, sigma_min=sigma_min,
                          motor=motor)
    sysm = current_error_system(vp, T_s, injection=injection, motor=motor)
    dense = current_error_system(cp, T_s, injection=injection, motor=motor).models
    best = None
    if decay_rate is None:
        t0 = time.perf_counter()
        best = best_feasible_rate(sysm, T_s)
        decay_rate = rate_fraction * best
        _log(progress, f'{loop} T_s = {T_s:g} s: best feasible rate {best:.1f} 1/s '
                       f'({time.perf_counter() - t0:.1f} s); designing for {decay_rate:.1f} 1/s')
    if not decay_rate >= 0:
        raise ValueError(f'decay_rate = {decay_rate!r} must be >= 0')
    rho = math.exp(-decay_rate * T_s)
    rho_design = math.exp(-(1.0 + design_reserve) * decay_rate * T_s)
    res = synthesize(sysm, solver='clarabel', rho=rho_design, margin=1e-6, normalization='thesis',
                     grid_models=dense, certify_rho=rho)
    _log(progress, f'{loop}: {res.status} ({res.solver_status}) {res.message}')
    d = LoopDesign(loop, T_s, injection, float(decay_rate), best, None, res, len(vp), len(cp),
                   sigma_min, (float(cp[:, 0].min()), float(cp[:, 0].max())),
                   (float(cp[:, 1].min()), float(cp[:, 1].max())))
    if res.status == 'certified':
        d.gain = _gain_to_si(res.G, injection, motor)
        d.dense_spectral_radius = float(max(np.abs(np.linalg.eigvals(A - B @ res.G)).max()
                                            for A, B in dense))
    return d


def _subsystem_models(T_s, sigma_min, motor, vertex_points, certify_points):
    """
    Set up the current-error subsystem for the gain design.

    (scaling, vertex points, dense points, vertex system, dense certification models) of the
    current-error subsystem.
    """
    sc = Scaling.for_motor(motor)
    vp = subsystem_points(vertex_points, sigma_min=sigma_min, motor=motor)
    cp = subsystem_points(certify_points or SUBSYSTEM_CERTIFY_POINTS, sigma_min=sigma_min,
                          motor=motor)
    sysm = current_error_system(vp, T_s, motor=motor)
    return sc, vp, cp, sysm, current_error_system(cp, T_s, motor=motor).models


def certify_current_gain(K, T_s: float, *, decay_rate: float = 0.0,
                         sigma_min: float = DEFAULT_SIGMA_MIN, motor: MotorParams = THESIS_MOTOR,
                         vertex_points=None, certify_points=None) -> Certificate:
    """Return the library's certificate for a current gain K [V/A] on the subsystem at T_s."""
    sc, vp, cp, sysm, dense = _subsystem_models(T_s, sigma_min, motor, vertex_points,
                                                certify_points)
    G = np.asarray(K, dtype=float) * (sc.i_base / sc.v_base)
    return certify(sysm, G, rho=math.exp(-decay_rate * T_s), grid_models=dense)


def thesis_current_design(T_s: float, *, k: float = THESIS_K1,
                          rate_fraction: float = DEFAULT_RATE_FRACTION,
                          sigma_min: float = DEFAULT_SIGMA_MIN, motor: MotorParams = THESIS_MOTOR,
                          vertex_points=None, certify_points=None,
                          progress: bool = False) -> Optional[LoopDesign]:
    """
    Return the thesis's current gain K = k I, certified as it is on the current-error subsystem.

    The largest rate α_k for which a common P exists at the vertex models is found by bisection
    (:func:`im_robust.certificate.best_rate`); K is then certified at ``rate_fraction``·α_k on the
    vertices *and* the dense grid. Returns None when K is not certified even at ρ = 1 (at 1 ms:
    its sampled pole leaves the unit circle), so the caller falls back to the synthesis.
    """
    sc, vp, cp, sysm, dense = _subsystem_models(T_s, sigma_min, motor, vertex_points,
                                                certify_points)
    K = k * np.eye(2)
    G = K * (sc.i_base / sc.v_base)
    rho_best = best_rate(sysm, G)
    if not (math.isfinite(rho_best) and 0.0 < rho_best < 1.0):
        _log(progress, f'current T_s = {T_s:g}: the thesis gain {k:g} I is not certified')
        return None
    best = -math.log(rho_best) / T_s
    alpha = rate_fraction * best
    cert = certify(sysm, G, rho=math.exp(-alpha * T_s), grid_models=dense)
    if not cert.certified:
        _log(progress, f'current T_s = {T_s:g}: thesis gain fails the dense grid ({cert.reason})')
        return None
    res = SynthesisResult('certified', 'analysis-lmi', 'thesis gain certified', G=G,
                          certificate=cert,
                          message=f'thesis gain {k:g} I certified at {alpha:.1f} 1/s '
                                  f'({rate_fraction:g} x its best vertex rate {best:.1f} 1/s)')
    d = LoopDesign('current', T_s, 'voltage', float(alpha), float(best), K, res, len(vp), len(cp),
                   sigma_min, (float(cp[:, 0].min()), float(cp[:, 0].max())),
                   (float(cp[:, 1].min()), float(cp[:, 1].max())), source='thesis gain')
    d.dense_spectral_radius = float(max(np.abs(np.linalg.eigvals(A - B @ G)).max()
                                        for A, B in dense))
    d.notes.append('best_feasible_rate is the best certified vertex rate of the thesis gain')
    _log(progress, f'current T_s = {T_s:g}: {res.message}')
    return d


# ---------------------------------------------------------------------------------------------
# The current-error subsystem with the computational delay (docs/plant.md §10)
# ---------------------------------------------------------------------------------------------
def delayed_current_error_system(pts: np.ndarray, T_s: float, delay: int, *,
                                 motor: MotorParams = THESIS_MOTOR) -> UncertainSystem:
    """
    Per-unit models of the current error with ``delay`` periods, the commands sent as states.

    z_k = [e_k; u_{k−1}; ...; u_{k−d}] (what the DSP has sent and the motor has not yet got):
    e_{k+1} = a e_k + b u_{k−d}, the new command u_k enters the second block, the rest shift
    (:func:`im_controller.gain_design.motor.delayed_closed_loop`'s state). d = 0 is
    :func:`current_error_system`. A gain on z is any law that may use its own past commands.
    """
    if delay == 0:
        return current_error_system(pts, T_s, motor=motor)
    sc = Scaling.for_motor(motor)
    a, b = subsystem_ab(pts, T_s)
    b = b * sc.v_base / sc.i_base
    n = 2 + 2 * delay
    I = np.eye(2)  # noqa: E741 (the identity matrix, as in the equations)
    B = np.zeros((n, 2))
    B[2:4] = I
    models = []
    for ak, bk in zip(a, b):
        A = np.zeros((n, n))
        A[:2, :2], A[:2, n - 2:] = ak * I, bk * I
        for j in range(1, delay):
            A[2 + 2 * j:4 + 2 * j, 2 * j:2 + 2 * j] = I
        models.append((A, B))
    return UncertainSystem(models, None, discrete=True,
                           name=f'current error, delay {delay}, T_s={T_s:g}')


def nominal_point(motor: MotorParams = THESIS_MOTOR) -> np.ndarray:
    """Return the row (R_eq, σL_s) of a motor's nominal parameters."""
    return np.array([[motor.R_s + motor.R_r * (motor.L_sr / motor.L_r) ** 2,
                      motor.L_s - motor.L_sr ** 2 / motor.L_r]])


def predicting_gain(K, T_s: float, delay: int, *, motor: MotorParams = THESIS_MOTOR
                    ) -> np.ndarray:
    """
    Return the thesis law told the delay as a per-unit gain on z_k.

    z_k as in :func:`delayed_current_error_system`. The law (im_controller.control_law,
    docs/plant.md §10) acts on the error predicted to the moment its command acts,
    ê_{k+d} = a₀^d e_k + Σ_{j=1..d} a₀^{j−1} b₀ u_{k−j} on the nominal model (a₀, b₀) of
    ``motor``: u_k = −K ê_{k+d}, the gain K [a₀^d, b₀, a₀b₀, ..., a₀^{d−1}b₀].
    """
    sc = Scaling.for_motor(motor)
    a0, b0 = subsystem_ab(nominal_point(motor), T_s)
    a0, b0 = float(a0[0]), float(b0[0]) * sc.v_base / sc.i_base
    G = np.asarray(K, dtype=float) * (sc.i_base / sc.v_base)
    row = [a0 ** delay] + [a0 ** (j - 1) * b0 for j in range(1, delay + 1)]
    return np.hstack([c * G for c in row])


@dataclass
class DelayedCurrentLoop:
    """What the delay leaves of a current gain's certificate (:func:`delayed_current_design`)."""

    T_s: float
    delay: int
    K: np.ndarray                   # the gain examined [V/A]
    rate: float                     # its certified decay rate, the law predicting [1/s] (0: none)
    rate_undelayed: float           # the same gain without the delay [1/s]
    k_best: float                   # the predicting law's best K = k I [V/A]
    rate_best: float                # its certified rate [1/s]
    rate_bound: float               # the best any gain on z certifies (synthesis) [1/s]
    dense_spectral_radius: float    # of K predicting, over the dense grid
    notes: List[str] = field(default_factory=list)

    def summary(self) -> dict:
        return {'T_s': self.T_s, 'delay': self.delay, 'K': np.asarray(self.K).tolist(),
                'rate': self.rate, 'rate_undelayed': self.rate_undelayed,
                'k_best': self.k_best, 'rate_best': self.rate_best,
                'rate_bound': self.rate_bound,
                'dense_spectral_radius': self.dense_spectral_radius, 'notes': self.notes}


def _rate(rho: float, T_s: float) -> float:
    return -math.log(rho) / T_s if math.isfinite(rho) and 0.0 < rho < 1.0 else 0.0


def predicting_rate(K, T_s: float, delay: int, *, motor: MotorParams = THESIS_MOTOR,
                    vertex_points=None, sigma_min: float = DEFAULT_SIGMA_MIN,
                    iterations: int = 20) -> float:
    """
    Return the decay rate [1/s] certified for K with the law predicting across ``delay``.

    One quadratic Lyapunov function over the vertex models of the delayed subsystem
    (:func:`im_robust.certificate.best_rate`); 0 when none exists even at ρ = 1.
    """
    vp = subsystem_points(vertex_points, sigma_min=sigma_min, motor=motor)
    sysm = delayed_current_error_system(vp, T_s, delay, motor=motor)
    return _rate(best_rate(sysm, predicting_gain(K, T_s, delay, motor=motor),
                           iterations=iterations), T_s)


def delayed_rate_bound(T_s: float, delay: int, *, motor: MotorParams = THESIS_MOTOR,
                       vertex_points=None, sigma_min: float = DEFAULT_SIGMA_MIN,
                       iterations: int = 12) -> float:
    """
    Return the best decay rate [1/s] seed 001's synthesis certifies on the delayed subsystem.

    Any static gain on z_k = [e_k; past commands]: the bound for every law that acts on the
    current error and its own commands, the predicting thesis law among them.
    """
    vp = subsystem_points(vertex_points, sigma_min=sigma_min, motor=motor)
    return best_feasible_rate(delayed_current_error_system(vp, T_s, delay, motor=motor), T_s,
                              iterations=iterations)


def delayed_current_design(K, T_s: float, delay: int = 1, *, motor: MotorParams = THESIS_MOTOR,
                           k_range: Optional[Sequence[float]] = None, vertex_points=None,
                           certify_points=None, sigma_min: float = DEFAULT_SIGMA_MIN,
                           progress: bool = False) -> DelayedCurrentLoop:
    """
    Certify a current gain K under ``delay`` and design the predicting law's K = k I for it.

    K's certified rate with and without the delay; the k in ``k_range`` (default: 0.05-2 × the
    diagonal mean of K) that certifies the fastest decay with the delay (golden section on log k
    of :func:`predicting_rate`; a k with no certificate scores 0); the synthesis bound
    (:func:`delayed_rate_bound`); K's spectral radius over the dense grid.
    """
    if not (isinstance(delay, int) and delay >= 1):
        raise ValueError(f'delay = {delay!r} must be an integer >= 1 (periods)')
    K = np.asarray(K, dtype=float)
    kw = {'motor': motor, 'vertex_points': vertex_points, 'sigma_min': sigma_min}
    k0 = float(np.trace(K)) / 2.0
    lo, hi = (0.05 * k0, 2.0 * k0) if k_range is None else map(float, k_range)
    if not 0.0 < lo < hi:
        raise ValueError(f'k_range = ({lo!r}, {hi!r}) must be 0 < low < high [V/A]')

    def score(log_k):
        return predicting_rate(math.exp(log_k) * np.eye(2), T_s, delay, iterations=14, **kw)
    x0, x1 = math.log(lo), math.log(hi)
    g = (math.sqrt(5.0) - 1.0) / 2.0
    c, d = x1 - g * (x1 - x0), x0 + g * (x1 - x0)
    fc, fd = score(c), score(d)
    for _ in range(14):
        if fc >= fd:
            x1, d, fd = d, c, fc
            c = x1 - g * (x1 - x0)
            fc = score(c)
        else:
            x0, c, fc = c, d, fd
            d = x0 + g * (x1 - x0)
            fd = score(d)
    k_best = math.exp(c if fc >= fd else d)
    cp = subsystem_points(certify_points or SUBSYSTEM_CERTIFY_POINTS, sigma_min=sigma_min,
                          motor=motor)
    G = predicting_gain(K, T_s, delay, motor=motor)
    dense = delayed_current_error_system(cp, T_s, delay, motor=motor).models
    out = DelayedCurrentLoop(
        T_s, delay, K, predicting_rate(K, T_s, delay, **kw), predicting_rate(K, T_s, 0, **kw),
        k_best, predicting_rate(k_best * np.eye(2), T_s, delay, **kw),
        delayed_rate_bound(T_s, delay, **kw),
        float(max(np.abs(np.linalg.eigvals(A - B @ G)).max() for A, B in dense)))
    _log(progress, f'current T_s = {T_s:g}, delay {delay}: K certified at {out.rate:.1f} 1/s '
                   f'(undelayed {out.rate_undelayed:.1f}); best k = {k_best:.4g} V/A at '
                   f'{out.rate_best:.1f} 1/s; bound {out.rate_bound:.1f} 1/s')
    return out


# ---------------------------------------------------------------------------------------------
# The observer's 4-state error with a discrete injection
# ---------------------------------------------------------------------------------------------
def _observer_system(A_d: np.ndarray, sc: Scaling, name: str) -> UncertainSystem:
    """Models (Ã, I₄), C̃ = S_y⁻¹ C S, so Ã − I G̃ C̃ = S⁻¹ (A_d − L C) S with G̃ = S⁻¹ L S_y."""
    S, Si = sc.S, np.linalg.inv(sc.S)
    Ct = np.linalg.inv(sc.S_y) @ C_CURRENT @ S
    return UncertainSystem([(Si @ A @ S, np.eye(4)) for A in A_d], Ct, discrete=True, name=name)


@dataclass
class ObserverCertificate:
    """
    Certificate of x̂⁺ = A_d x̂ + B_d V + L (i − î).

    Scope 'box' (one P for every parameter point and speed) or 'frozen-parameter' (one P per
    parameter point, common to every speed).
    """

    certified: bool
    scope: str
    T_s: float
    omega_max: float
    decay_rate: float
    worst_rho_vertices: Optional[float]
    worst_rho_dense: Optional[float]
    worst_spectral_radius: Optional[float]
    parameter_points: int
    models: int
    box_reason: str = ''
    reason: str = ''
    wall_s: float = 0.0

    def summary(self) -> dict:
        return dict(self.__dict__)


def _certify_strict(system: UncertainSystem, G, rho: float, decay_rate: float, T_s: float,
                    dense) -> Certificate:
    """
    Certify with a P that leaves margin above the LMI's numerical floor.

    certify() at ρ with P taken from the analysis LMI at a 1.5× stricter rate, so the margin is not
    left at the LMI's numerical floor; certify() falls back to its own P if that fails.
    """
    strict = math.exp(-1.5 * decay_rate * T_s) if decay_rate > 0 else rho
    P = analysis_lmi(system.closed_loops(G), True, rho=strict)
    return certify(system, G, rho=rho, P=P, grid_models=dense)


def certify_observer_gain(L, T_s: float, *, omega_max: float = 200.0,
                          decay_rate: float = DEFAULT_OBSERVER_RATE,
                          sigma_min: float = DEFAULT_SIGMA_MIN, motor: MotorParams = THESIS_MOTOR,
                          param_points=None, omega_vertices: int = OBSERVER_OMEGA_VERTICES,
                          omega_dense: int = OBSERVER_OMEGA_DENSE,
                          progress: bool = False) -> ObserverCertificate:
    """
    Certify the 4-state observer error e⁺ = (A_d(p, ω) − L C) e with the library's certificate.

    First box-wide (vertex models: parameter grid × ``omega_vertices`` speeds, dense check:
    ``omega_dense`` speeds at the same parameter points); if no common P exists, per frozen
    parameter point (one P for all speeds, checked on the dense speed grid).
    """
    t0 = time.perf_counter()
    sc = Scaling.for_motor(motor)
    L = np.asarray(L, dtype=float).reshape(4, 2)
    G = np.linalg.inv(sc.S) @ L @ sc.S_y
    rho = math.exp(-decay_rate * T_s)
    pts = parameter_grid(param_points or OBSERVER_PARAM_POINTS, 0.0, sigma_min=sigma_min)
    nom = np.array([[motor.R_r, motor.L_s, motor.L_r, motor.L_sr, 0.0]])
    pts = np.vstack([pts, nom])
    w_v = np.linspace(-omega_max, omega_max, omega_vertices) if omega_max > 0 else np.zeros(1)
    w_d = np.linspace(-omega_max, omega_max, omega_dense) if omega_max > 0 else np.zeros(1)

    def models(ws):
        g = np.array([(*p[:4], w) for p in pts for w in ws])
        A, _ = sampled_models(g, T_s, motor)
        return A.reshape(len(pts), len(ws), 4, 4)

    A_v, A_d = models(w_v), models(w_d)
    spec = float(np.abs(np.linalg.eigvals(A_d - L @ C_CURRENT)).max())
    n_models = A_v.shape[0] * A_v.shape[1] + A_d.shape[0] * A_d.shape[1]
    box = _observer_system(A_v.reshape(-1, 4, 4), sc, 'observer error (box)')
    dense = _observer_system(A_d.reshape(-1, 4, 4), sc, 'dense').models
    cert = _certify_strict(box, G, rho, decay_rate, T_s, dense)
    if cert.certified:
        _log(progress, f'observer T_s = {T_s:g}: certified box-wide, rho_c = {cert.rate:.6f}')
        return ObserverCertificate(True, 'box', T_s, omega_max, decay_rate, float(cert.rate),
                                   float(rho - cert.grid_margin), spec, len(pts), n_models,
                                   wall_s=time.perf_counter() - t0)
    box_reason = cert.reason
    _log(progress, f'observer T_s = {T_s:g}: no box-wide P ({box_reason}); '
                   f'certifying {len(pts)} frozen parameter points over the speed range')
    worst_v = worst_d = 0.0
    for k in range(len(pts)):
        s = _observer_system(A_v[k], sc, f'observer error at p{k}')
        c = _certify_strict(s, G, rho, decay_rate, T_s,
                            _observer_system(A_d[k], sc, 'dense').models)
        if not c.certified:
            return ObserverCertificate(False, 'frozen-parameter', T_s, omega_max, decay_rate, None,
                                       None, spec, len(pts), n_models, box_reason,
                                       f'parameter point {pts[k, :4].tolist()}: {c.reason}',
                                       time.perf_counter() - t0)
        worst_v = max(worst_v, float(c.rate))
        worst_d = max(worst_d, float(rho - c.grid_margin))
    _log(progress, f'observer: certified per frozen parameter point, worst rho_c = {worst_d:.8f}')
    return ObserverCertificate(True, 'frozen-parameter', T_s, omega_max, decay_rate, worst_v,
                               worst_d, spec, len(pts), n_models, box_reason,
                               wall_s=time.perf_counter() - t0)


# ---------------------------------------------------------------------------------------------
# The observer in the thesis's structure (k_e + speed-scheduled skew injection), sampled
# ---------------------------------------------------------------------------------------------
#: largest speed change per period |ω_{k+1} − ω_k| [rad/s] the speed-dependent certificate allows
#: (20 rad/s per 100 µs is 2·10⁵ rad/s²; the chapter-3 tasks reach 0.014 rad/s per 100 µs)
THESIS_OBSERVER_SPEED_STEP = 20.0


def thesis_observer_error_map(point: Sequence[float], omega_r: float, T_s: float, k_e: float, *,
                              motor: MotorParams = THESIS_MOTOR, max_substep: float = 1e-4,
                              skew_injection: bool = True) -> np.ndarray:
    """
    Return the observer's own one-period error map M.

    M (SI, 4×4) is built column by column from
    :class:`im_observer.observer.RotorFluxObserver` (thesis structure, ``k_e`` fixed, skew
    injection on) with model parameters ``point`` = (R_r, L_s, L_r, L_sr) and R_s of ``motor``.

    With the measured current and speed held over the period the observer is linear in its state:
    x̂⁺ = Φ x̂ + Γ (B V + H (i − C x̂)), H = [k_e/(σL_s) I; vωL_sr 𝒥], Φ, Γ its RK4 sub-step
    propagators. Stepping it from x̂ = unit vector j with V = 0 and i = 0 returns column j of
    M = Φ − Γ H C, which is also the map of the difference of two observers fed the same data.
    With k_e = 0 and ``skew_injection=False`` it returns the prediction Φ alone.
    """
    R_r, L_s, L_r, L_sr = (float(v) for v in point[:4])
    mp = MotorParams(R_s=motor.R_s, R_r=R_r, L_s=L_s, L_r=L_r, L_sr=L_sr, J=motor.J, b=motor.b,
                     pole_pairs=motor.pole_pairs)
    M = np.empty((4, 4))
    for j in range(4):
        x0 = [0.0, 0.0, 0.0, 0.0]
        x0[j] = 1.0
        obs = RotorFluxObserver(mp, k_e=k_e, max_substep=max_substep, x0=x0,
                                skew_injection=skew_injection)
        M[:, j] = obs.step(T_s, 0.0, 0.0, 0.0, 0.0, float(omega_r))
    return M


def held_injection_zoh_map(point: Sequence[float], omega_r: float, T_s: float, k_e: float, *,
                           motor: MotorParams = THESIS_MOTOR):
    """
    Return the held-injection error map with the period integrated exactly.

    (M_zoh, A_d): the same held-injection map with the period integrated exactly, M_zoh = A_d − Γ_d
    H C, Γ_d = ∫₀^{T_s} e^{Aτ}dτ — the error map if the observer's prediction were the plant's
    exact ZOH flow.
    """
    R_r, L_s, L_r, L_sr = (float(v) for v in point[:4])
    A, _ = eq112_matrices(motor.R_s, R_r, L_s, L_r, L_sr, motor.pole_pairs, float(omega_r))
    sLs = L_s - L_sr ** 2 / L_r
    J = np.array([[0.0, -1.0], [1.0, 0.0]])
    H = np.vstack([k_e / sLs * np.eye(2), motor.pole_pairs * omega_r * L_sr * J])
    A_d, GH = zoh(A, H, T_s)
    return A_d - GH @ C_CURRENT, A_d


@dataclass
class ThesisObserverCertificate:
    """
    Certificate of the sampled thesis-structure observer (k_e, skew injection) at T_s.

    Scope 'frozen-parameter, speed-dependent P': at each parameter point one
    P(ω) = P₀ + (ω/ω_max) P₁ ≻ 0 with ‖M(ω)‖ contracting from P(ω) to P(ω') by ρ for every
    |ω' − ω| ≤ ``speed_step`` — V_k = e_kᵀ P(ω_k) e_k decays by ρ² per step along any speed
    trajectory in [−ω_max, ω_max] whose per-period change is at most ``speed_step``.
    """

    certified: bool
    T_s: float
    k_e: float
    omega_max: float
    speed_step: float
    decay_rate: float
    scope: str
    worst_rho_vertices: Optional[float]
    worst_rho_dense: Optional[float]
    worst_spectral_radius: Optional[float]
    common_P_over_speed: Optional[bool]      # at the nominal point, ρ = 1 (checked, not assumed)
    rk4_vs_zoh_map: Optional[float]          # max ‖S⁻¹(M_rk4 − M_zoh)S‖₂, per unit
    model_residual: Optional[float]          # max ‖S⁻¹(A_d − Φ_rk4)S‖₂, per unit
    worst_P_condition: Optional[float]
    parameter_points: int
    models: int
    reason: str = ''
    wall_s: float = 0.0

    def summary(self) -> dict:
        return dict(self.__dict__)


def _speed_dependent_P(Ms: Sequence[np.ndarray], ws: np.ndarray, omega_max: float, step: float,
                       rho: float):
    """
    Find a speed-scheduled Lyapunov matrix P(ω) for the observer error maps.

    (P₀, P₁) of P(ω) = P₀ + (ω/ω_max)P₁ with P(±ω_max) ⪰ I and, at every (M, ω), Mᵀ P(ω') M ⪯ ρ²
    P(ω) for ω' = ω ± step (clipped to the range); None if the SDP fails. For fixed ω the
    inequality is affine in ω', so the two ends cover every |ω' − ω| ≤ step.
    """
    import cvxpy as cp  # heavy: cvxpy only when an LMI is solved
    n = 4
    P0 = cp.Variable((n, n), symmetric=True)
    P1 = cp.Variable((n, n), symmetric=True)
    s = cp.Variable()
    I = np.eye(n)  # noqa: E741 (the identity matrix, as in the equations)

    def P(w):
        return P0 + (w / omega_max) * P1
    cons = [P(omega_max) >> I, P(-omega_max) >> I, P(omega_max) << s * I, P(-omega_max) << s * I]
    for M, w in zip(Ms, ws):
        for wp in {max(-omega_max, w - step), min(omega_max, w + step)}:
            Q = P(wp)
            cons.append(cp.bmat([[rho ** 2 * P(w) - 1e-6 * I, M.T @ Q], [Q @ M, Q]]) >> 0)
    prob = cp.Problem(cp.Minimize(s), cons)
    try:
        prob.solve(solver='CLARABEL')
    except Exception:  # a solver failure is a non-certificate
        return None
    if P0.value is None or prob.status not in ('optimal', 'optimal_inaccurate'):
        return None
    return 0.5 * (P0.value + P0.value.T), 0.5 * (P1.value + P1.value.T)


def _speed_dependent_rate(P0, P1, Ms, ws, omega_max: float, step: float):
    """
    Check a speed-scheduled P(ω) numerically.

    (worst ρ_c, worst cond P) of e ↦ M e from P(ω) to P(ω'), ω' ∈ {ω − step, ω, ω + step} clipped,
    with numpy eigenvalues; (inf, inf) if some P(ω) is not positive definite.
    """
    worst, cond = 0.0, 0.0
    for M, w in zip(Ms, ws):
        lam, V = np.linalg.eigh(P0 + (w / omega_max) * P1)
        if lam.min() <= 0.0:
            return math.inf, math.inf
        cond = max(cond, lam.max() / lam.min())
        Pih = (V / np.sqrt(lam)) @ V.T
        for wp in (max(-omega_max, w - step), w, min(omega_max, w + step)):
            Q = P0 + (wp / omega_max) * P1
            worst = max(worst,
                        math.sqrt(max(0.0, np.linalg.eigvalsh(Pih @ M.T @ Q @ M @ Pih).max())))
    return worst, cond


def _observer_grid(motor: MotorParams, param_points, sigma_min: float, omega_max: float,
                   omega_vertices: int, omega_dense: int):
    """Return the observer's parameter points (the nominal motor last), vertex and dense speeds."""
    pts = parameter_grid(param_points or OBSERVER_PARAM_POINTS, 0.0, sigma_min=sigma_min)[:, :4]
    pts = np.vstack([pts, [[motor.R_r, motor.L_s, motor.L_r, motor.L_sr]]])
    w_v = np.linspace(-omega_max, omega_max, omega_vertices) if omega_max > 0 else np.zeros(1)
    w_d = np.linspace(-omega_max, omega_max, omega_dense) if omega_max > 0 else np.zeros(1)
    return pts, w_v, w_d


def _dense_maps(pts, w_d, T_s: float, k_e: float, motor: MotorParams, max_substep: float, pu):
    """
    Return the error maps on the dense speeds, RK4 and held-injection ZOH, both per unit (``pu``).

    Also the largest difference of the two and the largest model residual (A_d − Φ), per unit.
    """
    Md, Mz = [], []
    diff = resid = 0.0
    for p in pts:
        row, rowz = [], []
        for w in w_d:
            M = pu(thesis_observer_error_map(p, w, T_s, k_e, motor=motor, max_substep=max_substep))
            Mzoh, A_d = held_injection_zoh_map(p, w, T_s, k_e, motor=motor)
            Phi = thesis_observer_error_map(p, w, T_s, 0.0, motor=motor, max_substep=max_substep,
                                            skew_injection=False)
            row.append(M)
            rowz.append(pu(Mzoh))
            diff = max(diff, float(np.linalg.norm(M - pu(Mzoh), 2)))
            resid = max(resid, float(np.linalg.norm(pu(A_d - Phi), 2)))
        Md.append(row)
        Mz.append(rowz)
    return Md, Mz, diff, resid


def certify_thesis_observer(T_s: float, *, k_e: Optional[float] = None, omega_max: float = 200.0,
                            speed_step: float = THESIS_OBSERVER_SPEED_STEP,
                            decay_rate: float = DEFAULT_OBSERVER_RATE,
                            sigma_min: float = DEFAULT_SIGMA_MIN,
                            motor: MotorParams = THESIS_MOTOR,
                            param_points=None, omega_vertices: int = OBSERVER_OMEGA_VERTICES,
                            omega_dense: int = OBSERVER_OMEGA_DENSE, max_substep: float = 1e-4,
                            progress: bool = False) -> ThesisObserverCertificate:
    """
    Certify the observer in the thesis's structure.

    Certify the observer in the thesis's structure (``k_e`` fixed, default 1/σ̂ of ``motor`` — what
    the node uses with k_e_injection = 0 — plus the speed-scheduled skew injection).

    Error map: the observer's own M(p, ω) (:func:`thesis_observer_error_map`, RK4 sub-steps) at
    each parameter point (observer model = plant, as in :func:`certify_observer_gain`). With the
    plant integrated exactly, e⁺ = M e + d with d = (A_d − Φ)x + (B_d − ΓB)V, the model's
    one-period integration error (RK4: O((‖A‖T_s/n)⁵) per sub-step), an input to the certified map,
    reported as ``model_residual``. The exact held-injection map M_zoh
    (:func:`held_injection_zoh_map`) is checked with the same P on the dense speeds too.

    Steps: (1) spectral radius of every map (stop if ≥ ρ); (2) a common P over the speed range at
    the nominal point (reported; the held skew injection defeats it); (3) per parameter point the
    speed-dependent P(ω) of :class:`ThesisObserverCertificate`, from the SDP at a 1.5× stricter
    rate on ``omega_vertices`` speeds, checked with numpy at ρ = exp(−decay_rate·T_s) on them and
    on ``omega_dense`` speeds (both maps).
    """
    t0 = time.perf_counter()
    k_e = 1.0 / motor.sigma if k_e is None else float(k_e)
    sc = Scaling.for_motor(motor)
    S, Si = sc.S, np.linalg.inv(sc.S)
    rho = math.exp(-decay_rate * T_s)
    rho_strict = math.exp(-1.5 * decay_rate * T_s)
    pts, w_v, w_d = _observer_grid(motor, param_points, sigma_min, omega_max, omega_vertices,
                                   omega_dense)
    om = max(omega_max, 1e-9)

    def pu(M):
        return Si @ M @ S
    Mv = [[pu(thesis_observer_error_map(p, w, T_s, k_e, motor=motor, max_substep=max_substep))
           for w in w_v] for p in pts]
    h = T_s / max(1, int(math.ceil(T_s / max_substep - 1e-9)))
    Md, Mz, diff, resid = _dense_maps(pts, w_d, T_s, k_e, motor, max_substep, pu)
    n_models = len(pts) * (len(w_v) + 2 * len(w_d))
    spec = float(max(np.abs(np.linalg.eigvals(M)).max() for r in Md + Mz for M in r))

    def result(ok, scope, rv, rd, common, cond, reason=''):
        return ThesisObserverCertificate(ok, T_s, k_e, omega_max, speed_step, decay_rate, scope,
                                         rv,
                                         rd, spec, common, diff, resid, cond, len(pts), n_models,
                                         reason, time.perf_counter() - t0)
    if not spec < rho:
        return result(False, 'eigenvalues', None, None, None, None,
                      f'spectral radius {spec:.6g} >= rho = '
                      f'{rho:.8f}: the sampled thesis-structure '
                      f'error map is not stable on the grid (T_s = {T_s:g} s, k_e = {k_e:.4g})')
    nominal = len(pts) - 1
    common = analysis_lmi(Mv[nominal], True, rho=1.0) is not None
    _log(progress, f'thesis observer T_s = {T_s:g}, k_e = {k_e:.4g}: spectral radius {spec:.8f}; '
                   f'common P over the speeds at the nominal point: {common}; RK4 vs ZOH map '
                   f'{diff:.2e}, model residual {resid:.2e} (per unit, h = {h:g} s)')
    worst_v = worst_d = cond_max = 0.0
    for k in range(len(pts)):
        PP = _speed_dependent_P(Mv[k], w_v, om, speed_step, rho_strict)
        if PP is None:
            return result(False, 'frozen-parameter, speed-dependent P', None, None, common, None,
                          f'parameter point {pts[k].tolist()}: no speed-dependent P')
        rv, c1 = _speed_dependent_rate(*PP, Mv[k], w_v, om, speed_step)
        rd, c2 = _speed_dependent_rate(*PP, Md[k] + Mz[k], np.concatenate([w_d, w_d]), om,
                                       speed_step)
        cond = max(c1, c2)
        if not (rv < rho - 1e-9 and rd < rho - 1e-9 and cond < 1e12):
            return result(False, 'frozen-parameter, speed-dependent P', rv, rd, common, cond,
                          f'parameter point {pts[k].tolist()}: rho_c vertices {rv:.8f}, '
                          f'dense {rd:.8f} (required < {rho:.8f}), cond P {cond:.3g}')
        worst_v, worst_d, cond_max = max(worst_v, rv), max(worst_d, rd), max(cond_max, cond)
    _log(progress, f'thesis observer: certified per parameter point with P(omega), worst rho_c '
                   f'{worst_d:.8f} ({-math.log(worst_d) / T_s:.2f} 1/s)')
    return result(True, 'frozen-parameter, speed-dependent P', worst_v, worst_d, common, cond_max)


# ---------------------------------------------------------------------------------------------
# The flux-coupling term of the current feedback at the node period
# ---------------------------------------------------------------------------------------------
def held_coupling_residual(T_s: float, k: float, *, omega_max: float = 200.0,
                           motor: MotorParams = THESIS_MOTOR) -> Dict[str, float]:
    """
    Damping of the flux-error mode lost to the *held* cancellation term v ω θ 𝒥 (φ̂ − φ*)_k.

    The plant's coupling −v ω θ 𝒥 f(t) rotates with the field (ρ̇ = v ω + ω_sl); the controller
    holds its sample over the period, so the residual averages to v ω θ ρ̇ (T_s/2) f — in phase
    with f, not skew. Through the current loop (e ≈ w/(R_eq + k)) and the rotor equation
    (ḟ = R_r θ e − f/T_r) it removes R_r θ · v ω θ ρ̇ T_s/2 /(R_eq + k) from the flux-error damping
    1/T_r. Slip: the minimum-energy value R_r/(L_r √σ) (eq. 3.19) of the nominal motor.
    """
    m = motor
    theta = m.L_sr / m.L_r
    R_eq = m.R_s + m.R_r * theta ** 2
    w_e = m.pole_pairs * abs(omega_max)
    rho_dot = w_e + m.R_r / (m.L_r * math.sqrt(m.sigma))
    c = w_e * theta * rho_dot * T_s / 2.0
    lost = m.R_r * theta * c / (R_eq + k)
    return {'residual_gain_V_per_Wb': c, 'damping_lost_per_s': lost,
            'flux_damping_per_s': m.R_r / m.L_r, 'share': lost * m.L_r / m.R_r}


def choose_flux_coupling(T_s: float, k: float, *, omega_max: float = 200.0,
                         motor: MotorParams = THESIS_MOTOR) -> str:
    """'cancel' while the held residual costs ≤ ``FLUX_COUPLING_BUDGET`` of 1/T_r, else 'none'."""
    r = held_coupling_residual(T_s, k, omega_max=omega_max, motor=motor)
    return 'cancel' if r['share'] <= FLUX_COUPLING_BUDGET else 'none'


# ---------------------------------------------------------------------------------------------
# Both gains
# ---------------------------------------------------------------------------------------------
@dataclass
class DriveGains:
    """
    Both gains at T_s.

    ``observer_structure`` 'thesis': the observer keeps k_e (1/σ̂) and the skew injection,
    certified by ``thesis_observer``; 'discrete': the injection L = [ℓ I; 0] of
    ``observer_current``, certified by ``observer``.
    """

    T_s: float
    omega_max: float
    sigma_min: float
    current: LoopDesign
    observer_current: Optional[LoopDesign]
    observer: Optional[ObserverCertificate]
    flux_coupling: str
    coupling: Dict[str, float]
    observer_structure: str = 'discrete'
    thesis_observer: Optional[ThesisObserverCertificate] = None

    @property
    def K(self) -> Optional[np.ndarray]:
        return self.current.gain

    @property
    def L(self) -> Optional[np.ndarray]:
        if self.observer_structure != 'discrete' or self.observer_current is None:
            return None
        g = self.observer_current.gain
        return None if g is None else np.vstack([g, np.zeros((2, 2))])

    @property
    def k_e(self) -> Optional[float]:
        """Return the thesis-structure observer's gain (None with the discrete injection)."""
        t = self.thesis_observer
        return t.k_e if self.observer_structure == 'thesis' and t is not None else None

    @property
    def certified(self) -> bool:
        if not self.current.certified:
            return False
        if self.observer_structure == 'thesis':
            return self.thesis_observer is not None and self.thesis_observer.certified
        return (self.observer_current is not None and self.observer_current.certified
                and self.observer is not None and self.observer.certified)

    def summary(self) -> dict:
        return {'T_s': self.T_s, 'omega_max': self.omega_max, 'sigma_min': self.sigma_min,
                'certified': self.certified, 'current': self.current.summary(),
                'observer_structure': self.observer_structure,
                'thesis_observer': None if self.thesis_observer is None
                else self.thesis_observer.summary(),
                'observer_k_e': self.k_e,
                'observer_current': None if self.observer_current is None
                else self.observer_current.summary(),
                'observer': None if self.observer is None else self.observer.summary(),
                'observer_injection_gain': None if self.L is None else self.L.tolist(),
                'flux_coupling': self.flux_coupling, 'held_coupling': self.coupling}


def design_drive_gains(T_s: float, *, omega_max: float = 200.0, decay_rate: Optional[float] = None,
                       observer_rate: Optional[float] = None,
                       observer_decay_rate: float = DEFAULT_OBSERVER_RATE,
                       rate_fraction: float = DEFAULT_RATE_FRACTION,
                       sigma_min: float = DEFAULT_SIGMA_MIN, motor: MotorParams = THESIS_MOTOR,
                       vertex_points=None, certify_points=None, observer_param_points=None,
                       current_policy: str = 'thesis-if-certified',
                       observer_structure: str = 'auto',
                       progress: bool = False) -> DriveGains:
    """
    Return the gains for T_s.

    The current gain K, the observer (thesis structure or discrete L = [ℓ I; 0]) and the
    flux-coupling choice at T_s.

    ``current_policy`` 'thesis-if-certified' (default, ``decay_rate`` None): keep the thesis's
    K = 40 I when the subsystem certificate passes at ``rate_fraction`` × its own best rate (the
    design then is not more aggressive than the reference); otherwise — and always with
    'synthesis' or an explicit ``decay_rate`` — the minimum-norm synthesis at ``rate_fraction`` ×
    the largest feasible rate (or ``decay_rate``).
    ``observer_structure`` 'auto': the thesis structure (k_e = 1/σ̂, skew injection) when
    :func:`certify_thesis_observer` passes at T_s, else the discrete injection; 'thesis' or
    'discrete' force one (a failed certificate then leaves the design uncertified).
    """
    if not omega_max >= 0:
        raise ValueError(f'omega_max = {omega_max!r} must be >= 0 rad/s')
    if current_policy not in ('thesis-if-certified', 'synthesis'):
        raise ValueError(f"current_policy must be 'thesis-if-certified' or 'synthesis', "
                         f'got {current_policy!r}')
    if observer_structure not in ('auto', 'thesis', 'discrete'):
        raise ValueError(f"observer_structure must be 'auto', 'thesis' or 'discrete', "
                         f'got {observer_structure!r}')
    kw = {'sigma_min': sigma_min, 'motor': motor, 'vertex_points': vertex_points,
          'certify_points': certify_points, 'rate_fraction': rate_fraction, 'progress': progress}
    cur = None
    if current_policy == 'thesis-if-certified' and decay_rate is None:
        cur = thesis_current_design(T_s, **kw)
    if cur is None:
        cur = design_subsystem_gain(T_s, injection='voltage', decay_rate=decay_rate, **kw)
    thesis_obs = None
    structure = 'discrete'
    if observer_structure in ('auto', 'thesis'):
        thesis_obs = certify_thesis_observer(T_s, omega_max=omega_max,
                                             decay_rate=observer_decay_rate, sigma_min=sigma_min,
                                             motor=motor, param_points=observer_param_points,
                                             progress=progress)
        if thesis_obs.certified or observer_structure == 'thesis':
            structure = 'thesis'
        else:
            _log(progress, f'thesis-structure observer not certified at T_s = {T_s:g} '
                           f'({thesis_obs.reason}); designing the discrete injection')
    obs_cur = obs = None
    if structure == 'discrete':
        obs_cur = design_subsystem_gain(T_s, injection='direct', decay_rate=observer_rate, **kw)
        if obs_cur.certified:
            L = np.vstack([obs_cur.gain, np.zeros((2, 2))])
            obs = certify_observer_gain(L, T_s, omega_max=omega_max,
                                        decay_rate=observer_decay_rate, sigma_min=sigma_min,
                                        motor=motor, param_points=observer_param_points,
                                        progress=progress)
    if cur.certified:
        k = float(np.linalg.eigvalsh(0.5 * (cur.gain + cur.gain.T)).min())
    else:
        k = THESIS_K1
    return DriveGains(T_s, omega_max, sigma_min, cur, obs_cur, obs,
                      choose_flux_coupling(T_s, k, omega_max=omega_max, motor=motor),
                      held_coupling_residual(T_s, k, omega_max=omega_max, motor=motor),
                      structure, thesis_obs)
