"""
Reference trajectories for the shaft, with analytic derivatives (seed 000 §3.4.4).

Every trajectory answers ``sample(t) -> (p, v, a, j)``: position θ* [rad], velocity ω* [rad/s],
acceleration [rad/s²] and jerk [rad/s³] at time t. The controller needs p, v, a for the mechanical
feedforward of eq. 3.1 and j for the time derivative of that feedforward (which enters the
electrical reference, eq. 3.13, through dτ*/dt). Nothing is differentiated numerically.

Thesis profiles (t in s):

* position: θ* = −π/2 for t < 0.4, then −π/2 + (12π/10)(1 − e^{−10(t−0.4)²})³;
* speed: ω* = 135 for t < 0.2, then 135 + 45(1 − e^{−10(t−0.2)²})³. The position reference of the
  speed task is the exact integral θ*(t) = θ₀ + ∫₀ᵗ ω*, in closed form with erf.

The shape f(s) = (1 − e^{−k s²})³ starts like k³s⁶, so it is five times continuously
differentiable at s = 0 and the piecewise definitions above are smooth.

Setpoints (``set_setpoint`` of the controller) are quintic transitions from the current
(value, rate, acceleration) to (target, 0, 0) over a given duration, so a new setpoint issued
in the middle of a transition keeps the reference C².
"""
from __future__ import annotations

import math
from typing import Tuple

Sample = Tuple[float, float, float, float]

_SQRT_PI = math.sqrt(math.pi)


def cubed_gaussian_step(s: float, k: float = 10.0) -> Tuple[float, float, float, float]:
    """f(s) = (1 − e^{−k s²})³ for s ≥ 0 (0 before) and its first three derivatives."""
    if s <= 0.0:
        return 0.0, 0.0, 0.0, 0.0
    u = math.exp(-k * s * s)
    # derivatives of u = exp(−k s²)
    u1 = -2.0 * k * s * u
    u2 = (4.0 * k * k * s * s - 2.0 * k) * u
    u3 = (12.0 * k * k * s - 8.0 * k * k * k * s * s * s) * u
    g = 1.0 - u
    g1, g2, g3 = -u1, -u2, -u3
    f = g * g * g
    f1 = 3.0 * g * g * g1
    f2 = 6.0 * g * g1 * g1 + 3.0 * g * g * g2
    f3 = 6.0 * g1 * g1 * g1 + 18.0 * g * g1 * g2 + 3.0 * g * g * g3
    return f, f1, f2, f3


def cubed_gaussian_step_integral(s: float, k: float = 10.0) -> float:
    """
    F(s) = ∫₀ˢ (1 − e^{−k x²})³ dx (0 for s ≤ 0), closed form with erf.

    (1 − u)³ = 1 − 3u + 3u² − u³ and ∫₀ˢ e^{−n k x²} dx = ½ √(π/(n k)) erf(√(n k) s).
    """
    if s <= 0.0:
        return 0.0

    def gauss(n):
        a = n * k
        return 0.5 * _SQRT_PI / math.sqrt(a) * math.erf(math.sqrt(a) * s)

    return s - 3.0 * gauss(1) + 3.0 * gauss(2) - gauss(3)


class Trajectory:
    """Base class: ``sample(t)`` returns (position, velocity, acceleration, jerk)."""

    def sample(self, t: float) -> Sample:  # pragma: no cover - abstract
        raise NotImplementedError

    def describe(self) -> dict:
        return {'kind': type(self).__name__}


class ThesisPositionProfile(Trajectory):
    """θ* = θ₀ + A (1 − e^{−k(t−t₀)²})³ for t ≥ t₀ (θ₀ = −π/2, A = 12π/10, t₀ = 0.4, k = 10)."""

    def __init__(self, theta0: float = -0.5 * math.pi, amplitude: float = 1.2 * math.pi,
                 t0: float = 0.4, k: float = 10.0):
        self.theta0, self.amplitude = float(theta0), float(amplitude)
        self.t0, self.k = float(t0), float(k)

    def sample(self, t: float) -> Sample:
        f, f1, f2, f3 = cubed_gaussian_step(t - self.t0, self.k)
        A = self.amplitude
        return self.theta0 + A * f, A * f1, A * f2, A * f3

    def describe(self):
        return {'kind': 'thesis_position', 'theta0': self.theta0, 'amplitude': self.amplitude,
                't0': self.t0, 'k': self.k}


class ThesisSpeedProfile(Trajectory):
    """
    ω* = ω₀ + A (1 − e^{−k(t−t₀)²})³ for t ≥ t₀ (ω₀ = 135, A = 45, t₀ = 0.2, k = 10).

    θ* = θ₀ + ω₀ t + A ∫ f, exact.
    """

    def __init__(self, omega0: float = 135.0, amplitude: float = 45.0, t0: float = 0.2,
                 k: float = 10.0, theta0: float = 0.0):
        self.omega0, self.amplitude = float(omega0), float(amplitude)
        self.t0, self.k = float(t0), float(k)
        self.theta0 = float(theta0)

    def sample(self, t: float) -> Sample:
        s = t - self.t0
        f, f1, f2, _ = cubed_gaussian_step(s, self.k)
        A = self.amplitude
        theta = self.theta0 + self.omega0 * t + A * cubed_gaussian_step_integral(s, self.k)
        return theta, self.omega0 + A * f, A * f1, A * f2

    def describe(self):
        return {'kind': 'thesis_speed', 'omega0': self.omega0, 'amplitude': self.amplitude,
                't0': self.t0, 'k': self.k, 'theta0': self.theta0}


