"""
Shaft loads: torque opposing the motor, τ_L(t, θ, ω) [N·m] (seed 000 §3.4.5).

The one home of a load: the plant, the ROS-free loop, the studies and the run record take the
same object. Two kinds are functions of the shaft state (``pendulum``, ``linear``; with
``none`` and ``constant`` the :data:`MODEL_KINDS` a controller can feed forward), two are loads
in time a user writes to disturb the drive (``step``, ``schedule``). :class:`LiveLoad` is the
plant's own wrapper: the load plus the live ``load_offset`` (docs/running.md, "Loads").

Each kind's block — ``{kind: linear, c1, c2}`` in a load file or a run file's ``load:`` — is a
pydantic model (:data:`LoadBlock`, one model per kind): its fields' defaults, bounds and
descriptions are declared there once, and a load of any origin (a file, a node parameter, a
:class:`Load` built in code) is checked through it.
"""
from __future__ import annotations

import bisect
from dataclasses import dataclass, fields
import math
from typing import Annotated, get_args, Literal, Mapping, Tuple, Union

from pydantic import BaseModel, Field, field_validator

from .params import InvalidParameter, read_yaml_file
from .validation import BLOCK_CONFIG, choice_error, parse_block


class BaseLoadBlock(BaseModel):
    """A load's block ``{kind: ..., <its fields>}``: a load file, a run file's ``load:``."""

    model_config = BLOCK_CONFIG

    def load(self) -> 'Load':
        """Return the :class:`Load` this block describes."""
        return _LOADS[self.kind](**self.model_dump(exclude={'kind'}))


class NoLoadBlock(BaseLoadBlock):
    """No load: τ_L = 0."""

    kind: Literal['none'] = Field(description='no load')


class ConstantLoadBlock(BaseLoadBlock):
    """A constant torque: τ_L = tau."""

    kind: Literal['constant'] = Field(description='a constant torque')
    tau: float = Field(0.0, description='the load torque [N m]')


class PendulumLoadBlock(BaseLoadBlock):
    """The inverted pendulum of the position task: τ_L = mgl·cos θ."""

    kind: Literal['pendulum'] = Field(description='an inverted pendulum')
    mgl: float = Field(10.0, description='m g l [N m] (tau = mgl cos theta; the thesis: 10)')


class LinearLoadBlock(BaseLoadBlock):
    """The speed task's friction: τ_L = c1 + c2·ω."""

    kind: Literal['linear'] = Field(description='friction linear in the speed')
    c1: float = Field(1.0, description='c1 [N m] (tau = c1 + c2 omega; the thesis: 1)')
    c2: float = Field(0.001, description='c2 [N m s] (the thesis: 0.001)')


class StepLoadBlock(BaseLoadBlock):
    """A load step in time: tau_before until t, tau_after from t on."""

    kind: Literal['step'] = Field(description='a load step in time')
    t: float = Field(ge=0, description='the instant of the step [s] (the run starts at 0)')
    tau_before: float = Field(description='the load torque before t [N m]')
    tau_after: float = Field(description='the load torque from t on [N m]')


class ScheduleLoadBlock(BaseLoadBlock):
    """Load torque in time through points [t, tau], piecewise linear (:class:`ScheduleLoad`)."""

    kind: Literal['schedule'] = Field(description='a load torque schedule in time')
    points: Tuple[Tuple[float, float], ...] = Field(
        min_length=1, description='points [t [s], tau [N m]]: times from 0 on that never '
        'decrease; a time given twice is a jump there (not three times)')

    @field_validator('points', mode='before')
    @classmethod
    def _points(cls, pts):
        """Return the points as (t, tau) floats; refuse one in one line naming ``points[i]``."""
        if isinstance(pts, (str, bytes, Mapping)) or not hasattr(pts, '__len__'):
            raise InvalidParameter('points', pts, 'must be a list of [t, tau] points')
        out = []
        for i, p in enumerate(pts):
            if isinstance(p, (str, bytes, Mapping)) or not hasattr(p, '__len__') or len(p) != 2:
                raise InvalidParameter(f'points[{i}]', p, 'must be a point [t, tau]')
            t, tau = (_real(f'points[{i}].{k}', v) for k, v in zip(('t', 'tau'), p))
            if t < 0:
                raise InvalidParameter(f'points[{i}].t', t, 'must be >= 0 s')
            if out and t < out[-1][0]:
                raise InvalidParameter(f'points[{i}].t', t,
                                       f'times must not decrease (the point before is at '
                                       f'{out[-1][0]!r} s)')
            if len(out) >= 2 and t == out[-1][0] == out[-2][0]:
                raise InvalidParameter(f'points[{i}].t', t,
                                       'a time may be given twice (a jump), not three times')
            out.append((t, tau))
        return tuple(out)


