"""``ros2 run im_bringup record [--out bags/<run>.mcap] [--force] [--topics T ...]``

Records a running graph to MCAP: one raw (serialized) subscription per topic of
:data:`im_common.topics.TOPICS` (or the given topics; a topic outside the table needs
``topic:=pkg/msg/Type``), written as received through :class:`~im_bringup.bag.BagWriter`. Each
message's log time is its header stamp (simulated time), so the recording lines up with the run and
not with the recorder's scheduling; a payload's trailing bytes beyond its CDR length are trimmed.

QoS: reliable, volatile, keep-last 1000 — compatible with the stack's reliable publishers
(transient-local or volatile); if a topic already has a best-effort publisher when the recorder
starts, that topic is subscribed best-effort. SIGINT / SIGTERM stop spinning and close the file
(summary, footer), so an interrupted recording is complete up to the stop; after a hard kill use
``recover``. The in-process graph records without this node (``DriveGraph(recorder=BagWriter)``).
"""
from __future__ import annotations

import argparse
import sys
import time
from typing import Dict, Iterable, Optional

from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from im_common import cdr
from .bag import BagError, BagWriter, qos_yaml

STAMPED_TYPES = {'geometry_msgs/msg/Vector3Stamped', 'sensor_msgs/msg/JointState',
                 'rosgraph_msgs/msg/Clock'}


def default_topics() -> Dict[str, str]:
    from im_common.topics import TOPICS
    return {t.name: t.type for t in TOPICS}


def parse_topics(items: Optional[Iterable[str]]) -> Dict[str, str]:
    """['/a', '/b:=pkg/msg/T'] -> {topic: type} (types of table topics filled in)."""
    table = default_topics()
    if not items:
        return table
    out = {}
    for it in items:
        if ':=' in it:
            topic, tname = it.split(':=', 1)
        else:
            topic, tname = it, table.get(it)
            if tname is None:
                raise ValueError(f'topic {it!r} is not in im_common.topics; give its type as '
                                 f'{it}:=pkg/msg/Type')
        if not topic.startswith('/'):
            topic = '/' + topic
        out[topic] = tname
    return out


class RecorderNode(Node):
    """Subscribes raw to ``topics`` and writes every message to ``writer``."""

    def __init__(self, writer: BagWriter, topics: Optional[Dict[str, str]] = None,
                 node_name: str = 'recorder', depth: int = 1000, **kwargs):
        super().__init__(node_name, **kwargs)
        self.writer = writer
        self.counts: Dict[str, int] = {}
        self.trimmed = 0
        self._subs = []
        for topic, tname in (topics or default_topics()).items():
            cls = cdr.message_class(tname)
            reliability = ReliabilityPolicy.RELIABLE
            try:
                infos = self.get_publishers_info_by_topic(topic)
                if any(i.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT for i in infos):
                    reliability = ReliabilityPolicy.BEST_EFFORT
            except Exception:   # pragma: no cover - graph query is best-effort
                pass
            qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth,
                             reliability=reliability, durability=DurabilityPolicy.VOLATILE)
            writer.add_topic(topic, tname, qos=qos_yaml(
                reliability='best_effort' if reliability == ReliabilityPolicy.BEST_EFFORT
                else 'reliable'))
            self.counts[topic] = 0
            self._subs.append(self.create_subscription(
                cls, topic, self._callback(topic, tname), qos, raw=True))

    def _callback(self, topic: str, tname: str):
        stamped = tname in STAMPED_TYPES
        write = self.writer.write_serialized
        counts = self.counts

        def cb(data: bytes) -> None:
            try:
                n = cdr.payload_length(tname, data)
            except Exception:
                n = len(data)
            if n < len(data):
                data = data[:n]
                self.trimmed += 1
            if stamped:
                t = cdr.header_stamp_ns(data)
            else:
                t = self.get_clock().now().nanoseconds
            try:
                write(topic, data, t)
            except BagError:
                return          # closed by a signal while a callback was pending
            counts[topic] += 1
        return cb


def main(argv=None) -> int:
    import rclpy
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
    from rclpy.utilities import remove_ros_args
    full = list(sys.argv if argv is None else ['record'] + list(argv))
    ap = argparse.ArgumentParser(prog='record', description='Record the drive graph to MCAP.')
    ap.add_argument('--out', '-o', default=None,
                    help='output file (default bags/run_<YYYYmmdd_HHMMSS>.mcap)')
    ap.add_argument('--force', action='store_true', help='overwrite an existing file')
    ap.add_argument('--topics', nargs='+', default=None,
                    help='topics to record (default: every topic of im_common.topics); '
                         'others as /topic:=pkg/msg/Type')
    ap.add_argument('--duration', type=float, default=None,
                    help='stop after this many wall-clock seconds')
    a = ap.parse_args(remove_ros_args(args=full)[1:])
    out = a.out or time.strftime('bags/run_%Y%m%d_%H%M%S.mcap')
    try:
        topics = parse_topics(a.topics)
        writer = BagWriter(out, force=a.force, metadata={
            'recorder': {'node': 'im_bringup record', 'topics': ' '.join(topics),
                         'started_wall': time.strftime('%Y-%m-%dT%H:%M:%S%z')}})
    except (FileExistsError, ValueError, OSError) as exc:
        print(f'record: error: {exc}', file=sys.stderr)
        return 2
    rclpy.init(args=full)
    node = None
    try:
        node = RecorderNode(writer, topics)
        node.get_logger().info(f'recording {len(topics)} topics to {out}')
        ex = SingleThreadedExecutor()
        ex.add_node(node)
        t_end = None if a.duration is None else time.monotonic() + a.duration
        while rclpy.ok() and (t_end is None or time.monotonic() < t_end):
            ex.spin_once(timeout_sec=0.1)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        writer.close()
        n = sum(node.counts.values()) if node is not None else 0
        print(f'record: {n} messages written to {out}', file=sys.stderr)
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
