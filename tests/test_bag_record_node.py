"""The recorder node, in-process on its own context: what is published is what is recorded."""
import random
import time

import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from geometry_msgs.msg import Vector3Stamped
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState

from im_bringup.bag import read_messages
from im_bringup.bag import BagWriter
from im_bringup.record_node import RecorderNode, parse_topics


def test_parse_topics():
    t = parse_topics(['/im/measured/current', '/x:=std_msgs/msg/String'])
    assert t == {'/im/measured/current': 'geometry_msgs/msg/Vector3Stamped',
                 '/x': 'std_msgs/msg/String'}
    assert len(parse_topics(None)) >= 17


def test_recorder_node_records_what_was_published(tmp_path):
    ctx = Context()
    rclpy.init(context=ctx, domain_id=random.randint(150, 229))
    path = tmp_path / 'rec.mcap'
    writer = BagWriter(path)
    pub_node = rec = None
    try:
        topics = parse_topics(['/im/measured/current', '/im/measured/shaft', '/clock'])
        rec = RecorderNode(writer, topics, context=ctx)
        pub_node = Node('talker', context=ctx)
        q = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.TRANSIENT_LOCAL)
        p_cur = pub_node.create_publisher(Vector3Stamped, '/im/measured/current', q)
        p_sh = pub_node.create_publisher(JointState, '/im/measured/shaft', q)
        p_clk = pub_node.create_publisher(Clock, '/clock', 10)
        ex = SingleThreadedExecutor(context=ctx)
        ex.add_node(rec)
        ex.add_node(pub_node)
        deadline = time.monotonic() + 10
        while (p_cur.get_subscription_count() == 0 or p_sh.get_subscription_count() == 0
               or p_clk.get_subscription_count() == 0) and time.monotonic() < deadline:
            ex.spin_once(timeout_sec=0.05)
        sent = []
        for k in range(50):
            t = 2 * 10**9 + k * 100_000
            m = Vector3Stamped()
            m.header.stamp.sec, m.header.stamp.nanosec = divmod(t, 10**9)
            m.vector.x, m.vector.y = 0.5 * k, -1.0 * k
            js = JointState()
            js.header.stamp = m.header.stamp
            js.name = ['rotor']
            js.position, js.velocity = [0.1 * k], [3.0]
            c = Clock()
            c.clock = m.header.stamp
            p_cur.publish(m)
            p_sh.publish(js)
            p_clk.publish(c)
            sent += [('/im/measured/current', t, m), ('/im/measured/shaft', t, js),
                     ('/clock', t, c)]
            ex.spin_once(timeout_sec=0.0)
        while sum(rec.counts.values()) < len(sent) and time.monotonic() < deadline:
            ex.spin_once(timeout_sec=0.05)
    finally:
        writer.close()
        for n in (rec, pub_node):
            if n is not None:
                n.destroy_node()
        rclpy.shutdown(context=ctx)
    assert rec.trimmed >= 0
    got = list(read_messages(path))
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore
    with AnyReader([path], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as ar:
        assert sum(1 for c, _, raw in ar.messages() if ar.deserialize(raw, c.msgtype)) == len(sent)
    key = lambda e: (e[1], e[0])  # noqa: E731
    assert sorted([(tp, t) for tp, t, _ in got]) == sorted([(tp, t) for tp, t, _ in sent])
    by = {(tp, t): m for tp, t, m in got}
    for tp, t, m in sorted(sent, key=key):
        assert by[(tp, t)] == m
