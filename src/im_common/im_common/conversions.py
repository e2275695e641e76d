"""Message conversions: exact integer-nanosecond stamps and filling of reusable messages.

Stamps are simulated time t_k = k·T_s carried as integer nanoseconds, so a stamp identifies a
step exactly (no float comparison anywhere in the lock-step protocol). Messages are allocated once
per publisher and refilled each step (rclpy serializes on ``publish``), which keeps the hot path short.
"""
from __future__ import annotations

import math
from typing import Iterable, Sequence

from builtin_interfaces.msg import Time
from geometry_msgs.msg import Vector3Stamped
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState

NS_PER_S = 1_000_000_000


def period_ns(T_s: float) -> int:
    """The control period in integer nanoseconds; refuses periods that are not whole ns."""
    ns = round(T_s * NS_PER_S)
    if ns <= 0 or abs(ns - T_s * NS_PER_S) > 1e-3:
        raise ValueError(f"T_s = {T_s!r} s must be a positive whole number of nanoseconds")
    return int(ns)


def stamp_ns(stamp) -> int:
    return stamp.sec * NS_PER_S + stamp.nanosec


def set_stamp(stamp, ns: int) -> None:
    stamp.sec, stamp.nanosec = divmod(int(ns), NS_PER_S)


def ns_to_s(ns: int) -> float:
    return ns / NS_PER_S


def time_msg(ns: int) -> Time:
    t = Time()
    set_stamp(t, ns)
    return t


def finite(*values: float) -> bool:
    for v in values:
        if not math.isfinite(v):
            return False
    return True


class Vector3Out:
    """A reusable Vector3Stamped: ``fill(ns, x, y, z=0.0)`` returns the message."""

    __slots__ = ('msg',)

    def __init__(self, frame_id: str = 'alphabeta'):
        self.msg = Vector3Stamped()
        self.msg.header.frame_id = frame_id

    def fill(self, ns: int, x: float, y: float, z: float = 0.0) -> Vector3Stamped:
        m = self.msg
        st = m.header.stamp
        st.sec, st.nanosec = divmod(ns, NS_PER_S)
        v = m.vector
        v.x = x
        v.y = y
        v.z = z
        return m


class JointStateOut:
    """A reusable JointState with fixed names: ``fill(ns, position, velocity=(), effort=())``."""

    __slots__ = ('msg',)

    def __init__(self, names: Sequence[str], frame_id: str = ''):
        self.msg = JointState()
        self.msg.name = list(names)
        self.msg.header.frame_id = frame_id

    def fill(self, ns: int, position: Iterable[float] = (), velocity: Iterable[float] = (),
             effort: Iterable[float] = ()) -> JointState:
        m = self.msg
        st = m.header.stamp
        st.sec, st.nanosec = divmod(ns, NS_PER_S)
        m.position = list(position)
        m.velocity = list(velocity)
        m.effort = list(effort)
        return m


def clock_msg(ns: int) -> Clock:
    c = Clock()
    set_stamp(c.clock, ns)
    return c


def joint_values(msg: JointState, names: Sequence[str]) -> dict:
    """Values of a named-vector JointState as a dict (position field), checked for names."""
    got = list(msg.name)
    out = {}
    for n in names:
        try:
            out[n] = float(msg.position[got.index(n)])
        except ValueError:
            raise KeyError(f"JointState has no entry '{n}' (names: {got})") from None
    return out
