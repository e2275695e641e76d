"""
Online adaptation of the rotor resistance and of θ = L_sr/L_r (seed 000 §4.2.2-4.2.3).

ROS-free. :class:`ParameterAdapter` is stepped once per control period with the step's data
(V_k held over [t_k, t_k+1], measured i_k and ω_k, the observer's rotor flux φ̂_k) and produces the
estimates p̂_k+1 used by the controller and the observer at step k+1. The derivation, the choice of
the gains and the measured behaviour are in ``docs/adaptation.md``; the essentials:

Identifiable quantities
    Multiply the rotor flux by θ = L_sr/L_r: φ_M = θ φ_r. With L_M = L_sr θ = L_sr²/L_r,
    R_R = R_r θ² and L_σ = σL_s = L_s − L_M the motor seen from its terminals is

        ψ_s = L_σ i_s + φ_M,           dψ_s/dt = V_s − R_s i_s
        dφ_M/dt = R_R i_s − (R_R/L_M) φ_M + v ω_r 𝒥 φ_M,      τ_m = v (i_sβ φ_Mα − i_sα φ_Mβ)

    so currents, voltages and speed determine R_s, L_σ, L_M and R_R, never R_r and θ apart
    (eq. 4.10-4.13 only ever use R̂_r θ̂², L̂_sr θ̂ and L̂_s − L̂_sr θ̂). Both laws report
    L_M and R_R next to R_r and θ.

Voltage-model stator flux (eq. 4.3) without drift
    A pure integral of V − R̂_s i drifts with any offset. Drives blend it with a current-model
    flux ψ_cm below a corner ω_c (Jansen & Lorenz's flux observer):

        dψ̂/dt = V − R̂_s i + ω_c (ψ_cm − ψ̂)

    i.e. ψ̂ = s/(s+ω_c)·∫(V − R̂_s i) + ω_c/(s+ω_c)·ψ_cm: the voltage model above ω_c, the current
    model below it, no integrator left open. ``flux_corner = 0`` gives the thesis's pure integral.
    The current-model ψ_cm is L̂_σ i + θ̂ φ̂_r from the observer (law 'thesis') or the adapter's
    own current model with its own L̂_M, R̂_R (law 'improved'). The corner follows the stator
    frequency ω_e (the rotation rate of that model's rotor flux): ω_c = clip(κ|ω_e|, ω_c,min,
    ω_c,max), so a drive holding torque at a few rad/s still has the voltage model's information
    (``flux_corner_ratio`` κ = 0.4, ``flux_corner_min`` 0.5, ``flux_corner`` 5 rad/s).

law = 'thesis' (eq. 4.1-4.9, typos corrected)
    τ̂ = v (i_β ψ̂_α − i_α ψ̂_β)                          (4.2, ψ̂ from 4.3 as above)
    τ* = v θ̂ (i_β φ̂_α − i_α φ̂_β)                        (4.1)
    dθ̂/dt = γ_t (τ̂ − τ*) i_β                              (4.4, as printed)
    î_r = θ̂ (φ̂_r / L̂_sr − i),  P_r* = R̂_r |î_r|²          (4.5-4.7)
    P̂_r = V·i − R̂_s |i|² − τ̂ ω_r                          (4.8 with the squares and the sign of
                                                            the mechanical power restored)
    dR̂_r/dt = γ_r (P̂_r − P_r*) / (|î_r|² + ε)              (4.9)

law = 'improved'
    Least squares on the rotor equation written with the voltage-model stator flux ψ̂ in the
    rotor frame (angle ρ = ∫ v ω_r dt; there the equation has no rotation term and the signals
    move at the slip frequency, so discrete derivatives stay accurate at high ω_e):

        dψ^r/dt = L_σ di^r/dt + R_R i^r − c (ψ^r − L_σ i^r),      c = R_R/L_M

    Both sides are filtered by H(s) = ω_f/(s+ω_f) (Tustin; H[dx/dt] = ω_f (x − Hx), exact in the
    discrete filter), giving two real equations per period in (L_σ, R_R, c), linear in R_R and c
    and solved Gauss-Newton style in L_σ. Recursive least squares in information form with
    exponential forgetting (``memory`` for R_R and c, ``leakage_memory`` for L_σ) and a floor on
    the information matrix (``didt_floor``, ``i_floor``, ``phi_floor``) so that unexcited
    directions hold their value instead of winding up. The torque model (4.1) is the quadrature row
    of this equation and the rotor-loss model (4.5) its inner product with the rotor current, so
    the thesis's two reference models are both inside it. The controller-facing pair is θ̂ =
    L̂_M/L̂_sr and R̂_r = R̂_R/θ̂², projected so that σ̂ stays above ``sigma_min``; when θ̂ hits
    its bound R̂_r still keeps R̂_r θ̂² = R̂_R (not the rotor time constant R̂_R/L̂_M): in closed
    loop the terminal rotor resistance is what the controller and observer need most.

Projection
    R̂_r ∈ [R_r_min, R_r_max]; θ̂ ∈ [theta_min, θ_max] with
    θ_max = min(theta_max, (1 − sigma_min) L̂_s / L̂_sr), because the model leakage factor is
    σ̂ = 1 − θ̂ L̂_sr / L̂_s and σ̂ ≤ 0 makes D̂ of eq. 4.12-4.13 singular. The improved law's
    L̂_M ∈ [L_M_min, L_M_max] and R̂_R ∈ [R_r_min θ_min², R_r_max θ_max²].
"""
from __future__ import annotations

import cmath
from dataclasses import dataclass, fields, replace
import math
from typing import Optional

from im_common.params import check_real, InvalidParameter, MotorParams
from im_common.validation import check_choice

from .thermal_tracking import tracking_for

