"""
Rotor-flux strategies and the smoothing filters that give references their derivatives.

Flux strategies map the torque reference τ* (and the speed) to a *target* rotor flux φ_tgt:

``min_energy`` (seed 000 eq. 3.19, 3.22, 3.25)
    Slip at the minimum-magnetic-energy value ω_sl⁰ = R_r/(L_r√σ) while the flux it implies,
    φ = √(R_r|τ*|/(v ω_sl⁰)), lies in [φ_min, φ_max]; otherwise the flux is held at the bound
    (the constant-flux branches ω_sl = R_r τ*/(v φ_bound²) of eq. 3.25). Written in terms of the
    flux this is one clip, and it extends (3.25) to negative torques (|τ*|, slip of τ*'s sign).
``constant_flux`` (eq. 3.23-3.24)
    φ_tgt = φ_d.
``min_loss`` (beyond the thesis)
    The flux minimizing the steady-state copper + core loss (eq. 3.34-3.38) at the demanded
    torque and the measured speed:
    P(φ) = A φ² + C τ²/φ² + K(f_e) (θφ)^m, A = R_s/L_sr², C = (R_s L_r²/L_sr² + R_r)/v²,
    K = (k_h + k_e f_e) f_e, f_e = |v ω_r + ω_sl(φ)|/2π. For m = 2: φ⁴ = C τ²/(A + K θ²);
    for m = 1 a Newton solve of 2Aφ⁴ + Kθφ³ − 2Cτ² = 0; f_e is refreshed twice with the slip
    of the current solution. Clipped to [φ_min, φ_max].
``optimal`` (beyond the thesis)
    When the reference is known ahead, the controller plans the loss-optimal flux trajectory over
    it (:mod:`.flux_plan`, a convex program, docs/controller.md §10) and its reference follows the
    plan; ``target`` — the causal plan it falls back to (live setpoints, the torque task, past the
    plan's end) and the steady start — is ``min_loss``'s.

Under a current limit the two optimizing strategies keep their flux where the steady current for
the torque fits (:func:`flux_range_within_current`, docs/limits.md).

The target is not used directly: eq. 3.13 needs dφ*/dt and d²φ*/dt² (the d-axis current and its
derivative), and τ* needs dτ*/dt. Both come out of linear filters whose *states are the
derivatives* (:class:`LowPass2`), discretized exactly for a held input — no numerical
differentiation, so measurement noise enters the voltage only through bounded filter gains.
"""
from __future__ import annotations

import math
from typing import Literal, Optional

from .reference import ModelCoefficients

#: the flux strategies' names, their one home; :data:`Strategy` is their type (the controller
#: configuration's ``strategy`` field validates a name against it, the one check)
STRATEGIES = ('min_energy', 'constant_flux', 'min_loss', 'optimal')
Strategy = Literal[STRATEGIES]
#: the causal strategies every study compares (the thesis's two and ours); ``optimal`` plans ahead
COMPARED_STRATEGIES = ('min_energy', 'constant_flux', 'min_loss')
# the strategies whose causal target is the steady loss-optimal flux (optimal falls back to it)
LOSS_OPTIMAL = ('min_loss', 'optimal')
#: what the loss-optimizing strategies minimize (the run file's ``loss_scope``): the motor's
#: losses, or the drive's — the motor's plus the inverter's conduction and switching losses
#: r|i|² + c|i| (:meth:`im_common.inverter.Inverter.steady_loss_coefficients`)
LOSS_SCOPES = ('motor', 'drive')
TWO_PI = 2.0 * math.pi


