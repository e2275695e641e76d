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
"""
from __future__ import annotations

import csv
from dataclasses import dataclass
import math
from typing import Optional, Sequence, Tuple

from im_common.params import InvalidParameter, read_yaml_file
from im_common.validation import check_choice

# the field names of /im/setpoint (sensor_msgs/JointState) → controller modes
KINDS = {'position': 'position', 'velocity': 'speed', 'effort': 'torque'}
MODE_KIND = {mode: kind for kind, mode in KINDS.items()}


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


def _number(source: str, where: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise InvalidParameter(f'{source}: {where}', value, 'must be a finite number')
    return float(value)


def _check_times(source: str, times: Sequence[float]) -> None:
    for k in range(1, len(times)):
        if times[k] < times[k - 1]:
            raise InvalidParameter(f'{source}: entry {k} t', times[k],
                                   f'must not be before the previous t = {times[k - 1]:g}')


def from_setpoints(entries, source: str = 'profile') -> Profile:
    """Return a profile from ``[{t: ..., velocity: ...}, ...]`` (see module doc)."""
    if not isinstance(entries, list) or not entries:
        raise InvalidParameter(f'{source}: setpoints', entries, 'must be a non-empty list')
    kind = None
    out = []
    for k, e in enumerate(entries):
        if not isinstance(e, dict):
            raise InvalidParameter(f'{source}: setpoints[{k}]', e,
                                   'must be a mapping {t: ..., velocity: ...}')
        unknown = [key for key in e if key not in ('t', 'duration', *KINDS)]
        if unknown:
            raise InvalidParameter(f'{source}: setpoints[{k}].{unknown[0]}', e[unknown[0]],
                                   f"unknown field (t, duration, {', '.join(KINDS)})")
        kinds = [key for key in KINDS if key in e]
        if len(kinds) != 1:
            raise InvalidParameter(f'{source}: setpoints[{k}]', e,
                                   f"needs exactly one of {', '.join(KINDS)}")
        if kind is None:
            kind = kinds[0]
        elif kinds[0] != kind:
            raise InvalidParameter(f'{source}: setpoints[{k}].{kinds[0]}', e[kinds[0]],
                                   f'a profile has one kind; the first entry set {kind}')
        if 't' not in e:
            raise InvalidParameter(f'{source}: setpoints[{k}].t', None, 'is missing')
        t = _number(source, f'setpoints[{k}].t', e['t'])
        if t < 0.0:
            raise InvalidParameter(f'{source}: setpoints[{k}].t', t, 'must be >= 0')
        d = e.get('duration')
        if d is not None:
            d = _number(source, f'setpoints[{k}].duration', d)
            if d <= 0.0:
                raise InvalidParameter(f'{source}: setpoints[{k}].duration', d, 'must be > 0')
        out.append((t, _number(source, f'setpoints[{k}].{kind}', e[kind]), d))
    _check_times(source, [s[0] for s in out])
    return Profile(KINDS[kind], tuple(out), source)


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
    if not isinstance(doc, dict) or 'setpoints' not in doc:
        raise InvalidParameter(f'{path}: setpoints', None,
                               'is missing (expected setpoints: [{t: 0.0, velocity: 100.0}, ...])')
    extra = [k for k in doc if k != 'setpoints']
    if extra:
        raise InvalidParameter(f'{path}: {extra[0]}', doc[extra[0]],
                               'unknown key (only setpoints)')
    return from_setpoints(doc['setpoints'], source=path)


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
