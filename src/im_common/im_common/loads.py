"""
Shaft loads: torque opposing the motor, τ_L(t, θ, ω) [N·m] (seed 000 §3.4.5).

The one home of a load: the plant, the ROS-free loop, the studies and the run record take the
same object. Two kinds are functions of the shaft state (``pendulum``, ``linear``; with
``none`` and ``constant`` the :data:`MODEL_KINDS` a controller can feed forward), two are loads
in time a user writes to disturb the drive (``step``, ``schedule``). :class:`LiveLoad` is the
plant's own wrapper: the load plus the live ``load_offset`` (docs/running.md, "Loads").
"""
from __future__ import annotations

import bisect
from dataclasses import dataclass
import math
from typing import Mapping, Tuple

from .params import InvalidParameter, read_yaml_file
from .validation import choice_error


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

    def feedforward(self) -> 'Load':
        """
        Return what a controller may feed forward of this load (its τ_c of eq. 3.1).

        A load of the shaft state is known as a model: itself. A load in time is a disturbance
        the drive does not know in advance: the torque it starts under, held
        (:meth:`StepLoad.feedforward`, :meth:`ScheduleLoad.feedforward`).
        """
        return self

    def change_time(self):
        """Return when a load in time first changes its torque [s] (None: a load of the state)."""
        return None


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