class LowPass2:
    """
    y'' = p₁p₂(u − y) − (p₁ + p₂) y', poles −p₁, −p₂ (time constants τ₁ = 1/p₁, τ₂ = 1/p₂).

    Unity DC gain. ``advance(dt)`` propagates (y, y') exactly over dt with the input held
    (zero-order hold); ``accel`` is y'' right after the last ``set_input``.
    """

    __slots__ = ('p_sum', 'p_prod', 'y', 'dy', 'u', '_dt', '_phi')

    def __init__(self, tau1: float, tau2: float, y0: float = 0.0, dy0: float = 0.0, u0=None):
        for name, tc in (('tau1', tau1), ('tau2', tau2)):
            if not (math.isfinite(tc) and tc > 0.0):
                raise ValueError(f"filter time constant '{name}' = {tc!r} must be > 0 s")
        p1, p2 = 1.0 / tau1, 1.0 / tau2
        self.p_sum = p1 + p2
        self.p_prod = p1 * p2
        self.y = float(y0)
        self.dy = float(dy0)
        self.u = float(y0 if u0 is None else u0)
        self._dt = None
        self._phi = None

    def reset(self, y: float, dy: float = 0.0, u=None) -> None:
        self.y, self.dy = float(y), float(dy)
        self.u = float(y if u is None else u)

    def _transition(self, dt: float):
        """Φ = e^{A dt} of A = [[0, 1], [−p₁p₂, −(p₁+p₂)]] (closed form)."""
        if dt == self._dt:
            return self._phi
        a0, a1 = self.p_prod, self.p_sum
        disc = a1 * a1 - 4.0 * a0
        if disc > 1e-9 * a1 * a1:
            r = math.sqrt(disc)
            l1, l2 = 0.5 * (-a1 + r), 0.5 * (-a1 - r)
            e1, e2 = math.exp(l1 * dt), math.exp(l2 * dt)
            c0 = (l1 * e2 - l2 * e1) / (l1 - l2)
            c1 = (e1 - e2) / (l1 - l2)
        else:  # repeated pole
            lam = -0.5 * a1
            e = math.exp(lam * dt)
            c0 = e * (1.0 - lam * dt)
            c1 = e * dt
        # Φ = c0 I + c1 A
        phi = (c0, c1, -a0 * c1, c0 - a1 * c1)
        self._dt, self._phi = dt, phi
        return phi

    def advance(self, dt: float) -> None:
        if dt <= 0.0:
            return
        f11, f12, f21, f22 = self._transition(dt)
        ey = self.y - self.u           # deviation from the steady state (u, 0)
        dy = self.dy
        self.y = self.u + f11 * ey + f12 * dy
        self.dy = f21 * ey + f22 * dy

    def set_input(self, u: float) -> None:
        self.u = u

    @property
    def accel(self) -> float:
        return self.p_prod * (self.u - self.y) - self.p_sum * self.dy


def flux_min_energy(c: ModelCoefficients, tau: float, phi_min: float, phi_max: float) -> float:
    """Eq. 3.25 as a flux: √(R_r|τ|/(v ω_sl⁰)) clipped to [φ_min, φ_max]."""
    phi = math.sqrt(c.R_r * abs(tau) / (c.v * c.slip_min_energy))
    return phi_min if phi < phi_min else (phi_max if phi > phi_max else phi)


def flux_range_within_current(c: ModelCoefficients, tau: float, i_max: float):
    """
    Return (φ₁, φ₂): the rotor fluxes whose steady currents for the torque τ fit in ``i_max``.

    i_d = φ/L_sr, i_q = L_r τ/(v L_sr φ), i_d² + i_q² ≤ i_max² is, with x = φ², the quadratic
    x²/L_sr² − i_max² x + b ≤ 0, b = (L_r τ/(v L_sr))², between its roots
    x₁ = 2b/(i_max² + √D), x₂ = L_sr² (i_max² + √D)/2, D = i_max⁴ − 4b/L_sr². A torque beyond
    the current's reach at any flux (D ≤ 0) gets the flux of most torque per ampere, i_d = i_q:
    φ₁ = φ₂ = L_sr i_max/√2. The optimizing strategies' flux is clipped into it
    (docs/limits.md): min-energy's is far below φ₁ near the limit, min-loss's can pass φ₂.
    """
    b = (c.L_r * tau / (c.v * c.L_sr)) ** 2
    i2 = i_max * i_max
    disc = i2 * i2 - 4.0 * b / (c.L_sr * c.L_sr)
    if disc <= 0.0:
        phi = c.L_sr * i_max / math.sqrt(2.0)
        return phi, phi
    r = i2 + math.sqrt(disc)
    return math.sqrt(2.0 * b / r), c.L_sr * math.sqrt(0.5 * r)


