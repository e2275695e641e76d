"""Shaft loads: torque opposing the motor, τ_L(t, θ, ω) [N·m] (seed 000 §3.4.5)."""
from __future__ import annotations

import math
from dataclasses import dataclass

from .params import InvalidParameter


class Load:
    """Base class: ``torque(t, theta, omega)`` returns the load torque τ_L [N·m]."""

    name = 'none'

    def torque(self, t: float, theta: float, omega: float) -> float:  # pragma: no cover - abstract
        raise NotImplementedError

    def describe(self) -> dict:
        return {'kind': self.name}


@dataclass
class NoLoad(Load):
    name = 'none'

    def torque(self, t, theta, omega):
        return 0.0


@dataclass
class ConstantLoad(Load):
    tau: float = 0.0
    name = 'constant'

    def __post_init__(self):
        if not math.isfinite(self.tau):
            raise InvalidParameter('load_tau', self.tau, 'must be finite')

    def torque(self, t, theta, omega):
        return self.tau

    def describe(self):
        return {'kind': self.name, 'tau': self.tau}


@dataclass
class PendulumLoad(Load):
    """Inverted pendulum τ_L = mgl·cos θ (position task, mgl = 10 N·m)."""

    mgl: float = 10.0
    name = 'pendulum'

    def __post_init__(self):
        if not math.isfinite(self.mgl):
            raise InvalidParameter('load_mgl', self.mgl, 'must be finite')

    def torque(self, t, theta, omega):
        return self.mgl * math.cos(theta)

    def describe(self):
        return {'kind': self.name, 'mgl': self.mgl}


@dataclass
class LinearLoad(Load):
    """τ_L = c1 + c2·ω (speed task: c1 = 1 N·m, c2 = 0.001 N·m·s)."""

    c1: float = 1.0
    c2: float = 0.001
    name = 'linear'

    def __post_init__(self):
        for k in ('c1', 'c2'):
            if not math.isfinite(getattr(self, k)):
                raise InvalidParameter('load_' + k, getattr(self, k), 'must be finite')

    def torque(self, t, theta, omega):
        return self.c1 + self.c2 * omega

    def describe(self):
        return {'kind': self.name, 'c1': self.c1, 'c2': self.c2}


LOAD_KINDS = ('none', 'constant', 'pendulum', 'linear')


def make_load(kind: str, mgl: float = 10.0, c1: float = 1.0, c2: float = 0.001,
              tau: float = 0.0) -> Load:
    """Build a load by name (the plant node's ``load`` parameter)."""
    if kind == 'none':
        return NoLoad()
    if kind == 'constant':
        return ConstantLoad(tau)
    if kind == 'pendulum':
        return PendulumLoad(mgl)
    if kind == 'linear':
        return LinearLoad(c1, c2)
    raise InvalidParameter('load', kind, f'must be one of {", ".join(LOAD_KINDS)}')