LAWS = ('thesis', 'improved')
#: what the controller and observer take from the adapter (docs/adaptation.md §7):
#: 'inverse_gamma' — L̂_σ, L̂_M, R̂_R into every coefficient (the improved law's default);
#: 'thesis_pair' — R̂_r, θ̂ into eq. 4.12-4.13 with L̂_s, L̂_sr, R̂_s nominal (the thesis law's
#: only feed); 'auto' — the law's default
FEEDS = ('auto', 'inverse_gamma', 'thesis_pair')
FEED_DEFAULT = 'auto'
#: the start offset of the voltage-model flux estimated ('auto': unless R_s is estimated)
START_OFFSETS = ('auto', 'on', 'off')
TWO_PI = 2.0 * math.pi
#: improved law estimating R_s (always sensorless): R_s is estimated and L_M held where the stator
#: resistance's voltage R_s|i| exceeds this share of the flux's ω_e|φ|, elsewhere L_M is estimated
#: and R_s held (the thesis motor at 8 A and 0.5 Wb: below ω_e ≈ 110 rad/s; docs/sensorless.md §3)
SPLIT_RATIO = 0.1


@dataclass(frozen=True)
class AdaptationGains:
    """
    Gains, bounds and filter corners of the adaptation (SI units).

    ``None`` bounds are derived from the motor parameters given to :class:`ParameterAdapter`
    (see :meth:`resolve`). Invalid values raise :class:`InvalidParameter` naming the field.
    """

    law: str = 'improved'
    """'thesis' (eq. 4.4, 4.9 as printed) or 'improved' (least squares on the rotor equation)."""
    feed: str = FEED_DEFAULT
    """What the controller and observer take (``FEEDS``): 'inverse_gamma' (L̂_σ, L̂_M, R̂_R: every
    coefficient follows them) or 'thesis_pair' (R̂_r, θ̂); 'auto' resolves to 'inverse_gamma' for
    the improved law and 'thesis_pair' for the thesis law (which estimates nothing else)."""
    freeze: bool = False
    """Hold the estimates (the flux and filter states keep running, so unfreezing is smooth)."""
    decimation: int = 10
    """Update the estimates every N control periods (information is gathered every period)."""
    # Thesis law (eq. 4.4 and 4.9).
    gamma_t: float = 0.02
    """γ_t of eq. 4.4 [1/(N·m·A·s)]."""
    gamma_r: float = 100.0
    """γ_r of eq. 4.9 [1/s]: the inverse time constant of R̂_r when |î_r|² ≫ ε."""
    epsilon: float = 1.0
    """ε of eq. 4.9 [A²]: keeps the normalisation finite when î_r passes through zero."""
    # Voltage-model flux (eq. 4.3).
    flux_corner: float = 5.0
    """ω_c [rad/s]: below it the stator flux comes from the current model (0: pure integral).
    With ``flux_corner_ratio`` > 0 it is the corner's upper bound."""
    flux_corner_ratio: float = 0.4
    """κ: the corner follows the stator frequency, ω_c = clip(κ|ω_e|, flux_corner_min, flux_corner)
    (0: fixed at ``flux_corner``). ω_e is the rotation rate of the model rotor flux."""
    flux_corner_min: float = 0.5
    """Lower bound [rad/s] of the frequency-following corner."""
    # Improved law.
    filter_corner: float = 200.0
    """ω_f [rad/s] of the regression filter H(s) = ω_f/(s+ω_f)."""
    memory: float = 0.02
    """Time constant [s] of the exponential forgetting of the least squares (R_R and L_M)."""
    leakage_memory: float = 2.0
    """Time constant [s] of the forgetting in the leakage direction (L_σ varies slowly)."""
    i_floor: float = 0.3
    """Current [A] whose information is always present (holds unexcited directions)."""
    phi_floor: float = 0.01
    """Flux [Wb] whose information is always present (holds unexcited directions)."""
    didt_floor: float = 20.0
    """Current rate [A/s] whose information is always present (holds L̂_σ when unexcited)."""
    estimate_leakage: bool = True
    """Estimate the leakage L_σ = σL_s as well (else hold it at ``L_sigma``)."""
    estimate_stator_resistance: bool = False
    """Sensored: estimate R_s beside L_σ, R_R, L_M (sensorless always does, in R_R's place)."""
    stator_memory: float = 2.0
    """Time constant [s] of the forgetting in the R_s direction (R_s drifts with temperature)."""
    start_offset: str = 'auto'
    """Estimate the offset the voltage-model flux starts with in a drive started magnetised (a
    model's flux is never the motor's; it decays with the blend, and left out of the least squares
    it is read as L_σ, R_R and L_M): 'on', 'off', or 'auto' = on unless R_s is estimated (R_s's
    own start transient is the same decaying mode; docs/adaptation.md §4)."""
    L_sigma: Optional[float] = None
    """Initial (or fixed) leakage L_σ = σL_s [H] (None: L̂_s − L̂_sr θ̂_0)."""
    L_sigma_min: Optional[float] = None
    """Lower bound of L̂_σ [H] (None: a quarter of the initial L_σ)."""
    L_sigma_max: Optional[float] = None
    """Upper bound of L̂_σ [H] (None: ten times the initial L_σ)."""
    # Projection.
    R_r_min: Optional[float] = None
    """Lower bound of R̂_r [Ω] (None: R_r/4 of the nominal parameters)."""
    R_r_max: Optional[float] = None
    """Upper bound of R̂_r [Ω] (None: 4 R_r of the nominal parameters)."""
    theta_min: float = 0.5
    """Lower bound of θ̂."""
    theta_max: float = 1.0
    """Upper bound of θ̂ before the σ̂ bound (θ = L_sr/L_r < 1 for a motor with rotor leakage)."""
    sigma_min: float = 0.04
    """Smallest model leakage factor σ̂ = 1 − θ̂ L̂_sr/L̂_s allowed (θ̂ ≤ (1−σ_min) L̂_s/L̂_sr)."""
    L_M_min: Optional[float] = None
    """Lower bound of L̂_M [H] (None: half the nominal L_sr²/L_r)."""
    L_M_max: Optional[float] = None
    """Upper bound of L̂_M [H] (None: twice the nominal L_sr²/L_r)."""

    def __post_init__(self):
        check_choice('law', self.law, LAWS)
        check_choice('feed', self.feed, FEEDS)
        if self.feed == 'auto':
            object.__setattr__(self, 'feed',
                               'inverse_gamma' if self.law == 'improved' else 'thesis_pair')
        if self.feed != 'thesis_pair' and self.law == 'thesis':
            raise InvalidParameter('feed', self.feed, "needs law 'improved' (the thesis law "
                                   'estimates only R_r and theta)')
        check_choice('start_offset', self.start_offset, START_OFFSETS)
        for name in ('freeze', 'estimate_leakage', 'estimate_stator_resistance'):
            if not isinstance(getattr(self, name), bool):
                raise InvalidParameter(name, getattr(self, name), 'must be true or false')
        d = self.decimation
        if isinstance(d, bool) or not isinstance(d, int) or d < 1:
            raise InvalidParameter('decimation', d, 'must be a whole number >= 1')
        for name in ('gamma_t', 'gamma_r', 'flux_corner', 'flux_corner_ratio', 'flux_corner_min'):
            _finite(name, getattr(self, name), lo=0.0)
        for name in ('epsilon', 'filter_corner', 'memory', 'leakage_memory', 'stator_memory',
                     'i_floor',
                     'phi_floor', 'didt_floor',
                     'theta_min', 'theta_max'):
            _finite(name, getattr(self, name), lo=0.0, strict=True)
        _finite('sigma_min', self.sigma_min, lo=0.0, strict=True)
        if self.sigma_min >= 1.0:
            raise InvalidParameter('sigma_min', self.sigma_min, 'must be < 1')
        for name in ('L_sigma', 'L_sigma_min', 'L_sigma_max', 'R_r_min', 'R_r_max', 'L_M_min',
                     'L_M_max'):
            if getattr(self, name) is not None:
                _finite(name, getattr(self, name), lo=0.0, strict=True)
        if self.theta_min >= self.theta_max:
            raise InvalidParameter('theta_min', self.theta_min,
                                   f'must be below theta_max = {self.theta_max}')
        _ordered('R_r_min', self.R_r_min, 'R_r_max', self.R_r_max)
        _ordered('L_M_min', self.L_M_min, 'L_M_max', self.L_M_max)
        _ordered('L_sigma_min', self.L_sigma_min, 'L_sigma_max', self.L_sigma_max)
        if self.flux_corner > 0.0 and self.flux_corner_ratio > 0.0:
            _ordered('flux_corner_min', self.flux_corner_min, 'flux_corner', self.flux_corner)

    def theta_bound(self, L_s_hat: float, L_sr_hat: float) -> float:
        """θ_max: the tighter of ``theta_max`` and the σ̂ ≥ σ_min bound (1 − σ_min) L̂_s/L̂_sr."""
        return min(self.theta_max, (1.0 - self.sigma_min) * L_s_hat / L_sr_hat)

    def resolve(self, params: MotorParams, theta0: Optional[float] = None) -> 'AdaptationGains':
        """
        Return a copy with every ``None`` bound derived from ``params``.

        The bounds are checked for consistency.

        Raises :class:`InvalidParameter` naming ``sigma_min``/``theta_min`` if the σ̂ bound leaves
        no room for θ̂.
        """
        th0 = params.theta if theta0 is None else theta0
        th0 = _clip(th0, self.theta_min, self.theta_bound(params.L_s, params.L_sr))
        L_M0 = params.L_sr * params.L_sr / params.L_r
        g = replace(
            self,
            R_r_min=0.25 * params.R_r if self.R_r_min is None else self.R_r_min,
            R_r_max=4.0 * params.R_r if self.R_r_max is None else self.R_r_max,
            L_M_min=0.5 * L_M0 if self.L_M_min is None else self.L_M_min,
            L_M_max=2.0 * L_M0 if self.L_M_max is None else self.L_M_max,
            L_sigma=(params.L_s - params.L_sr * th0) if self.L_sigma is None else self.L_sigma)
        th_max = g.theta_bound(params.L_s, params.L_sr)
        if th_max <= g.theta_min:
            raise InvalidParameter(
                'sigma_min', g.sigma_min,
                f'the bound theta <= (1 - sigma_min) L_s/L_sr = {th_max:.6g} leaves no room above '
                f'theta_min = {g.theta_min}')
        if not g.L_sigma > 0.0:
            raise InvalidParameter(
                'L_sigma', g.L_sigma,
                f'the leakage L_s - L_sr*theta0 = {g.L_sigma:.6g} H must be > 0 (sigma > 0); '
                'give L_sigma explicitly or a smaller theta_initial')
        g = replace(g,
                    L_sigma_min=0.25 * g.L_sigma if g.L_sigma_min is None else g.L_sigma_min,
                    L_sigma_max=10.0 * g.L_sigma if g.L_sigma_max is None else g.L_sigma_max)
        return g

    def as_dict(self) -> dict:
        return {f.name: getattr(self, f.name) for f in fields(self)}


