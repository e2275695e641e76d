"""
Profiles of one's own: setpoint lists (YAML) and sampled trajectories (CSV) for the controller.

A profile is what ``/im/setpoint`` would carry, known in advance, so the controller applies it
itself (``ControllerConfig.setpoints``) and a run is reproducible without a publisher:

YAML (``--profile FILE.yaml``)::

    setpoints:
      - {t: 0.0, velocity: 100.0}
      - {t: 0.2, velocity: 180.0}
      - {t: 1.5, velocity: 100.0, duration: 0.3}   # optional: transition length [s]

``position`` [rad], ``velocity`` [rad/s] or ``effort`` [N·m] as on ``/im/setpoint`` (one kind per
file); each setpoint is reached by the controller's quintic transition starting at ``t`` (default
length ``setpoint_duration``).

CSV (``--profile FILE.csv``), a sampled trajectory: a header ``t,<kind>`` then rows ``t, value``
with increasing t. The reference passes through every sample at its time: from t_i it moves to
the next value over t_{i+1} − t_i (a quintic, at rest at each sample), so a dense CSV is followed
closely and a sparse one is joined smoothly.

The first value (at t = 0) is the run's start value (speed: the drive starts in steady state
there; position: the shaft starts there).

The YAML form is a pydantic model, :class:`ProfileBlock` (its :class:`Setpoint` entries): a
profile file and a run file's ``profile:`` are parsed through it, every error one line naming
the entry's key (``profile: setpoints[3].t``).
"""
from __future__ import annotations

import csv
from dataclasses import dataclass
import math
from typing import List, Mapping, Optional, Sequence, Tuple

from im_common.params import InvalidParameter, read_yaml_file
from im_common.validation import BLOCK_CONFIG, check_choice, parse_block
from pydantic import BaseModel, Field, field_validator, model_validator


def _kind(mode: str, description: str):
    """Return a setpoint's value field: a field name of /im/setpoint, the controller's ``mode``."""
    return Field(None, description=f'{description} (the {mode} task; one kind per profile)',
                 json_schema_extra={'mode': mode})


class Setpoint(BaseModel):
    """One setpoint of a profile: ``{t, position|velocity|effort, duration}`` (module doc)."""

    model_config = BLOCK_CONFIG

    t: float = Field(ge=0, description='when the transition to this value starts [s]')
    # a value left out is None; one written is a number (null is none)
    position: float = _kind('position', 'shaft position [rad]')
    velocity: float = _kind('speed', 'shaft speed [rad/s]')
    effort: float = _kind('torque', 'torque [N m]')
    duration: Optional[float] = Field(None, gt=0, description="the transition's length [s] "
                                      "(left out: the controller's setpoint_duration)")

    @model_validator(mode='after')
    def _one_kind(self) -> 'Setpoint':
        """Refuse an entry without exactly one value (position, velocity or effort)."""
        if len(self.model_fields_set.intersection(KINDS)) != 1:
            raise InvalidParameter('', {k: v for k, v in self if k in self.model_fields_set},
                                   f"needs exactly one of {', '.join(KINDS)}")
        return self

    @property
    def kind(self) -> str:
        """Return the entry's kind: the field name of /im/setpoint it sets (:data:`KINDS`)."""
        return next(k for k in KINDS if getattr(self, k) is not None)

    @property
    def value(self) -> float:
        return getattr(self, self.kind)


# the field names of /im/setpoint (sensor_msgs/JointState) → controller modes (the Setpoint's)
KINDS = {k: f.json_schema_extra['mode'] for k, f in Setpoint.model_fields.items()
         if f.json_schema_extra}
MODE_KIND = {mode: kind for kind, mode in KINDS.items()}


class ProfileBlock(BaseModel):
    """A profile of setpoints ``{setpoints: [{t, velocity}, ...]}``: a file, ``profile:``."""

    model_config = BLOCK_CONFIG

    setpoints: List[Setpoint] = Field(min_length=1, description='the setpoints, of one kind, '
                                      'their times never decreasing')

    @field_validator('setpoints', mode='before')
    @classmethod
    def _a_list(cls, value):
        if not isinstance(value, list):
            raise ValueError('must be a non-empty list')
        return value

    @model_validator(mode='after')
    def _one_kind_in_time(self) -> 'ProfileBlock':
        """Refuse a second kind and a time before the previous one, naming the entry's key."""
        first = self.setpoints[0]
        for k, (before, e) in enumerate(zip(self.setpoints, self.setpoints[1:]), start=1):
            if e.kind != first.kind:
                raise InvalidParameter(f'setpoints[{k}].{e.kind}', e.value, 'a profile has one '
                                       f'kind; the first entry set {first.kind}')
            if e.t < before.t:
                raise InvalidParameter(f'setpoints[{k}].t', e.t,
                                       f'must not be before the previous t = {before.t:g}')
        return self

    def profile(self, source: str = 'profile') -> 'Profile':
        """Return the :class:`Profile` of these setpoints (``source``: where they were read)."""
        return Profile(KINDS[self.setpoints[0].kind],
                       tuple((e.t, e.value, e.duration) for e in self.setpoints), source)


@dataclass(frozen=True)
class Profile:
    """
    Describe a setpoint profile.

    ``mode`` ('position' | 'speed' | 'torque') and ``setpoints`` ((t, value, duration|None), ...).
    """

    mode: str
    setpoints: Tuple[Tuple[float, float, Optional[float]], ...]
    source: str = 'profile'

    @property
    def start_value(self) -> Optional[float]:
        """Return the value at t = 0 if the profile sets one there (else None)."""
        if self.setpoints and self.setpoints[0][0] == 0.0:
            return self.setpoints[0][1]
        return None

    @property
    def end_time(self) -> float:
        t, _, d = self.setpoints[-1]
        return t + (d or 0.0)

    def as_parameters(self) -> dict:
        """
        Return the controller node's parameters for this profile.

        Flat (t, value, duration)
        triples; duration 0 = the node's ``setpoint_duration``).
        """
        flat = []
        for t, value, d in self.setpoints:
            flat += [float(t), float(value), float(d or 0.0)]
        return {'mode': self.mode, 'profile': 'setpoint', 'setpoints': flat}