def _on_the_curve(A: float, Ct2: float, Kt2: float, b: float, S: float, y: float) -> float:
    """
    Return y = φ² minimizing A y (1 + b y^(S/2))² + Cτ²/y + Kθ² y (the steady loss on the curve).

    Convex in y > 0: Newton from ``y`` (the linear optimum, which lies above the curve's), kept
    positive; 8 steps reach 1e-12 relative on the shipped curves.
    """
    k = 0.5 * S
    for _ in range(8):
        yk = y ** k
        g = 1.0 + b * yk
        g1 = b * k * yk / y
        g2 = g1 * (k - 1.0) / y
        d1 = A * (g * g + 2.0 * y * g * g1) - Ct2 / (y * y) + Kt2
        d2 = A * (4.0 * g * g1 + 2.0 * y * g1 * g1 + 2.0 * y * g * g2) + 2.0 * Ct2 / (y * y * y)
        step = d1 / d2
        y = max(y - step, 0.25 * y)
        if abs(step) <= 1e-12 * y:
            break
    return y


def flux_min_loss(c: ModelCoefficients, tau: float, omega_r: float, phi_min: float, phi_max: float,
                  k_e: float, k_h: float, core_exponent: float = 2.0, sat=None,
                  inverter=None) -> float:
    """
    Steady-state loss-minimizing flux (see module docstring), clipped to [φ_min, φ_max].

    ``sat`` (b, S) of :func:`~im_controller.flux_plan.saturation_terms`: on the magnetizing
    curve, the copper term A φ²(1 + b φ^S)² (``c`` then the unsaturated model's, exponent 2);
    or g(φ) of a table curve (:func:`~im_controller.flux_plan.curve_shape`), A φ² g(φ)².
    ``inverter`` (r, c_i): the drive's losses, the inverter's r|i|² + c_i|i| added
    (:func:`_drive_min_loss`).
    """
    A = c.R_s / (c.L_sr * c.L_sr)
    C = (c.R_s * c.L_r * c.L_r / (c.L_sr * c.L_sr) + c.R_r) / (c.v * c.v)
    th = c.theta
    tau2 = tau * tau
    ve = c.v * omega_r
    phi = (C * tau2 / A) ** 0.25  # copper-only optimum: the starting point
    if phi < phi_min:
        phi = phi_min
    if (inverter is not None and (inverter[0] > 0.0 or inverter[1] > 0.0)) or callable(sat):
        # the inverter's losses, or a table curve: no closed form
        return _drive_min_loss(c, tau, omega_r, phi_min, phi_max, k_e, k_h, core_exponent, sat,
                               inverter or (0.0, 0.0), phi)
    for _ in range(2):  # refresh f_e with the slip of the current solution
        f_e = abs(ve + c.R_r * tau / (c.v * phi * phi)) / TWO_PI
        K = (k_h + k_e * f_e) * f_e
        if core_exponent == 2.0:
            phi = (C * tau2 / (A + K * th * th)) ** 0.25
            if sat is not None and tau2 > 0.0:
                phi = math.sqrt(_on_the_curve(A, C * tau2, K * th * th, sat[0], sat[1],
                                              phi * phi))
        else:
            x = (C * tau2 / A) ** 0.25   # h(x) = 2A x⁴ + Kθ x³ − 2Cτ² ≥ 0 here; Newton descends
            for _ in range(5):
                h = 2.0 * A * x ** 4 + K * th * x ** 3 - 2.0 * C * tau2
                dh = 8.0 * A * x ** 3 + 3.0 * K * th * x * x
                if dh <= 0.0:
                    break
                x -= h / dh
            phi = x
        if phi < phi_min:
            phi = phi_min
        elif phi > phi_max:
            phi = phi_max
    return phi


def _drive_loss(c: ModelCoefficients, tau: float, omega_r: float, k_e: float, k_h: float,
                core_exponent: float, sat, inverter, phi: float) -> float:
    """
    Return the drive's steady loss at the rotor flux φ: the motor's plus the inverter's [W].

    i_d = φ g(φ)/L_sr (g = 1 + bφ^S on a power-law curve, a table's own, 1 off the curve),
    i_q = L_r τ/(v L_sr φ): copper
    R_s|i|² + R_r τ²/(vφ)², core (k_h + k_e f_e) f_e (θφ)^m, inverter r|i|² + c_i|i|.
    """
    if sat is None:
        g = 1.0
    elif callable(sat):                         # a table curve (flux_plan.curve_shape)
        g = sat(phi)
    else:
        g = 1.0 + sat[0] * phi ** sat[1]
    i_d = phi * g / c.L_sr
    i_q = c.L_r * tau / (c.v * c.L_sr * phi)
    i2 = i_d * i_d + i_q * i_q
    r, ci = inverter
    f_e = abs(c.v * omega_r + c.R_r * tau / (c.v * phi * phi)) / TWO_PI
    core = (k_h + k_e * f_e) * f_e * (c.theta * phi) ** core_exponent
    return ((c.R_s + r) * i2 + c.R_r * (tau / (c.v * phi)) ** 2 + core + ci * math.sqrt(i2))