def _real(name: str, value) -> float:
    """Return ``value`` (a point's number) as a float; else the line a model field gives."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise InvalidParameter(name, value, 'must be a real number')
    try:
        x = float(value)
    except OverflowError:           # an int beyond a float's range
        x = math.inf
    if not math.isfinite(x):
        raise InvalidParameter(name, value, 'must be finite')
    return x


def _kind(model) -> str:
    """Return the kind a load block's model describes (its ``kind`` literal)."""
    return get_args(model.model_fields['kind'].annotation)[0]


#: a load's block, one model per kind (the run file's ``load:`` mapping; discriminated on kind)
LoadBlock = Annotated[Union[NoLoadBlock, ConstantLoadBlock, PendulumLoadBlock, LinearLoadBlock,
                            StepLoadBlock, ScheduleLoadBlock], Field(discriminator='kind')]
#: each kind's block model (the union's members)
LOAD_MODELS = {_kind(m): m for m in get_args(get_args(LoadBlock)[0])}
#: the kinds a controller's load model takes (functions of the shaft state; eq. 3.1's τ_c)
MODEL_KINDS = tuple(_kind(m) for m in (NoLoadBlock, ConstantLoadBlock, PendulumLoadBlock,
                                       LinearLoadBlock))
#: every kind a plant applies: the model kinds and the loads in time
LOAD_KINDS = tuple(LOAD_MODELS)
#: each kind's fields (its ``load_<field>`` node parameters)
LOAD_FIELDS = {kind: tuple(k for k in m.model_fields if k != 'kind')
               for kind, m in LOAD_MODELS.items()}
#: the defaults of the fields that have one (the model kinds' thesis values): what the nodes'
#: ``load_<field>`` parameters default to
LOAD_DEFAULTS = {k: info.default for m in LOAD_MODELS.values()
                 for k, info in m.model_fields.items() if k != 'kind' and not info.is_required()}


def _default(model, key: str):
    """Return a load block's default of ``key`` (a :class:`Load`'s default is its block's)."""
    return model.model_fields[key].default


def parse_load_block(kind: str, values: Mapping, prefix: str = '') -> BaseLoadBlock:
    """
    Return the block of a load ``kind`` with the field ``values`` (a mapping without ``kind``).

    One :class:`InvalidParameter` line otherwise, naming ``prefix`` + the key (``load: t``, the
    file's ``path: points[2].t``, the node parameter ``load_tau``) or ``prefix + 'kind'``.
    """
    if not isinstance(kind, str) or kind not in LOAD_MODELS:     # [linear] is no kind either
        raise InvalidParameter(f'{prefix}kind', kind, choice_error(kind, LOAD_KINDS))
    try:
        return parse_block(LOAD_MODELS[kind], dict(values, kind=kind), '')
    except InvalidParameter as exc:
        raise InvalidParameter(prefix + exc.name, exc.value, exc.reason) from None


class Load:
    """Base class: ``torque(t, theta, omega)`` returns the load torque τ_L [N·m]."""

    name = _kind(NoLoadBlock)
    # a kind's ``block`` (its model) is the home of its fields' defaults and bounds

    def __post_init__(self):
        """Check the fields through the kind's block model (errors name ``load_<field>``)."""
        values = {f.name: getattr(self, f.name) for f in fields(self)}
        block = parse_load_block(self.name, values, 'load_')
        for key in values:          # as the block holds them: floats, (t, tau) tuples
            setattr(self, key, getattr(block, key))

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
    block = NoLoadBlock
    name = _kind(block)

    def torque(self, t, theta, omega):
        return 0.0


@dataclass
class ConstantLoad(Load):
    block = ConstantLoadBlock
    name = _kind(block)
    tau: float = _default(block, 'tau')

    def torque(self, t, theta, omega):
        return self.tau

    def describe(self):
        return {'kind': self.name, 'tau': self.tau}