def _finite(name, value, lo=None, strict=False):
    return check_real(name, value, lo, lo_open=strict)


def _ordered(lo_name, lo, hi_name, hi):
    if lo is not None and hi is not None and not lo < hi:
        raise InvalidParameter(lo_name, lo, f'must be below {hi_name} = {hi}')


def _clip(x: float, lo: float, hi: float) -> float:
    return lo if x < lo else hi if x > hi else x


def _solve_sym3(R, e):
    """R⁻¹ e for a symmetric positive-definite 3×3 R stored as [11, 12, 13, 22, 23, 33]."""
    a, b, c, d, f, g = R
    A11 = d * g - f * f
    A12 = c * f - b * g
    A13 = b * f - c * d
    A22 = a * g - c * c
    A23 = b * c - a * f
    A33 = a * d - b * b
    det = a * A11 + b * A12 + c * A13
    e1, e2, e3 = e
    return ((A11 * e1 + A12 * e2 + A13 * e3) / det,
            (A12 * e1 + A22 * e2 + A23 * e3) / det,
            (A13 * e1 + A23 * e2 + A33 * e3) / det)


def _solve_sym(R, e, n):
    """
    R⁻¹ e for a symmetric positive-definite n×n R stored packed by rows (upper triangle).

    Gaussian elimination without pivoting (R is positive definite); n = 2 and 3 in closed form.
    """
    if n == 3:
        return _solve_sym3(R, e)
    if n == 2:
        a, b, d = R
        det = a * d - b * b
        return ((d * e[0] - b * e[1]) / det, (a * e[1] - b * e[0]) / det)
    A = [[0.0] * n for _ in range(n)]
    k = 0
    for i in range(n):
        for j in range(i, n):
            A[i][j] = A[j][i] = R[k]
            k += 1
    x = list(e)
    for p in range(n):
        piv = A[p][p]
        for r in range(p + 1, n):
            f = A[r][p] / piv
            if f:
                Ar, Ap = A[r], A[p]
                for c in range(p, n):
                    Ar[c] -= f * Ap[c]
                x[r] -= f * x[p]
    for p in range(n - 1, -1, -1):
        acc = x[p]
        Ap = A[p]
        for c in range(p + 1, n):
            acc -= Ap[c] * x[c]
        x[p] = acc / Ap[p]
    return x


