"""Shaft loads: torque opposing the motor, τ_L(t, θ, ω) [N·m] (seed 000 §3.4.5)."""
from __future__ import annotations

from dataclasses import dataclass
import math

from .params import InvalidParameter, read_yaml_file


class Load:
    """Base class: ``torque(t, theta, omega)`` returns the load torque τ_L [N·m]."""

    name = 'none'

    def torque(self, t: float, theta: float, omega: float) -> float:  # pragma: no cover - abstract
        raise NotImplementedError

    def rate(self, t: float, theta: float, omega: float, accel: float) -> float:
        """
        dτ_L/dt along a motion (θ, ω, ω̇).

        What a controller feeding the load model forward needs for dτ*/dt without
        differentiating numerically.
        """
        return 0.0

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

    def rate(self, t, theta, omega, accel):
        return -self.mgl * math.sin(theta) * omega

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

    def rate(self, t, theta, omega, accel):
        return self.c2 * accel

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


LOAD_FIELDS = {'none': (), 'constant': ('tau',), 'pendulum': ('mgl',), 'linear': ('c1', 'c2')}


def load_from_dict(doc, source: str = 'load') -> Load:
    """
    Return a load from a description ``{kind: linear, c1: 1.0, c2: 0.001}``.

    The form of YAML ``--load`` files.

    Every error is one line naming ``source`` and the field.
    """
    if not isinstance(doc, dict):
        raise InvalidParameter(f'{source}', doc, 'must be a mapping with a kind')
    kind = doc.get('kind')
    if kind not in LOAD_FIELDS:
        raise InvalidParameter(f'{source}: kind', kind, f'must be one of {", ".join(LOAD_KINDS)}')
    allowed = LOAD_FIELDS[kind]
    values = {}
    for key, val in doc.items():
        if key == 'kind':
            continue
        if key not in allowed:
            fields = ', '.join(allowed) or 'none'
            raise InvalidParameter(f'{source}: {key}', val,
                                   f'unknown for a {kind} load (fields: {fields})')
        if isinstance(val, bool) or not isinstance(val, (int, float)) or not math.isfinite(val):
            raise InvalidParameter(f'{source}: {key}', val, 'must be a finite number')
        values[key] = float(val)
    return make_load(kind, **values)


def load_file(path: str) -> Load:
    """Read a load description (YAML mapping, see :func:`load_from_dict`) from ``path``."""
    return load_from_dict(read_yaml_file(path, 'load file'), source=path)


def load_parameters(load: Load) -> dict:
    """
    Return the node parameters that rebuild ``load``.

    They are (``load``, ``load_mgl``, ``load_c1``, ``load_c2``, ``load_tau``)
    that rebuild ``load`` with :func:`make_load` — plant and controller read the same ones.
    """
    d = load.describe()
    out = {'load': d['kind']}
    for key in LOAD_FIELDS[d['kind']]:
        out['load_' + key] = float(d[key])
    return out