def _finite(name: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise InvalidParameter(name, value, 'must be a finite number')
    return float(value)


@dataclass
class StepLoad(Load):
    """
    A load step in time: τ_L = tau_before for t < t, tau_after from t on [N·m].

    Written ``{kind: step, t: 0.5, tau_before: 2.0, tau_after: 8.0}``.
    """

    t: float = 0.0
    tau_before: float = 0.0
    tau_after: float = 0.0
    name = 'step'

    def __post_init__(self):
        self.t = _finite('load_t', self.t)
        if self.t < 0:
            raise InvalidParameter('load_t', self.t, 'must be >= 0 s (the run starts at 0)')
        self.tau_before = _finite('load_tau_before', self.tau_before)
        self.tau_after = _finite('load_tau_after', self.tau_after)

    def torque(self, t, theta, omega):
        return self.tau_after if t >= self.t else self.tau_before

    def feedforward(self):
        return ConstantLoad(self.torque(0.0, 0.0, 0.0))

    def change_time(self):
        return self.t if self.tau_after != self.tau_before else None

    def describe(self):
        return {'kind': self.name, 't': self.t, 'tau_before': self.tau_before,
                'tau_after': self.tau_after}


@dataclass
class ScheduleLoad(Load):
    """
    Load torque in time through points (t_i, τ_i) [s, N·m]: piecewise linear between them.

    Written ``{kind: schedule, points: [[0.0, 2.0], [0.5, 2.0], [0.5, 8.0], [1.0, 4.0]]}``.
    Before the first point the first torque, after the last the last one. Times never decrease;
    a time given twice is a jump there (the second torque holds from that instant on), so
    steps and ramps mix in one schedule.
    """

    points: Tuple[Tuple[float, float], ...] = ((0.0, 0.0),)
    name = 'schedule'

    def __post_init__(self):
        pts = self.points
        if isinstance(pts, (str, bytes)) or not hasattr(pts, '__len__') or not len(pts):
            raise InvalidParameter('load_points', pts, 'must be a list of [t, tau] points')
        out = []
        for i, p in enumerate(pts):
            if isinstance(p, (str, bytes)) or not hasattr(p, '__len__') or len(p) != 2:
                raise InvalidParameter(f'load_points[{i}]', p, 'must be a point [t, tau]')
            t = _finite(f'load_points[{i}].t', p[0])
            tau = _finite(f'load_points[{i}].tau', p[1])
            if t < 0:
                raise InvalidParameter(f'load_points[{i}].t', t, 'must be >= 0 s')
            if out and t < out[-1][0]:
                raise InvalidParameter(f'load_points[{i}].t', t,
                                       f'times must not decrease (the point before is at '
                                       f'{out[-1][0]!r} s)')
            if len(out) >= 2 and t == out[-1][0] == out[-2][0]:
                raise InvalidParameter(f'load_points[{i}].t', t,
                                       'a time may be given twice (a jump), not three times')
            out.append((t, tau))
        self.points = tuple(out)
        self._times = [p[0] for p in out]

    def _segment(self, t: float) -> int:
        """Return i with points[i].t <= t < points[i+1].t (-1 before the first point)."""
        return bisect.bisect_right(self._times, t) - 1

    def torque(self, t, theta, omega):
        pts = self.points
        i = self._segment(t)
        if i < 0:
            return pts[0][1]
        if i >= len(pts) - 1:
            return pts[-1][1]
        (t0, a), (t1, b) = pts[i], pts[i + 1]
        return a + (b - a) * (t - t0) / (t1 - t0)     # t0 < t1: a jump's t0 is never i

    def rate(self, t, theta, omega, accel):
        pts = self.points
        i = self._segment(t)
        if i < 0 or i >= len(pts) - 1:
            return 0.0
        (t0, a), (t1, b) = pts[i], pts[i + 1]
        return (b - a) / (t1 - t0)

    def feedforward(self):
        return ConstantLoad(self.torque(0.0, 0.0, 0.0))

    def change_time(self):
        first = self.points[0][1]
        for i, (_t, tau) in enumerate(self.points):
            if tau != first:
                return self.points[i - 1][0]
        return None

    def describe(self):
        return {'kind': self.name, 'points': [[t, tau] for t, tau in self.points]}


class LiveLoad(Load):
    """
    The plant's load: a :class:`Load` plus ``offset``, the live ``load_offset`` [N·m].

    τ_L = load.torque(t, θ, ω) + offset. The plant sets ``offset`` between two steps only
    (:meth:`im_plant.plant_sim.PlantSimulator.set_load_offset`), so a change acts from a step
    boundary on. Its description is the load's: the offset is an event of the run, not a kind.
    """

    def __init__(self, load: Load, offset: float = 0.0):
        self.load = load
        self.name = load.name
        self.set_offset(offset)

    def set_offset(self, tau: float) -> None:
        """Add ``tau`` [N·m] to the load's torque (0: the load's own, called directly)."""
        self.offset = float(tau)
        # the model calls ``torque`` every RK4 stage: without an offset, the load's own method
        self.torque = self.load.torque if self.offset == 0.0 else self._offset_torque

    def _offset_torque(self, t, theta, omega):
        return self.load.torque(t, theta, omega) + self.offset

    def torque(self, t, theta, omega):      # replaced per instance by set_offset
        return self.load.torque(t, theta, omega) + self.offset

    def rate(self, t, theta, omega, accel):
        return self.load.rate(t, theta, omega, accel)

    def describe(self):
        return self.load.describe()

    def feedforward(self):
        return self.load.feedforward()

    def change_time(self):
        return self.load.change_time()


#: the kinds a controller's load model takes (functions of the shaft state; eq. 3.1's τ_c)
MODEL_KINDS = ('none', 'constant', 'pendulum', 'linear')
#: every kind a plant applies: the model kinds and the loads in time
LOAD_KINDS = MODEL_KINDS + ('step', 'schedule')


def make_load(kind: str, mgl: float = 10.0, c1: float = 1.0, c2: float = 0.001,
              tau: float = 0.0, t: float = 0.0, tau_before: float = 0.0,
              tau_after: float = 0.0, points=((0.0, 0.0),)) -> Load:
    """
    Build a load by name (the nodes' ``load`` parameter and its ``load_*`` values).

    ``points`` takes the pairs [[t, tau], ...] or the node parameter's flat list
    [t0, tau0, t1, tau1, ...].
    """
    if kind == 'none':
        return NoLoad()
    if kind == 'constant':
        return ConstantLoad(tau)
    if kind == 'pendulum':
        return PendulumLoad(mgl)
    if kind == 'linear':
        return LinearLoad(c1, c2)
    if kind == 'step':
        return StepLoad(t, tau_before, tau_after)
    if kind == 'schedule':
        flat = list(points)
        if flat and not hasattr(flat[0], '__len__'):      # the node parameter's flat form
            if len(flat) % 2:
                raise InvalidParameter('load_points', flat,
                                       'must hold pairs t, tau (an even count)')
            flat = [flat[i:i + 2] for i in range(0, len(flat), 2)]
        return ScheduleLoad(flat)
    raise InvalidParameter('load', kind, choice_error(kind, LOAD_KINDS))


LOAD_FIELDS = {'none': (), 'constant': ('tau',), 'pendulum': ('mgl',), 'linear': ('c1', 'c2'),
               'step': ('t', 'tau_before', 'tau_after'), 'schedule': ('points',)}
#: the fields a load in time must be given (the model kinds have the thesis's defaults)
REQUIRED_FIELDS = {'step': ('t', 'tau_before', 'tau_after'), 'schedule': ('points',)}


def load_from_dict(doc, source: str = 'load') -> Load:
    """
    Return a load from a description ``{kind: linear, c1: 1.0, c2: 0.001}``.

    The form of YAML ``--load`` files.

    Every error is one line naming ``source`` and the field.
    """
    if not isinstance(doc, dict):
        raise InvalidParameter(f'{source}', doc, 'must be a mapping with a kind')
    kind = doc.get('kind')
    if not isinstance(kind, str) or kind not in LOAD_FIELDS:     # [linear] is no kind either
        raise InvalidParameter(f'{source}: kind', kind, choice_error(kind, LOAD_KINDS))
    allowed = LOAD_FIELDS[kind]
    values = {}
    for key, val in doc.items():
        if key == 'kind':
            continue
        if key not in allowed:
            fields = ', '.join(allowed) or 'none'
            raise InvalidParameter(f'{source}: {key}', val,
                                   f'unknown for a {kind} load (fields: {fields})')
        if key == 'points':
            if not isinstance(val, list) or not val:
                raise InvalidParameter(f'{source}: points', val,
                                       'must be a list of [t, tau] points')
            values[key] = val
            continue
        if isinstance(val, bool) or not isinstance(val, (int, float)) or not math.isfinite(val):
            raise InvalidParameter(f'{source}: {key}', val, 'must be a finite number')
        values[key] = float(val)
    for key in REQUIRED_FIELDS.get(kind, ()):
        if key not in values:
            raise InvalidParameter(f'{source}: {key}', None,
                                   f'missing (a {kind} load needs {", ".join(LOAD_FIELDS[kind])})')
    try:
        return make_load(kind, **values)
    except InvalidParameter as exc:     # name the file / run-file key, not the node parameter
        name = exc.name[len('load_'):] if exc.name.startswith('load_') else exc.name
        raise InvalidParameter(f'{source}: {name}', exc.value, exc.reason) from None


def load_from_parameters(values: Mapping) -> Load:
    """Return the load of node parameters ``load``, ``load_<field>`` (:func:`load_parameters`)."""
    fields = {f for kind in LOAD_FIELDS.values() for f in kind}
    return make_load(values.get('load', 'none'),
                     **{k[len('load_'):]: v for k, v in values.items()
                        if k.startswith('load_') and k[len('load_'):] in fields})


def load_file(path: str) -> Load:
    """Read a load description (YAML mapping, see :func:`load_from_dict`) from ``path``."""
    return load_from_dict(read_yaml_file(path, 'load file'), source=path)


def load_parameters(load: Load) -> dict:
    """
    Return the node parameters that rebuild ``load``.

    They are ``load`` and its ``load_<field>`` (``load_mgl``, ``load_c1``, ``load_c2``,
    ``load_tau``, ``load_t``, ``load_tau_before``, ``load_tau_after``, ``load_points`` flat:
    [t0, tau0, t1, tau1, ...]) that rebuild ``load`` with :func:`make_load`; the controller
    takes those of :meth:`Load.feedforward`.
    """
    d = load.describe()
    out = {'load': d['kind']}
    for key in LOAD_FIELDS[d['kind']]:
        if key == 'points':
            out['load_points'] = [float(v) for p in d['points'] for v in p]
        else:
            out['load_' + key] = float(d[key])
    return out