class ParameterAdapter:
    """
    Online estimates of R_r and θ = L_sr/L_r (and of the identifiable L_M, R_R).

    Parameters
    ----------
    params : MotorParams
        The controller's (nominal) estimates: R̂_s, L̂_s, L̂_sr are used as fixed, pole pairs v.
    gains : AdaptationGains
    R_r0, theta0 : float
        Initial estimates (projected into their bounds).

    Notes
    -----
    ``update`` is scalar Python on complex numbers (αβ pairs as α + jβ); one call per period.

    """

    def __init__(self, params: MotorParams, gains: AdaptationGains, R_r0: float, theta0: float,
                 sensorless: bool = False, thermal=None):
        _finite('R_r_initial', R_r0, lo=0.0, strict=True)
        _finite('theta_initial', theta0, lo=0.0, strict=True)
        self.params = params
        self.gains = g = gains.resolve(params, theta0)
        self.R_s = params.R_s
        self.L_s = params.L_s
        self.L_sr = params.L_sr
        self.v = params.pole_pairs
        self.theta_lo = g.theta_min
        self.theta_hi = g.theta_bound(params.L_s, params.L_sr)
        self.R_r_lo, self.R_r_hi = g.R_r_min, g.R_r_max
        self.R_R_lo = g.R_r_min * g.theta_min ** 2
        self.R_R_hi = g.R_r_max * self.theta_hi ** 2
        self.L_M_lo, self.L_M_hi = g.L_M_min, g.L_M_max
        self.L_sigma = g.L_sigma
        self.improved = g.law == 'improved'
        # sensorless (ω is the observer's ω̂): R_R and ω enter the rotor equation only through the
        # slip, so R̂_R is held; the improved law estimates (L_σ, R_s, c = R_R/L_M) instead of
        # (L_σ, R_R, c): R_s through the voltage-model flux (docs/sensorless.md §3)
        if not isinstance(sensorless, bool):
            raise InvalidParameter('sensorless', sensorless, 'must be true or false')
        self.sensorless = sensorless
        self.freeze = g.freeze
        self.N = g.decimation
        # Controller-facing estimates.
        self.theta = _clip(float(theta0), self.theta_lo, self.theta_hi)
        self.R_r = _clip(float(R_r0), self.R_r_lo, self.R_r_hi)
        # Identifiable estimates (the improved law's own parameters).
        self.L_M = _clip(self.L_sr * self.theta, self.L_M_lo, self.L_M_hi)
        self.R_R = _clip(self.R_r * self.theta ** 2, self.R_R_lo, self.R_R_hi)
        self.k = 0
        self._started = False
        self._psi = 0j            # voltage-model stator flux ψ̂ [Wb]
        self._phi_cm = 0j         # improved law: own current-model φ_M [Wb]
        self._phi_obs_prev = 0j   # thesis law: the observer's φ̂_r at t_k-1
        self._omega_e = math.inf  # stator frequency of the model rotor flux [rad/s] (∞: unknown)
        self._i_prev = 0j
        self._v_prev = 0j
        self._acc_t = 0.0         # thesis law: accumulated integrands over the block
        self._acc_r = 0.0
        # Improved law: regression filters and least-squares information (symmetric 3×3
        # matrices stored as [11, 12, 13, 22, 23, 33]).
        self.estimate_leakage = g.estimate_leakage
        self.L_sigma_lo, self.L_sigma_hi = g.L_sigma_min, g.L_sigma_max
        self.L_sigma = _clip(self.L_sigma, self.L_sigma_lo, self.L_sigma_hi)
        self._Hi = self._Hpsi = 0j
        self._u_prev = (0j, 0j)
        self._rho = 0.0
        self._omega_prev = 0.0
        # The least squares' parameters: L_σ; R_R (sensorless: R_s, R̂_R held); c = R_R/L_M;
        # sensored with estimate_stator_resistance, R_s; a drive started magnetised, the start
        # offset of ψ̂ (its real and imaginary parts, while it still matters).
        self.estimate_R_s = sensorless or g.estimate_stator_resistance
        self._names = ['L_sigma', 'R_s' if sensorless else 'R_R', 'c']
        if self.estimate_R_s and not sensorless:
            self._names.append('R_s')
        self._S = self._b = self._R = None
        self._c = self.R_R / self.L_M        # c = R_R/L_M = 1/T_r [1/s]
        self._z = self._Hz = self._uz = 0j  # R_s estimated: −∂ψ̂/∂R_s and its rotor-frame filter
        self._w = 0.0                       # ∂ψ̂/∂(start offset) (real: the blend's decay)
        self._Hw = self._uw = 0j            # its rotor-frame filter
        self._w_floor = 0.0                 # w below which the start offset no longer matters
        self._hold_L_M = False              # R_s learnt where it weighs (SPLIT_RATIO): L̂_M held
        # with the motor's thermal block (thermal_tracking; docs/adaptation.md §9) the windings'
        # temperatures, which the drive's own losses give, carry R̂_s and R̂_R: sensorless they
        # are R̂_s and R̂_R (the least squares keep L_σ and L_M); sensored they move the least
        # squares' estimates between updates and are re-anchored to them at each
        self.temperatures = None
        if thermal is not None:
            if not self.improved:
                raise InvalidParameter('thermal', 'given', "tracks the windings' temperatures "
                                       "in the improved law only (law 'thesis' has no R_s)")
            self.temperatures = tracking_for(thermal, params)
            self.temperatures.R_s_ref, self.temperatures.R_R_ref = self.R_s, self.R_R
        self.R_s_lo, self.R_s_hi = 0.25 * params.R_s, 4.0 * params.R_s
        self._filter_T = None     # period for which the filter coefficients are computed
        self.last = {}            # diagnostics of the last step (for tests and plots)

    @property
    def stator_flux(self) -> tuple:
        """Return the voltage-model stator flux ψ̂_s(t_k) (α, β) [Wb] after the last update."""
        return self._psi.real, self._psi.imag

    @property
    def sigma_hat(self) -> float:
        """Return the controller's model leakage factor σ̂ = 1 − θ̂ L̂_sr / L̂_s."""
        return 1.0 - self.theta * self.L_sr / self.L_s

    # ------------------------------------------------------------------------------------
    def estimates(self) -> dict:
        """
        Return the estimates handed to the controller and observer.

        Published on ``/im/adapter/estimate``.

        {'R_r', 'theta', 'L_M', 'R_R'}: the controller and observer take the pair (R̂_r, θ̂) of eq.
        4.10-4.13 with their L̂_s, L̂_sr, R̂_s fixed; L_M and R_R are the identifiable image (law
        'thesis': L_M = L̂_sr θ̂, R_R = R̂_r θ̂²; law 'improved': the least-squares estimates). Law
        'improved' with ``feed='inverse_gamma'`` adds 'L_sigma': the controller and observer then
        take the inverse-Γ set (L̂_σ, L̂_M, R̂_R) whole (every coefficient follows it,
        docs/adaptation.md §7), and 'R_s' where R̂_s moves: estimated (sensorless,
        ``estimate_stator_resistance``) or carried by the thermal networks.
        """
        e = {'R_r': self.R_r, 'theta': self.theta, 'L_M': self.L_M, 'R_R': self.R_R}
        if self.improved and self.gains.feed == 'inverse_gamma':
            e['L_sigma'] = self.L_sigma
            if self.estimate_R_s or self.temperatures is not None:  # learnt, or the networks'
                e['R_s'] = self.R_s
        return e

    # ------------------------------------------------------------------------------------
    def update(self, T_s, v_a, v_b, i_a, i_b, omega_r, phi_hat_a, phi_hat_b) -> None:
        """
        One control period: data of step k in, estimates p̂_k+1 out (see :meth:`estimates`).

        Parameters are V_k (held over the period), the measured i_k and ω_k and the observer's
        rotor flux φ̂_k (rotor scaling, as the observer of eq. 4.13 carries it).
        """
        V = complex(v_a, v_b)
        i = complex(i_a, i_b)
        g = self.gains
        if not self._started:
            # ψ_s(t_0) from the current model (zero for a motor starting unmagnetised).
            self._started = True
            if self.improved:
                # Own current model starts from the observer's flux (θ̂ φ̂_r = φ̂_M): a drive that
                # is already magnetised at t_0 has no start-up offset in ψ̂.
                self._phi_cm = self.theta * complex(phi_hat_a, phi_hat_b)
                self._psi = self.L_sigma * i + self._phi_cm
            else:
                self._phi_obs_prev = complex(phi_hat_a, phi_hat_b)
                self._psi = ((self.L_s - self.L_sr * self.theta) * i
                             + self.theta * self._phi_obs_prev)
            self._i_prev = i
            self._v_prev = V
            if self.improved:
                self._init_filters(T_s, i, omega_r)
            return
        # Voltage-model flux ψ̂_k (eq. 4.3) over [t_k-1, t_k]: V_k-1 was held, i trapezoidal.
        i_prev = self._i_prev
        # Current-model stator flux at t_k-1 (the start of the period, explicit blend).
        if self.improved:
            psi_cm = self.L_sigma * i_prev + self._phi_cm
        else:
            psi_cm = (self.L_s - self.L_sr * self.theta) * i_prev + self.theta * self._phi_obs_prev
            self._phi_obs_prev = complex(phi_hat_a, phi_hat_b)
        w_c = self._corner()
        if self.estimate_R_s:   # ψ̂ = … − R_s z: its sensitivity to R_s, integrated alike
            self._z += T_s * (0.5 * (i + i_prev) - w_c * self._z)
        if self._w:             # ψ̂ = … + δ w: its sensitivity to the start offset δ
            self._w *= 1.0 - T_s * w_c
        self._psi += T_s * (self._v_prev - self.R_s * 0.5 * (i + i_prev)
                            + w_c * (psi_cm - self._psi))
        V_prev = self._v_prev
        self._i_prev = i
        self._v_prev = V
        if self.temperatures is not None:     # the windings heated by the period's losses
            i_R = i_prev - self._phi_cm / self.L_M
            self.temperatures.step(T_s, 0.5 * self.R_s * (abs(i) ** 2 + abs(i_prev) ** 2),
                                   self.R_R * (i_R.real * i_R.real + i_R.imag * i_R.imag))
        if self.improved:
            phi_before = self._phi_cm
            self._improved_step(T_s, i, omega_r, i_prev)
            if g.flux_corner_ratio > 0.0:
                # Stator frequency: the rotation rate of the own model's rotor flux over the
                # period (it moves smoothly, unlike ψ̂, whose leakage part carries the current
                # loop's steps).
                rot = self._phi_cm * phi_before.conjugate()
                self._omega_e = (math.atan2(rot.imag, rot.real) / T_s
                                 if abs(rot) > g.phi_floor * g.phi_floor else math.inf)
        else:
            self._thesis_step(T_s, V_prev, i, i_prev, omega_r, phi_hat_a, phi_hat_b)

    def _corner(self) -> float:
        """
        ω_c of the flux blend.

        The improved law's follows the stator frequency (``flux_corner_ratio``; ∞ while the
        model flux is below ``phi_floor`` gives the upper bound), the thesis law's is
        fixed.
        """
        g = self.gains
        if not self.improved or g.flux_corner_ratio <= 0.0 or g.flux_corner <= 0.0:
            return g.flux_corner
        return _clip(g.flux_corner_ratio * abs(self._omega_e), g.flux_corner_min, g.flux_corner)

    # Thesis law -------------------------------------------------------------------------
    def _thesis_step(self, T_s, V_prev, i, i_prev, omega_r, phi_a, phi_b):
        v = self.v
        psi = self._psi
        th = self.theta
        # Estimated torque from the stator flux (4.2) and the reference model (4.1).
        tau_hat = v * (i.imag * psi.real - i.real * psi.imag)
        tau_ref = v * th * (i.imag * phi_a - i.real * phi_b)
        # Rotor currents (4.6-4.7), loss reference (4.5) and loss estimate (4.8, corrected).
        k = th / self.L_sr
        ir_a = k * phi_a - th * i.real
        ir_b = k * phi_b - th * i.imag
        ir2 = ir_a * ir_a + ir_b * ir_b
        P_ref = self.R_r * ir2
        # Input and stator copper power over the period just integrated: V_k-1 was held while
        # the current went from i_k-1 to i_k (sampling V_k·i_k instead is off by ~|V||i|ω_e T_s/2).
        P_hat = (0.5 * (V_prev.real * (i.real + i_prev.real)
                        + V_prev.imag * (i.imag + i_prev.imag))
                 - 0.5 * self.R_s * (i.real * i.real + i.imag * i.imag
                                     + i_prev.real * i_prev.real + i_prev.imag * i_prev.imag)
                 - tau_hat * omega_r)
        self._acc_t += (tau_hat - tau_ref) * i.imag
        self._acc_r += (P_hat - P_ref) / (ir2 + self.gains.epsilon)
        self.k += 1
        if self.k % self.N:
            return
        if not self.freeze:
            g = self.gains
            self.theta = _clip(th + g.gamma_t * T_s * self._acc_t, self.theta_lo, self.theta_hi)
            if not self.sensorless:     # the rotor loss balance needs τ̂ω: R̂_r held
                self.R_r = _clip(self.R_r + g.gamma_r * T_s * self._acc_r, self.R_r_lo,
                                 self.R_r_hi)
            self.L_M = self.L_sr * self.theta
            self.R_R = self.R_r * self.theta * self.theta
            self.L_sigma = self.L_s - self.L_M
        self.last = {'tau_hat': tau_hat, 'tau_ref': tau_ref, 'P_r_hat': P_hat, 'P_r_ref': P_ref}
        self._acc_t = 0.0
        self._acc_r = 0.0

    # Improved law -----------------------------------------------------------------------
    def _init_filters(self, T_s, i, omega_r):
        self._set_filter(T_s)
        # Rotor frame: electrical rotor angle ρ = ∫ v ω_r dt from 0 (any start angle will do).
        self._rho = 0.0
        self._omega_prev = omega_r
        # Filters start in their steady state. In the rotor frame a loaded drive's currents and
        # flux turn at the slip frequency, s = (R_R i − c φ)/φ of the model's rotor equation, so
        # each sample is z = e^{s T_s} times the last and the Tustin filter's steady gain is
        # G = f_b (1 + 1/z)/(1 − f_a/z); starting at the sample itself (G = 1) is a start-up
        # transient the regression reads as data (10 % at 20 rad/s of slip: R̂_R fell from
        # 0.77 to 0.05 Ω within 3 ms at a loaded steady start).
        G = 1.0
        phi = self._phi_cm
        if abs(phi) > self.gains.phi_floor:
            z = cmath.exp((self.R_R * i - self._c * phi) / phi * T_s)
            G = self._fb * (1.0 + 1.0 / z) / (1.0 - self._fa / z)
        self._G0 = G
        self._Hi, self._Hpsi = G * i, G * self._psi
        self._u_prev = (i, self._psi)
        # A drive started magnetised: ψ̂(t_0) comes from the model, and the motor's flux differs
        # by an unknown offset δ that the blend removes as w(t) = Π(1 − T_s ω_c) (w's filter
        # starts like ψ̂'s, at its first sample). Estimated with
        # the rest while w|ψ̂(t_0)| is above the flux floor (then it no longer matters); a drive
        # started demagnetised starts exact (ψ = 0).
        g = self.gains
        use = g.start_offset == 'on' or (g.start_offset == 'auto' and not self.estimate_R_s)
        if use and abs(self._psi) > g.phi_floor:
            self._w = 1.0
            self._Hw, self._uw = self._G0, 1.0 + 0j     # the offset's share of Hψ̂(t_0)
            self._w_floor = g.phi_floor / abs(self._psi)
            self._names += ['offset_re', 'offset_im']
        self._size()

    def _set_filter(self, T_s):
        g = self.gains
        wT = g.filter_corner * T_s
        self._wf = g.filter_corner
        self._fa = (2.0 - wT) / (2.0 + wT)
        self._fb = wT / (2.0 + wT)
        self._filter_T = T_s
        self._size()

    #: per parameter: its forgetting time constant (a gains field; None: a constant, never
    #: forgotten, its information starting at the floor's over ``memory``)
    _MEMORY = {'L_sigma': 'leakage_memory', 'R_R': 'memory', 'c': 'memory',
               'R_s': 'stator_memory', 'offset_re': None, 'offset_im': None}

    def _size(self):
        """
        Forgetting, floors and the information of the parameters in ``_names``.

        Per parameter the forgetting per period, its N-period factors for the stored upper
        triangle (packed by rows) and the floor's share of N periods; the information of a new
        parameter starts at its floor's steady state f/(1 − λ), of a dropped one is removed.
        """
        g = self.gains
        T_s, N, names = self._filter_T, self.N, self._names
        if T_s is None:
            return
        n = len(names)
        mem = [self._MEMORY[p] for p in names]
        lam = [1.0 if m is None else math.exp(-T_s / getattr(g, m)) for m in mem]
        wf = self._wf
        floor = {'L_sigma': g.didt_floor ** 2, 'R_R': g.i_floor ** 2, 'R_s': g.i_floor ** 2,
                 'c': g.phi_floor ** 2}
        off = (wf * self._w_floor) ** 2       # the offset's regressor ≈ ω_f w at w = w_floor
        self._floor = [floor.get(p, off) for p in names]
        self._pairs = [(a, b) for a in range(n) for b in range(a, n)]
        self._lamN = [math.sqrt(lam[a] * lam[b]) ** N for a, b in self._pairs]
        self._share = [N if lk == 1.0 else (1.0 - lk ** N) / (1.0 - lk) for lk in lam]
        start = [f * (g.memory / T_s if lk == 1.0 else 1.0 / (1.0 - lk))
                 for f, lk in zip(self._floor, lam)]
        old = {} if self._R is None else dict(zip(self._pairs_names, self._R))
        self._pairs_names = [(names[a], names[b]) for a, b in self._pairs]
        self._R = [old.get(pq, start[a] if a == b else 0.0)
                   for pq, (a, b) in zip(self._pairs_names, self._pairs)]
        self._S = [0.0] * len(self._pairs)
        self._b = [0.0] * n

    def _improved_step(self, T_s, i, omega_r, i_prev):
        """
        One period of the improved law: the least squares' data, solved every N periods.

        The own current model and the rotor frame advance over [t_k-1, t_k]; the filtered rotor
        equation's residual and regressors (those of the parameters in ``_names``) go into the
        normal equations, which :meth:`_ls_update` solves every N-th period.
        """
        if T_s != self._filter_T:
            self._set_filter(T_s)
        rot = self._advance_current_model(T_s, i, omega_r, i_prev)
        i_r = i * rot
        psi_r = self._psi * rot
        # Tustin filters H(s) = ω_f/(s+ω_f) on the rotor-frame i and ψ̂.
        fa, fb = self._fa, self._fb
        ui, upsi = self._u_prev
        Hi = self._Hi = fa * self._Hi + fb * (i_r + ui)
        Hpsi = self._Hpsi = fa * self._Hpsi + fb * (psi_r + upsi)
        self._u_prev = (i_r, psi_r)
        e, cols, Hphi = self._rotor_equation_residual(i_r, psi_r, Hi, Hpsi)
        if self.estimate_R_s:
            self._stator_resistance_regressor(cols, rot, i, Hi, Hphi)
        if self._w:             # the start offset δ (complex): ψ̂ = … + δ w, e = … − δ g_w
            cols += self._start_offset_regressors(rot)
        self._accumulate_normal_equations(cols, e)
        self.k += 1
        if self.k % self.N:
            return
        self._ls_update()

    def _advance_current_model(self, T_s, i, omega_r, i_prev) -> complex:
        """
        Advance the own current model φ_cm and the rotor angle ρ over [t_k-1, t_k].

        Returns e^{−jρ}, the rotation from αβ to the rotor frame at t_k.
        """
        # Own current model φ_cm over [t_k-1, t_k]: dφ/dt = R_R i − c φ + j v ω φ (Tustin, with
        # the interval's mean speed: ω_k alone is off by T_s/2·dω/dt, which under a hard braking
        # (1000 rad/s²) put 10⁻³ Wb into φ_cm and biased L̂_M by 13 % as the flux decayed).
        a = complex(-self._c, self.v * 0.5 * (omega_r + self._omega_prev)) * (0.5 * T_s)
        self._phi_cm = ((1.0 + a) * self._phi_cm + self.R_R * T_s * 0.5 * (i + i_prev)) / (1.0 - a)
        # To the rotor frame (angle ρ = ∫ v ω_r dt, trapezoidal): there the rotor equation has no
        # rotation term and the signals move at the slip frequency, so the filters below are
        # accurate even where ω_e ≫ ω_sl (in αβ, dψ/dt and j v ω ψ nearly cancel and the
        # O((ω_e T_s)²) error of a discrete derivative swamps the slip term at low torque).
        self._rho = rho = (self._rho + 0.5 * T_s * self.v * (omega_r + self._omega_prev)) % TWO_PI
        self._omega_prev = omega_r
        return complex(math.cos(rho), -math.sin(rho))

    def _rotor_equation_residual(self, i_r, psi_r, Hi, Hpsi):
        """
        Return (e, cols, Hφ): the filtered rotor equation's residual and regressors.

        ``cols`` holds −∂e/∂p of (L_σ, R_R, c) as complex numbers x + jy; Hφ = Hψ̂ − L_σ Hi.
        """
        # H[dψ/dt] = L_σ H[di/dt] + R_R H[i] − c H[ψ − L_σ i] (rotor frame; H[dx/dt] = ω_f(x −
        # Hx)):
        # residual at the current estimates and its gradient in (L_σ, R_R, c) (Gauss-Newton;
        # linear in R_R and c).
        wf = self._wf
        c = self._c
        L_sig = self.L_sigma
        y = wf * (psi_r - Hpsi)
        r1 = wf * (i_r - Hi)
        Hphi = Hpsi - L_sig * Hi
        e = y - (L_sig * r1 + self.R_R * Hi - c * Hphi)
        # The regressors −∂e/∂p of the parameters in _names, as complex numbers x + jy.
        g1 = r1 + c * Hi
        return e, [g1, Hi, -Hphi], Hphi

    def _stator_resistance_regressor(self, cols, rot, i, Hi, Hphi) -> None:
        """
        Put R_s's regressor into ``cols`` (in place), holding L_M or R_s where they alias.

        Sensorless it takes R_R's place; sensored it is appended (zero while L_M is learnt).
        """
        fa, fb, wf, c = self._fa, self._fb, self._wf, self._c
        # R_s: −∂e/∂R_s = ω_f(z − Hz) + c Hz (rotor frame)
        z_r = self._z * rot
        Hz = self._Hz = fa * self._Hz + fb * (z_r + self._uz)
        self._uz = z_r
        gz = wf * (z_r - Hz) + c * Hz
        # R_s moves ψ̂ by ~R̃_s|i|/ω_e, L_M by ~L̃_M i_d: one steady operating point cannot
        # tell them apart, a changing operating point can. Where R_s weighs more than
        # SPLIT_RATIO of the flux's rate (R_s|i| > SPLIT_RATIO·|ω_e||φ|: low stator
        # frequency, low flux) L_M is held and R_s learnt, elsewhere the reverse
        # (docs/sensorless.md §3, docs/adaptation.md §4).
        self._hold_L_M = low = (self.R_s * abs(i)
                                > SPLIT_RATIO * abs(self._omega_e) * abs(self._phi_cm))
        if self.sensorless:     # in R_R's place (R̂_R held, so c held is L_M held)
            cols[1] = 0j if self.temperatures is not None else gz   # (or its temperature)
            if low:
                cols[2] = 0j
        else:                   # R_R with c = R_R/L̂_M: −∂e/∂R_R = Hi − Hφ/L̂_M
            if low:
                cols[1] = Hi - Hphi / self.L_M
                cols[2] = 0j
            cols.append(gz if low else 0j)

    def _start_offset_regressors(self, rot) -> list:
        """Return the regressors of the start offset δ's real and imaginary parts: g_w, j g_w."""
        fa, fb = self._fa, self._fb
        w_r = self._w * rot
        Hw = self._Hw = fa * self._Hw + fb * (w_r + self._uw)
        self._uw = w_r
        gw = self._wf * (w_r - Hw) + self._c * Hw
        return [gw, 1j * gw]

    def _accumulate_normal_equations(self, cols, e) -> None:
        """Add one period's regressors ``cols`` and residual ``e`` to the sums S and b."""
        S, b = self._S, self._b
        er, ei = e.real, e.imag
        if len(cols) == 3:      # the usual set, unrolled: the loop below costs 1.5 µs a period
            g1, g2, g3 = cols
            x1, y1, x2, y2, x3, y3 = g1.real, g1.imag, g2.real, g2.imag, g3.real, g3.imag
            S[0] += x1 * x1 + y1 * y1
            S[1] += x1 * x2 + y1 * y2
            S[2] += x1 * x3 + y1 * y3
            S[3] += x2 * x2 + y2 * y2
            S[4] += x2 * x3 + y2 * y3
            S[5] += x3 * x3 + y3 * y3
            b[0] += x1 * er + y1 * ei
            b[1] += x2 * er + y2 * ei
            b[2] += x3 * er + y3 * ei
        else:
            X = [q.real for q in cols]
            Y = [q.imag for q in cols]
            for k, (p, q) in enumerate(self._pairs):
                S[k] += X[p] * X[q] + Y[p] * Y[q]
            for p in range(len(cols)):
                b[p] += X[p] * er + Y[p] * ei

    def _ls_update(self):
        f = self._floor
        S, b, R = self._S, self._b, self._R
        n = len(b)
        # Per-parameter exponential forgetting over N periods: R_ij ← √(λ_i λ_j)^N R_ij, plus the
        # information floor's share of those N periods.
        lam = self._lamN
        share = self._share
        for j in range(len(R)):
            R[j] = lam[j] * R[j] + S[j]
            S[j] = 0.0
        diag = 0
        for p in range(n):
            R[diag] += share[p] * f[p]
            diag += n - p
        g = list(b)
        for p in range(n):
            b[p] = 0.0
        t = self.temperatures
        if t is not None and (self.freeze or not self.sensorless):
            # the windings still warm; sensored, what the networks moved since the last anchor
            # is the prediction the increments below correct (their residuals were taken at the
            # old estimates over N periods)
            self._follow_temperatures()
        if self.freeze:
            return
        c = self._c
        L_sig = self.L_sigma
        if self.estimate_leakage:
            d = _solve_sym(R, g, n)
            L_sig = _clip(L_sig + d[0], self.L_sigma_lo, self.L_sigma_hi)
        else:                   # L_σ held: the solve in the others (row and column 0 left out)
            d = [0.0] + list(_solve_sym(R[n:], g[1:], n - 1))
        d1 = d[1]
        c = c + d[2]
        names = self._names
        if self.sensorless:      # the second parameter is R_s; R̂_R held
            R_s = _clip(self.R_s + d1, self.R_s_lo, self.R_s_hi)
            self._shift_stator_resistance(R_s - self.R_s)
            R_R = self.R_R
        else:
            R_R = _clip(self.R_R + d1, self.R_R_lo, self.R_R_hi)
            if self.estimate_R_s:
                R_s = _clip(self.R_s + d[3], self.R_s_lo, self.R_s_hi)
                self._shift_stator_resistance(R_s - self.R_s)
                if self._hold_L_M:      # R_R moved with c = R_R/L̂_M
                    c = R_R / self.L_M
        if self._w:
            k = names.index('offset_re')
            self._shift_start_offset(complex(d[k], d[k + 1]))
        L_M = _clip(R_R / max(c, 1e-12), self.L_M_lo, self.L_M_hi)
        self.L_sigma = L_sig
        self.R_R = R_R
        self.L_M = L_M
        self._c = R_R / L_M
        self._publish_pair(R_R, self._c)
        if t is not None:
            if self.sensorless:     # R_s, R_R at the windings' temperatures
                self._follow_temperatures()
            else:                   # the windings at the temperatures of the estimates
                t.anchor(self.R_s, self.R_R)

    def _follow_temperatures(self) -> None:
        """R̂_s and R̂_R at the windings' estimated temperatures, L̂_M and L̂_σ unchanged."""
        t = self.temperatures
        R_s = _clip(t.R_s, self.R_s_lo, self.R_s_hi)
        self._shift_stator_resistance(R_s - self.R_s)
        R_R = _clip(t.R_R, self.R_R_lo, self.R_R_hi)
        self.R_R = R_R
        self._c = R_R / self.L_M
        self._publish_pair(R_R, self._c)

    def _shift_start_offset(self, d: complex) -> None:
        """
        Remove the estimated part d of the start offset from ψ̂ and its filter states.

        ψ̂ is linear in the offset (∂ψ̂/∂δ = w), so the next residuals see the corrected flux.
        Once w|ψ̂(t_0)| is 1 % of the flux floor the offset is gone and leaves the least squares.
        """
        self._psi -= d * self._w
        self._Hpsi -= d * self._Hw
        ui, upsi = self._u_prev
        self._u_prev = (ui, upsi - d * self._uw)
        if self._w < 0.01 * self._w_floor:
            self._w = 0.0
            self._names = self._names[:-2]
            self._size()

    def _shift_stator_resistance(self, dR: float) -> None:
        """
        Move R̂_s by dR, with ψ̂ and its filter states as if integrated with the new R̂_s.

        ψ̂ is linear in R_s (∂ψ̂/∂R_s = −z), so the next residuals see the change.
        """
        self.R_s += dR
        self._psi -= dR * self._z
        self._Hpsi -= dR * self._Hz
        ui, upsi = self._u_prev
        self._u_prev = (ui, upsi - dR * self._uz)

    def _publish_pair(self, R_R, c):
        """
        θ̂ = L̂_M/L̂_sr and R̂_r = R̂_R/θ̂², projected.

        R̂_r θ̂² = R̂_R holds even when θ̂ is at its σ̂ bound (the rotor resistance seen
        from the terminals, which the closed loop needs most; see docs/adaptation.md),
        while L̂_sr θ̂ = L̂_M only inside the bounds.
        """
        th = _clip(self.L_M / self.L_sr, self.theta_lo, self.theta_hi)
        self.theta = th
        self.R_r = _clip(R_R / (th * th), self.R_r_lo, self.R_r_hi)