@dataclass
class PendulumLoad(Load):
    """Inverted pendulum τ_L = mgl·cos θ (position task, mgl = 10 N·m)."""

    block = PendulumLoadBlock
    name = _kind(block)
    mgl: float = _default(block, 'mgl')

    def torque(self, t, theta, omega):
        return self.mgl * math.cos(theta)

    def rate(self, t, theta, omega, accel):
        return -self.mgl * math.sin(theta) * omega

    def describe(self):
        return {'kind': self.name, 'mgl': self.mgl}


@dataclass
class LinearLoad(Load):
    """τ_L = c1 + c2·ω (speed task: c1 = 1 N·m, c2 = 0.001 N·m·s)."""

    block = LinearLoadBlock
    name = _kind(block)
    c1: float = _default(block, 'c1')
    c2: float = _default(block, 'c2')

    def torque(self, t, theta, omega):
        return self.c1 + self.c2 * omega

    def rate(self, t, theta, omega, accel):
        return self.c2 * accel

    def describe(self):
        return {'kind': self.name, 'c1': self.c1, 'c2': self.c2}


@dataclass
class StepLoad(Load):
    """
    A load step in time: τ_L = tau_before for t < t, tau_after from t on [N·m].

    Written ``{kind: step, t: 0.5, tau_before: 2.0, tau_after: 8.0}``.
    """

    block = StepLoadBlock
    name = _kind(block)
    t: float
    tau_before: float
    tau_after: float

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

    block = ScheduleLoadBlock
    name = _kind(block)
    points: Tuple[Tuple[float, float], ...]

    def __post_init__(self):
        super().__post_init__()
        self._times = [p[0] for p in self.points]

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


#: each kind's :class:`Load`
_LOADS = {cls.name: cls for cls in (NoLoad, ConstantLoad, PendulumLoad, LinearLoad, StepLoad,
                                    ScheduleLoad)}


def make_load(kind: str, **values) -> Load:
    """
    Build a load by name (the nodes' ``load`` parameter and its ``load_*`` values, unprefixed).

    The kind's own fields are taken from ``values`` (another kind's are left), a field not
    given is its block's default (a load in time has none: it must be given). ``points`` takes
    the pairs [[t, tau], ...] or the node parameter's flat list [t0, tau0, t1, tau1, ...].
    Errors name the node parameter (``load``, ``load_<field>``).
    """
    unknown = set(values).difference(*LOAD_FIELDS.values())
    if unknown:
        raise TypeError(f'make_load: no load has the field(s) {", ".join(sorted(unknown))}')
    if not isinstance(kind, str) or kind not in LOAD_MODELS:
        raise InvalidParameter('load', kind, choice_error(kind, LOAD_KINDS))
    given = {k: values[k] for k in LOAD_FIELDS[kind] if k in values}
    flat = given.get('points')
    if hasattr(flat, '__len__') and not isinstance(flat, (str, bytes, Mapping)) and len(flat) \
            and not hasattr(flat[0], '__len__'):      # the node parameter's flat form
        flat = list(flat)
        if len(flat) % 2:
            raise InvalidParameter('load_points', flat, 'must hold pairs t, tau (an even count)')
        given['points'] = [flat[i:i + 2] for i in range(0, len(flat), 2)]
    return parse_load_block(kind, given, 'load_').load()


def load_from_dict(doc, source: str = 'load') -> Load:
    """
    Return a load from its block ``{kind: linear, c1: 1.0, c2: 0.001}`` (or a block model).

    The form of YAML ``--load`` files and a run file's ``load:`` (:data:`LoadBlock`). Every
    error is one line naming ``source`` and the field (``load: tau_after``).
    """
    if isinstance(doc, BaseLoadBlock):
        return doc.load()
    if not isinstance(doc, Mapping):
        raise InvalidParameter(f'{source}', doc, 'must be a mapping with a kind')
    return parse_load_block(doc.get('kind'), doc, f'{source}: ').load()


def load_from_parameters(values: Mapping) -> Load:
    """Return the load of node parameters ``load``, ``load_<field>`` (:func:`load_parameters`)."""
    known = {f for kind in LOAD_FIELDS.values() for f in kind}
    return make_load(values.get('load', 'none'),
                     **{k[len('load_'):]: v for k, v in values.items()
                        if k.startswith('load_') and k[len('load_'):] in known})


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
