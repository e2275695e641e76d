"""
The rclpy QoS profiles of the stack, built from the topic table (:class:`im_common.topics.Qos`).

One home: a topic's reliability, durability and histories are its :class:`~im_common.topics.Qos`
in :data:`im_common.topics.TOPICS`; publishers (:func:`writer`), the nodes' readers (gates, the
run protocol: :func:`reader`) and the recorder (:func:`recorder`) all take their profile from it.
"""
from __future__ import annotations

from typing import Optional

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from .topics import DATA_QOS, LOCKSTEP_QOS, PROBE_QOS, Qos, qos_of, REPORT_QOS, STATUS_QOS


def build(q: Qos, depth: int, reliable: Optional[bool] = None,
          latched: Optional[bool] = None) -> QoSProfile:
    """Return the keep-last rclpy profile of ``q``, ``depth`` deep (or as reliable/latched)."""
    rel = q.reliable if reliable is None else reliable
    lat = q.latched if latched is None else latched
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth,
                      reliability=(ReliabilityPolicy.RELIABLE if rel
                                   else ReliabilityPolicy.BEST_EFFORT),
                      durability=(DurabilityPolicy.TRANSIENT_LOCAL if lat
                                  else DurabilityPolicy.VOLATILE))


def writer(topic: str) -> QoSProfile:
    """Return the profile a publisher of ``topic`` offers."""
    q = qos_of(topic)
    return build(q, q.history)


def reader(topic: str, latched: Optional[bool] = None) -> QoSProfile:
    """
    Return the profile a node's reader of ``topic`` asks for (a gate, the run protocol).

    ``latched`` True asks for transient-local where the topic is volatile: such a reader matches
    only the publishers that offer it (the controller's second setpoint reader).
    """
    q = qos_of(topic)
    return build(q, q.reader_history, latched=latched)


def recorder(topic: str, reliable: bool = True, latched: Optional[bool] = None) -> QoSProfile:
    """
    Return the profile the recorder reads ``topic`` with.

    Its delivery, with the recorder's history; ``reliable``/``latched`` False when the graph's
    publishers offer less (a best-effort or volatile publisher would not match otherwise).
    """
    q = qos_of(topic)
    return build(q, q.record_history, reliable=q.reliable and reliable, latched=latched)


# The profiles by kind, for topics outside the table (benchmarks, tests) ----------------------
def lockstep_qos(depth: int = LOCKSTEP_QOS.history) -> QoSProfile:
    """Reliable, transient-local, keep-last: a late-joining node still gets the step it needs."""
    return build(LOCKSTEP_QOS, depth)


def data_qos(depth: int = 100) -> QoSProfile:
    """Reliable, volatile: what a subscriber takes when any publisher must match (setpoints)."""
    return build(DATA_QOS, depth)


def report_qos(depth: int = REPORT_QOS.history) -> QoSProfile:
    """Return the QoS of the report topics: reliable, transient-local, keep-last."""
    return build(REPORT_QOS, depth)


def probe_qos() -> QoSProfile:
    """Return the QoS of free_run's pre-flight probe and its echoes: reliable, volatile."""
    return build(PROBE_QOS, PROBE_QOS.history)


def status_qos(depth: int = STATUS_QOS.history) -> QoSProfile:
    """Return the QoS of the run-protocol events: reliable and transient-local."""
    return build(STATUS_QOS, depth)
