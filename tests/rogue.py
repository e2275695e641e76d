"""
A foreign node on the drive graph's ROS domain that tries to steer the run.

It answers every measured current stamped t_k, on RELIABLE + TRANSIENT_LOCAL publishers, with a
50 V command of the same stamp, a fake flux estimate, fake adapter estimates, a fake measurement
for the next step (ahead of the plant), a fake applied voltage on the truth (a report topic: a
recording must not mix it into the run's ground truth), a /clock jump, and — once it has seen the
run's id on /im/status — a fake ``finished`` of the plant for that run. Imported by the
in-process tests (:class:`Rogue`) and run as its own process by the multi-process ones
(``python tests/rogue.py``, ROS_DOMAIN_ID from the environment, until SIGINT/SIGTERM).
"""
import signal
import sys
import threading

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import Vector3Stamped
from im_common import topics as T
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState

# the graph's own writer history (100): a late discovery replays it at once into the graph's
# readers, which keep ten times that (im_common.lockstep.LOCKSTEP_READER_HISTORY, docs/security.md)
QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE,
                 durability=DurabilityPolicy.TRANSIENT_LOCAL)
STATUS_QOS = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.TRANSIENT_LOCAL)
ROGUE_VOLTAGE = 50.0


class RogueNode(Node):

    def __init__(self, **kwargs):
        super().__init__('rogue', **kwargs)
        self.answered = 0
        self.run_id = ''
        self.pubs = {t: self.create_publisher(cls, t, QOS) for t, cls in (
            (T.CMD_VOLTAGE, Vector3Stamped), (T.OBS_FLUX, Vector3Stamped),
            (T.ADAPT_ESTIMATE, JointState), (T.MEAS_CURRENT, Vector3Stamped),
            (T.TRUTH_VOLTAGE, Vector3Stamped))}
        self.clock = self.create_publisher(Clock, T.CLOCK, 10)
        self.status = self.create_publisher(DiagnosticArray, T.STATUS, STATUS_QOS)
        self.create_subscription(Vector3Stamped, T.MEAS_CURRENT, self.on_current, QOS)
        self.create_subscription(DiagnosticArray, T.STATUS, self.on_status, STATUS_QOS)

    def on_status(self, msg):
        for st in msg.status:
            values = {kv.key: kv.value for kv in st.values}
            if values.get('time_master') == 'true' and values.get('run_id') and not self.run_id:
                self.run_id = values['run_id']

    def on_current(self, msg):
        if msg.vector.x == 100.0:            # its own fake measurement coming back
            return
        stamp = msg.header.stamp
        cmd = Vector3Stamped()
        cmd.header.stamp = stamp
        cmd.header.frame_id = msg.header.frame_id        # even a copied tag does not verify
        cmd.vector.x = ROGUE_VOLTAGE
        self.pubs[T.CMD_VOLTAGE].publish(cmd)
        flux = Vector3Stamped()
        flux.header.stamp = stamp
        flux.vector.x = 1.0
        self.pubs[T.OBS_FLUX].publish(flux)
        est = JointState()
        est.header.stamp = stamp
        est.name = list(T.ESTIMATE_NAMES)
        est.position = [10.0] * len(T.ESTIMATE_NAMES)
        self.pubs[T.ADAPT_ESTIMATE].publish(est)
        ahead = Vector3Stamped()
        ahead.header.stamp.sec, ahead.header.stamp.nanosec = stamp.sec, stamp.nanosec + 100_000
        ahead.vector.x = 100.0
        self.pubs[T.MEAS_CURRENT].publish(ahead)
        truth = Vector3Stamped()
        truth.header.stamp = stamp
        truth.vector.x = ROGUE_VOLTAGE
        self.pubs[T.TRUTH_VOLTAGE].publish(truth)
        clk = Clock()
        clk.clock.sec = stamp.sec + 1000
        self.clock.publish(clk)
        self.answered += 1
        if self.run_id and self.answered == 10:
            fake = DiagnosticArray()
            fake.status = [DiagnosticStatus(name='plant', message='finished', values=[
                KeyValue(key='time_master', value='true'), KeyValue(key='run_id',
                                                                    value=self.run_id),
                KeyValue(key='step', value='10')])]
            self.status.publish(fake)


class Rogue:
    """``with Rogue(domain_id) as r:`` a rogue node spinning in a thread of its own context."""

    def __init__(self, domain_id: int):
        self.domain_id = domain_id

    def __enter__(self):
        self.ctx = Context()
        rclpy.init(context=self.ctx, domain_id=self.domain_id)
        self.node = RogueNode(context=self.ctx)
        self.ex = SingleThreadedExecutor(context=self.ctx)
        self.ex.add_node(self.node)
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()
        return self

    def _spin(self):
        while not self.stop.is_set():
            self.ex.spin_once(timeout_sec=0.02)

    def __exit__(self, *exc):
        self.stop.set()
        self.thread.join()
        self.ex.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.ctx)


def main() -> int:
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    rclpy.init(signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    node = RogueNode()
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    print('rogue: up', flush=True)
    while not stop.is_set():
        ex.spin_once(timeout_sec=0.05)
    print(f'rogue: answered {node.answered} measurements', flush=True)
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