def _parse(model_cls, spec, source: str, where: str = ''):
    """Return ``model_cls`` of ``spec``; an error is one line naming ``source: where.key``."""
    try:
        return parse_block(model_cls, spec, where)
    except InvalidParameter as exc:
        raise InvalidParameter(f'{source}: {exc.name}' if exc.name else source, exc.value,
                               exc.reason) from None


def profile_from_block(doc, source: str = 'profile') -> Profile:
    """
    Return the profile of a block ``{setpoints: [...]}`` (a mapping or a :class:`ProfileBlock`).

    Each entry is parsed on its own first, so that an error names it: ``source:
    setpoints[3].t``.
    """
    if isinstance(doc, ProfileBlock):
        return doc.profile(source)
    if isinstance(doc, Mapping) and isinstance(doc.get('setpoints'), list):
        doc = dict(doc, setpoints=[_parse(Setpoint, e, source, f'setpoints[{k}]')
                                   for k, e in enumerate(doc['setpoints'])])
    return _parse(ProfileBlock, doc, source).profile(source)


def from_setpoints(entries, source: str = 'profile') -> Profile:
    """Return a profile from ``[{t: ..., velocity: ...}, ...]`` (see module doc)."""
    return profile_from_block({'setpoints': entries}, source)


def from_samples(kind: str, samples: Sequence[Tuple[float, float]],
                 source: str = 'profile') -> Profile:
    """
    Return a sampled trajectory.

    The reference reaches each value at its time (see module doc).
    """
    check_choice(f'{source}: kind', kind, KINDS)
    if len(samples) < 1:
        raise InvalidParameter(f'{source}', len(samples), 'needs at least one sample')
    times = [s[0] for s in samples]
    if times[0] < 0.0:
        raise InvalidParameter(f'{source}: row 1 t', times[0], 'must be >= 0')
    for k in range(1, len(times)):
        if not times[k] > times[k - 1]:
            raise InvalidParameter(f'{source}: row {k + 1} t', times[k],
                                   f'must be after the previous t = {times[k - 1]:g}')
    out = [(times[0], samples[0][1], None)]
    for k in range(len(samples) - 1):
        out.append((times[k], samples[k + 1][1], times[k + 1] - times[k]))
    return Profile(KINDS[kind], tuple(out), source)


def load_profile(path: str) -> Profile:
    """Read a profile file: ``.yaml``/``.yml`` setpoints or ``.csv`` samples (module doc)."""
    if path.endswith('.csv'):
        return _load_csv(path)
    doc = read_yaml_file(path, 'profile file')
    if not isinstance(doc, Mapping):
        raise InvalidParameter(f'{path}: setpoints', None,
                               'is missing (expected setpoints: [{t: 0.0, velocity: 100.0}, ...])')
    return profile_from_block(doc, source=path)


def _load_csv(path: str) -> Profile:
    try:
        with open(path, newline='', encoding='utf-8') as f:
            rows = [r for r in csv.reader(f) if r and not r[0].lstrip().startswith('#')]
    except OSError as exc:
        raise InvalidParameter('profile file', path, f'cannot be read ({exc.strerror})') from None
    except UnicodeDecodeError as exc:
        raise InvalidParameter(f'{path}', exc.object[exc.start:exc.start + 1],
                               f'is not UTF-8 text (byte {exc.start})') from None
    except csv.Error as exc:
        raise InvalidParameter(f'{path}', 'CSV', f'is not CSV ({exc})') from None
    if not rows:
        raise InvalidParameter(f'{path}', 'empty',
                               f"needs a header t,<{'|'.join(KINDS)}> and rows")
    header = [h.strip() for h in rows[0]]
    if len(header) != 2 or header[0] != 't' or header[1] not in KINDS:
        raise InvalidParameter(f'{path}: header', ','.join(header),
                               f"must be t,<kind> with kind one of {', '.join(KINDS)}")
    samples = []
    for k, r in enumerate(rows[1:], start=2):
        if len(r) != 2:
            raise InvalidParameter(f'{path}: line {k}', ','.join(r),
                                   'must be two numbers t, value')
        try:
            t, value = float(r[0]), float(r[1])
        except ValueError:
            raise InvalidParameter(f'{path}: line {k}', ','.join(r),
                                   'must be two numbers t, value') from None
        if not (math.isfinite(t) and math.isfinite(value)):
            raise InvalidParameter(f'{path}: line {k}', ','.join(r), 'must be finite')
        samples.append((t, value))
    return from_samples(header[1], samples, source=path)


def from_parameters(flat: Sequence[float]) -> tuple:
    """
    Read ``ControllerConfig.setpoints`` from the node parameter ``setpoints``.

    ``ControllerConfig.setpoints`` from the node parameter ``setpoints`` (flat triples t, value,
    duration; duration 0 = default; [0.0] = no profile).
    """
    flat = list(flat)
    if flat == [0.0] or not flat:
        return ()
    if len(flat) % 3:
        raise ValueError(f"invalid parameter 'setpoints' = {flat!r}: (t, value, duration) triples")
    return tuple((flat[i], flat[i + 1], flat[i + 2] or None) for i in range(0, len(flat), 3))
