"""
Message conversions: exact integer-nanosecond stamps and filling of reusable messages.

Stamps are simulated time t_k = k·T_s carried as integer nanoseconds, so a stamp identifies a
step exactly (no float comparison anywhere in the lock-step protocol). Lock-step messages are
published and received serialized (``publish(bytes)``, ``raw=True`` subscriptions) and encoded /
decoded with ``struct`` (:mod:`im_common.cdr`), which keeps the hot path short.
"""
from __future__ import annotations

import struct
from typing import Iterable, Sequence

from .auth import Signer
from .cdr import (decode_joint_state, decode_vector3_stamped, joint_state_packer, NS_PER_S,
                  pack_clock, pack_joint_state, pack_vector3_stamped)
from .params import estimate_arguments
from .topics import ESTIMATE_NAMES

# NS_PER_S (imported above) is defined with the wire format, builtin_interfaces/Time's nanosec;
# every module takes it from here.


def period_ns(T_s: float) -> int:
    """Return the control period in integer nanoseconds; refuses periods that are not whole ns."""
    ns = round(T_s * NS_PER_S)
    if ns <= 0 or abs(ns - T_s * NS_PER_S) > 1e-3:
        raise ValueError(f'T_s = {T_s!r} s must be a positive whole number of nanoseconds')
    return int(ns)


def stamp_ns(stamp) -> int:
    return stamp.sec * NS_PER_S + stamp.nanosec


def set_stamp(stamp, ns: int) -> None:
    stamp.sec, stamp.nanosec = divmod(int(ns), NS_PER_S)


def ns_to_s(ns):
    """
    Return integer nanoseconds ``ns`` as float seconds, ``ns / NS_PER_S``.

    The one conversion of a stamp (or a span of stamps) to seconds. The division is correctly
    rounded, so a period's ns give back the period itself, ``ns_to_s(period_ns(1e-6)) == 1e-6``
    (multiplying by 1e-9 does not always: 1e-9 is not exact in binary). Also element-wise for a
    numpy array of ns.
    """
    return ns / NS_PER_S


def s_to_ns(t: float) -> int:
    """Return float seconds ``t`` as the nearest integer nanoseconds, ``round(t * NS_PER_S)``."""
    return round(t * NS_PER_S)


def s_to_ns_array(t):
    """Return a numpy array of float seconds ``t`` as the nearest int64 ns, element-wise."""
    return (t * NS_PER_S).round().astype('int64')


class Vector3Out:
    """
    Serialized Vector3Stamped for ``Publisher.publish(bytes)``: ``fill(ns, x, y, z=0.0)``.

    The lock-step topics travel as exact CDR made with ``struct`` (:mod:`im_common.cdr`), which
    costs a fraction of building and serializing a message object; subscribers that ask for
    message objects get them as usual.
    """

    __slots__ = ('frame_id',)

    def __init__(self, frame_id: str = 'alphabeta'):
        self.frame_id = frame_id

    def fill(self, ns: int, x: float, y: float, z: float = 0.0) -> bytes:
        sec, nsec = divmod(ns, NS_PER_S)
        return pack_vector3_stamped(sec, nsec, x, y, z, self.frame_id)


class JointStateOut:
    """
    Serialized JointState with fixed names.

    ``fill(ns, position, velocity=(), effort=())`` (one packer per combination of sequence
    lengths, :func:`im_common.cdr.joint_state_packer`).
    """

    __slots__ = ('names', 'frame_id', '_packers')

    def __init__(self, names: Sequence[str], frame_id: str = ''):
        self.names = tuple(names)
        self.frame_id = frame_id
        self._packers = {}

    def fill(self, ns: int, position: Iterable[float] = (), velocity: Iterable[float] = (),
             effort: Iterable[float] = ()) -> bytes:
        sec, nsec = divmod(ns, NS_PER_S)
        position, velocity, effort = tuple(position), tuple(velocity), tuple(effort)
        key = (len(position), len(velocity), len(effort))
        pack = self._packers.get(key)
        if pack is None:
            pack = self._packers[key] = joint_state_packer(self.names, *key, self.frame_id)
        return pack(sec, nsec, position, velocity, effort)