#: The thesis's reference of each task (seed 000 §3.4.4-3.4.5): the controller's ``profile:
#: thesis``, and what a run record writes for it (its ``describe()``).
THESIS_TRAJECTORIES = {'position': ThesisPositionProfile, 'speed': ThesisSpeedProfile}


class Quintic:
    """
    A quintic polynomial p(τ), τ = t − t₀ ∈ [0, T], joining (p₀, v₀, a₀) to (p₁, 0, 0).

    Before t₀ it returns the start state extrapolated as a constant-acceleration arc is *not*
    wanted, so t < t₀ is clamped to t₀; after t₀ + T it holds p₁. ``integral(t)`` is ∫_{t₀}^{t} p.
    """

    def __init__(self, t0: float, duration: float, p0: float, v0: float, a0: float, p1: float):
        if not (math.isfinite(duration) and duration > 0.0):
            raise ValueError(f'transition duration must be > 0 s, got {duration!r}')
        T = float(duration)
        self.t0, self.T, self.p1 = float(t0), T, float(p1)
        d = p1 - p0 - v0 * T - 0.5 * a0 * T * T
        dv = -v0 - a0 * T
        da = -a0
        # c3 τ³ + c4 τ⁴ + c5 τ⁵ matches (d, dv, da) at τ = T.
        c3 = (10.0 * d - 4.0 * dv * T + 0.5 * da * T * T) / T ** 3
        c4 = (-15.0 * d + 7.0 * dv * T - da * T * T) / T ** 4
        c5 = (6.0 * d - 3.0 * dv * T + 0.5 * da * T * T) / T ** 5
        self.c = (float(p0), float(v0), 0.5 * float(a0), c3, c4, c5)
        c0, c1, c2 = self.c[:3]
        self._area_T = (c0 * T + c1 * T ** 2 / 2 + c2 * T ** 3 / 3 + c3 * T ** 4 / 4
                        + c4 * T ** 5 / 5 + c5 * T ** 6 / 6)

    def sample(self, t: float) -> Sample:
        tau = t - self.t0
        if tau <= 0.0:
            tau = 0.0
        if tau >= self.T:
            return self.p1, 0.0, 0.0, 0.0
        c0, c1, c2, c3, c4, c5 = self.c
        p = c0 + tau * (c1 + tau * (c2 + tau * (c3 + tau * (c4 + tau * c5))))
        v = c1 + tau * (2 * c2 + tau * (3 * c3 + tau * (4 * c4 + tau * 5 * c5)))
        a = 2 * c2 + tau * (6 * c3 + tau * (12 * c4 + tau * 20 * c5))
        j = 6 * c3 + tau * (24 * c4 + tau * 60 * c5)
        return p, v, a, j

    def integral(self, t: float) -> float:
        tau = t - self.t0
        if tau <= 0.0:
            return 0.0
        if tau >= self.T:
            return self._area_T + self.p1 * (tau - self.T)
        c0, c1, c2, c3, c4, c5 = self.c
        inner = c3 / 4 + tau * (c4 / 5 + tau * c5 / 6)
        return tau * (c0 + tau * (c1 / 2 + tau * (c2 / 3 + tau * inner)))


class SetpointPosition(Trajectory):
    """Position setpoints joined by quintic transitions."""

    def __init__(self, theta0: float = 0.0):
        self._seg = Quintic(0.0, 1.0, theta0, 0.0, 0.0, theta0)

    def set(self, value: float, t: float, duration: float) -> None:  # noqa: A003
        p, v, a, _ = self.sample(t)
        self._seg = Quintic(t, duration, p, v, a, value)

    def sample(self, t: float) -> Sample:
        return self._seg.sample(t)

    def describe(self):
        return {'kind': 'setpoint_position', 'target': self._seg.p1}


class SetpointSpeed(Trajectory):
    """Speed setpoints joined by quintic transitions of ω*; θ* is the exact integral."""

    def __init__(self, omega0: float = 0.0, theta0: float = 0.0):
        self._seg = Quintic(0.0, 1.0, omega0, 0.0, 0.0, omega0)
        self._theta_start = float(theta0)
        self._t_start = 0.0

    def set(self, value: float, t: float, duration: float) -> None:  # noqa: A003
        theta, w, a, j = self.sample(t)
        self._theta_start = theta
        self._t_start = t
        self._seg = Quintic(t, duration, w, a, j, value)

    def sample(self, t: float) -> Sample:
        w, a, j, _ = self._seg.sample(t)
        if t >= self._t_start:
            theta = self._theta_start + self._seg.integral(t)
        else:
            theta = self._theta_start - self._seg.c[0] * (self._t_start - t)
        # the jerk of the speed reference (d²ω*/dt²) is the quintic's third output
        return theta, w, a, j

    def describe(self):
        return {'kind': 'setpoint_speed', 'target': self._seg.p1}


class SetpointTorque:
    """Torque setpoints with quintic transitions: ``sample(t) -> (τ*, dτ*/dt)``."""

    def __init__(self, tau0: float = 0.0):
        self._seg = Quintic(0.0, 1.0, tau0, 0.0, 0.0, tau0)

    def set(self, value: float, t: float, duration: float) -> None:  # noqa: A003
        p, v, a, _ = self._seg.sample(t)
        self._seg = Quintic(t, duration, p, v, a, value)

    def sample(self, t: float) -> Tuple[float, float]:
        p, v, _, _ = self._seg.sample(t)
        return p, v