def _drive_min_loss(c: ModelCoefficients, tau: float, omega_r: float, phi_min: float,
                    phi_max: float, k_e: float, k_h: float, core_exponent: float, sat, inverter,
                    phi0: float) -> float:
    """
    Return the flux minimizing :func:`_drive_loss` in [φ_min, φ_max].

    The inverter's c_i|i| is not quadratic in φ, so no closed form: Newton on u = ln φ with
    central differences, from the copper-only optimum, each step kept within a factor 1.5 and
    taken only while the loss falls (the loss is unimodal in φ between its copper terms' rise
    at both ends); at most 12 steps (from a far start on a steep curve 7 reach 1e-9 of φ).
    """
    lo, hi = math.log(phi_min), math.log(phi_max)
    u = min(max(math.log(phi0), lo), hi)

    def f(x):
        return _drive_loss(c, tau, omega_r, k_e, k_h, core_exponent, sat, inverter,
                           math.exp(x))
    h = 1e-3
    fu = f(u)
    for _ in range(12):
        fp, fm = f(u + h), f(u - h)
        d1 = (fp - fm) / (2.0 * h)
        d2 = (fp - 2.0 * fu + fm) / (h * h)
        step = -d1 / d2 if d2 > 0.0 else -math.copysign(0.4, d1)
        step = max(-0.4, min(0.4, step))
        while True:
            un = min(max(u + step, lo), hi)
            fn = f(un)
            if fn <= fu or abs(step) < 1e-7:
                break
            step *= 0.5
        done = abs(un - u) < 1e-6
        u, fu = un, min(fn, fu)
        if done:
            break
    return math.exp(u)


class FluxStrategy:
    """
    Target rotor flux for a torque demand: ``target(coefficients, tau, omega_r)``.

    ``i_max`` (A, None: no bound): the optimizing strategies' flux is clipped into
    :func:`flux_range_within_current` of it, then into [φ_min, φ_max]; constant flux keeps φ_d.
    ``name`` is one of :data:`STRATEGIES`, validated by the configuration that chose it
    (:class:`im_controller.control_law.ControllerConfig`).
    """

    def __init__(self, name: Strategy, phi_d: float = 1.2, phi_min: float = 0.2,
                 phi_max: float = 1.2, k_e: float = 0.012, k_h: float = 0.012,
                 core_exponent: float = 2.0, i_max: Optional[float] = None, curve=None,
                 inverter=None):
        self.name = name
        self.phi_d, self.phi_min, self.phi_max = float(phi_d), float(phi_min), float(phi_max)
        self.k_e, self.k_h, self.core_exponent = float(k_e), float(k_h), float(core_exponent)
        self.i_max = i_max
        #: on the magnetizing curve: (unsaturated coefficients, (b, S)) — min_loss's optimum
        #: is the curve's (the secant coefficients the model runs on are not its derivative)
        self.curve = curve
        #: the inverter's (r, c_i) the loss-optimizing strategies add (loss_scope drive; None:
        #: the motor's losses alone)
        self.inverter = inverter if inverter and (inverter[0] or inverter[1]) else None

    def target(self, c: ModelCoefficients, tau: float, omega_r: float) -> float:
        if self.name == 'constant_flux':
            return self.phi_d
        if self.name == 'min_energy':
            phi = flux_min_energy(c, tau, self.phi_min, self.phi_max)
        elif self.curve is not None:
            c0, sat = self.curve
            phi = flux_min_loss(c0, tau, omega_r, self.phi_min, self.phi_max, self.k_e, self.k_h,
                                self.core_exponent, sat, self.inverter)
        else:
            phi = flux_min_loss(c, tau, omega_r, self.phi_min, self.phi_max, self.k_e, self.k_h,
                                self.core_exponent, inverter=self.inverter)
        if self.i_max is None:
            return phi
        lo, hi = flux_range_within_current(c, tau, self.i_max)
        phi = min(max(phi, lo), hi)
        return min(max(phi, self.phi_min), self.phi_max)
