"""
A node's run-protocol channel: its events out on ``/im/status``, the graph's in, probe echoes.

The rclpy side of :class:`im_common.lockstep_protocol.LockstepProtocol` for one
:class:`im_common.lockstep.LockstepNode`: events are tagged with the graph's key
(:meth:`im_common.signing.NodeSigning.status_tag`) and published through the node's own (tapped)
publisher; an event received that does not verify is named once per sender and never acted on;
one that concerns the node (:meth:`LockstepProtocol.accept`) goes to ``node.on_peer_status``. A
node that is not the time master echoes the time master's free_run probes of the run it follows.
"""
from __future__ import annotations

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
import rclpy
from std_msgs.msg import Header

from .conversions import NS_PER_S
from .lockstep_parts import foreign_status_text
from .qos import reader, writer
from .topics import PROBE, PROBE_ECHO, STATUS


def status_message(name: str, state: str, level: int, ns: int, values: dict):
    """Return a run-protocol event (``DiagnosticArray``, one status) stamped ``ns``, untagged."""
    msg = DiagnosticArray()
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(int(ns), NS_PER_S)
    msg.status = [DiagnosticStatus(level=bytes([level]), name=name, message=state,
                                   hardware_id='im_drive',
                                   values=[KeyValue(key=str(k), value=str(v))
                                           for k, v in values.items()])]
    return msg


class StatusChannel:
    """The ``/im/status`` publisher and reader of ``node`` (and its probe echo)."""

    __slots__ = ('node', 'pub', 'echo_pub')

    def __init__(self, node):
        self.node = node
        self.pub = node.create_publisher(DiagnosticArray, STATUS, writer(STATUS))
        node.create_subscription(DiagnosticArray, STATUS, self.receive, reader(STATUS))
        self.echo_pub = None
        if not node.time_master:
            self.echo_pub = node.create_publisher(Header, PROBE_ECHO, writer(PROBE_ECHO))
            node.create_subscription(Header, PROBE, self.echo, reader(PROBE))

    def publish(self, state: str, level: int, stamp_ns, values: dict) -> None:
        """
        Publish the node's event ``state``, tagged, stamped ``stamp_ns`` (None: its step).

        Its key/values: the node's role, period, step and run, its ``event_context``, ``values``.
        """
        node = self.node
        ns = node.current_ns() if stamp_ns is None else stamp_ns
        msg = status_message(node.get_name(), state, level, ns, node.protocol.event_values(
            node.critical, node.time_master, node.period, ns, dict(node.event_context, **values)))
        msg.header.frame_id = node.signing.status_tag(msg)
        try:
            self.pub.publish(msg)
        except Exception as exc:  # noqa: BLE001 - a closed context during shutdown: log, go on
            if rclpy.ok(context=node.context):
                raise
            node.get_logger().debug(f'status {state} not published: {exc}')

    def receive(self, msg) -> None:
        """Hand each event of this graph that concerns the node to ``node.on_peer_status``."""
        node = self.node
        if not node.signing.status_verifies(msg):
            for st in msg.status:       # another graph with its own key, or a rogue: say once
                if node.watch.first_status_from(st.name):
                    node.get_logger().warning(foreign_status_text(
                        STATUS, st.message, st.name, node.foreign_publishers(STATUS)))
            return
        own = node.get_name()
        for st in msg.status:
            values = {kv.key: kv.value for kv in st.values}
            if node.protocol.accept(own, st.name, st.message, values):
                node.on_peer_status(st.name, st.message, values)

    def echo(self, msg) -> None:
        """
        Send the time master's pre-flight probe straight back, named (free_run, before step 0).

        Only a probe of the run the node follows: the time master times the round trip through
        the node's executor (``im_common.timing.assess_probe``).
        """
        run = self.node.run_id
        if run and msg.frame_id == run:
            msg.frame_id = f'{run} {self.node.get_name()}'
            self.echo_pub.publish(msg)