def named_values(names, values, wanted: Sequence[str]) -> dict:
    """``{name: value}`` for ``wanted`` from a named-vector JointState's names and positions."""
    out = {}
    for n in wanted:
        try:
            out[n] = float(values[names.index(n)])
        except (ValueError, IndexError):
            raise KeyError(f"JointState has no value for '{n}' (names: {list(names)})") from None
    return out


def clock_bytes(ns: int) -> bytes:
    """Return the serialized rosgraph_msgs/Clock at ``ns``."""
    sec, nsec = divmod(ns, NS_PER_S)
    return pack_clock(sec, nsec)


# Extractors for LockstepNode.gate_input: serialized message -> (stamp_ns, value).
def xy_in(data: bytes, _head=__import__('struct').Struct('<iII').unpack_from,
          _xyz=__import__('struct').Struct('<ddd').unpack_from):
    """
    Decode a Vector3Stamped carrying an αβ pair.

    (stamp_ns, (x, y)) of a Vector3Stamped: an αβ pair (the layout of
    :func:`im_common.cdr.decode_vector3_stamped`, inlined: every node decodes several per step).
    """
    try:
        sec, nsec, n = _head(data, 4)
        pos = 16 + n
        x, y, _ = _xyz(data, pos + (4 - pos) % 8)
        return sec * NS_PER_S + nsec, (x, y)
    except __import__('struct').error:
        decode_vector3_stamped(data)        # raises its CdrError naming the payload's fault
        raise


def _shaft_layout():
    """
    Return the byte layout of the plant's shaft JointState.

    Byte layout of the plant's shaft JointState (name ['rotor'], one position, one velocity, no
    effort, a tagged frame id of fixed length, :mod:`im_common.auth`): its length, the frame-id
    length field, where the names start, the bytes from there to the values, and the offsets of the
    two doubles — found by packing a sample, so it follows cdr.pack_joint_state.
    """
    a = pack_joint_state(0, 0, ('rotor',), (1.5,), (2.5,), (), Signer.frame(''))
    pos_off = a.index(struct.pack('<d', 1.5))
    vel_off = a.index(struct.pack('<d', 2.5))
    names_at = 16 + struct.unpack_from('<I', a, 12)[0]
    return len(a), a[12:16], names_at, a[names_at:pos_off], pos_off, vel_off


_SHAFT_LEN, _SHAFT_FRAME_LEN, _SHAFT_NAMES, _SHAFT_MIDDLE, _SHAFT_POS, _SHAFT_VEL = \
    _shaft_layout()
_SHAFT_MID_END = _SHAFT_NAMES + len(_SHAFT_MIDDLE)


def shaft_in(data: bytes, _unpack=__import__('struct').Struct('<iI').unpack_from,
             _d=__import__('struct').Struct('<d').unpack_from):
    """
    Decode the measured-shaft JointState.

    (stamp_ns, (theta_r, omega_r)) of the measured-shaft JointState (fixed-layout fast path for the
    plant's own message; anything else goes through the general decoder).
    """
    if len(data) == _SHAFT_LEN and data[12:16] == _SHAFT_FRAME_LEN \
            and data[_SHAFT_NAMES:_SHAFT_MID_END] == _SHAFT_MIDDLE:
        sec, nsec = _unpack(data, 4)
        return sec * NS_PER_S + nsec, (_d(data, _SHAFT_POS)[0], _d(data, _SHAFT_VEL)[0])
    sec, nsec, _, pos, vel, _ = decode_joint_state(data)
    return sec * NS_PER_S + nsec, (pos[0], vel[0])


def estimates_in(data: bytes):
    """
    (stamp_ns, model estimates) of the adapter's estimate JointState.

    {'R_r', 'theta'} from the thesis pair, the inverse-Γ set {'L_sigma', 'L_M', 'R_R'} when the
    message carries L_sigma, with 'R_s' when it carries that too (a sensorless adapter's;
    :func:`im_common.params.estimate_arguments`). The first four names are required.
    """
    sec, nsec, names, pos, _, _ = decode_joint_state(data)
    wanted = ESTIMATE_NAMES[:4] + tuple(n for n in ESTIMATE_NAMES[4:] if n in names)
    return sec * NS_PER_S + nsec, estimate_arguments(named_values(names, pos, wanted))
