"""The recorder node, in-process on its own context: what is published is what is recorded."""
import time

from geometry_msgs.msg import Vector3Stamped
from im_bringup.testing import random_domain
from im_common import topics as T
from im_common.auth import Signer
from im_common.conversions import JointStateOut, Vector3Out
from im_recording.bag import BagWriter, info, read_messages
from im_recording.record_node import parse_topics, RecorderNode
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState


def test_parse_topics():
    t = parse_topics(['/im/measured/current', '/x:=std_msgs/msg/String'])
    assert t == {'/im/measured/current': 'geometry_msgs/msg/Vector3Stamped',
                 '/x': 'std_msgs/msg/String'}
    assert len(parse_topics(None)) >= 17


def test_recorder_node_records_what_was_published(tmp_path):
    ctx = Context()
    rclpy.init(context=ctx, domain_id=random_domain())
    path = tmp_path / 'rec.mcap'
    writer = BagWriter(path)
    pub_node = rec = None
    try:
        topics = parse_topics(['/im/measured/current', '/im/measured/shaft', '/clock',
                               T.TRUTH_VOLTAGE])
        rec = RecorderNode(writer, topics, context=ctx)
        pub_node = Node('talker', context=ctx)
        q = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.TRANSIENT_LOCAL)
        p_cur = pub_node.create_publisher(Vector3Stamped, '/im/measured/current', q)
        p_sh = pub_node.create_publisher(JointState, '/im/measured/shaft', q)
        p_clk = pub_node.create_publisher(Clock, '/clock', 10)
        p_tv = pub_node.create_publisher(Vector3Stamped, T.TRUTH_VOLTAGE, q)
        ex = SingleThreadedExecutor(context=ctx)
        ex.add_node(rec)
        ex.add_node(pub_node)
        from im_bringup.testing import wait_until

        def spun_until(condition):          # events, each with a generous hang guard
            return wait_until(lambda: ex.spin_once(timeout_sec=0.05) or condition(), 60, 0.0)
        assert spun_until(lambda: all(p.get_subscription_count() for p in (
            p_cur, p_sh, p_clk, p_tv))), 'hang: the recorder never matched the talker in 60 s'
        # the talker is the graph's plant: it signs the lock-step and truth topics for its run
        rec.adopt_run('run1')
        sign = Signer(rec.signer.key, 'run1').sign
        v3 = Vector3Out(Signer.frame('alphabeta'))
        shaft = JointStateOut(['rotor'], Signer.frame(''))
        sent = []
        for k in range(50):
            t = 2 * 10**9 + k * 100_000
            cur = sign('/im/measured/current', v3.fill(t, 0.5 * k, -1.0 * k))
            sh = sign('/im/measured/shaft', shaft.fill(t, (0.1 * k,), (3.0,)))
            c = Clock()
            c.clock.sec, c.clock.nanosec = divmod(t, 10**9)
            p_cur.publish(cur)
            p_sh.publish(sh)
            p_clk.publish(c)
            sent += [('/im/measured/current', t, deserialize_message(cur, Vector3Stamped)),
                     ('/im/measured/shaft', t, deserialize_message(sh, JointState)),
                     ('/clock', t, c)]
            if k % 10 == 0:
                tv = sign(T.TRUTH_VOLTAGE, v3.fill(t, 20.0, -k))
                p_tv.publish(tv)
                sent.append((T.TRUTH_VOLTAGE, t, deserialize_message(tv, Vector3Stamped)))
            ex.spin_once(timeout_sec=0.0)
        # a foreign message on a lock-step topic: kept apart, never mixed into the run's data
        rogue = Vector3Stamped()
        rogue.header.stamp.sec = 2
        rogue.vector.x = 50.0
        p_cur.publish(rogue)
        p_tv.publish(rogue)             # and on a report topic: another graph's ground truth
        assert spun_until(lambda: sum(rec.counts.values()) >= len(sent) and sum(
            rec.unsigned.values()) + len(rec.signing.early) >= 2), \
            f'hang: the recorder got {sum(rec.counts.values())} of {len(sent)} messages in 60 s'
        rec.flush_unverified()          # the run never started: what did not verify is refused
        rec.writer.add_metadata('recording', rec.close_metadata(None))
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
        assert sum(1 for c, _,
                   raw in ar.messages() if ar.deserialize(raw, c.msgtype)) == len(sent) + 2
    key = lambda e: (e[1], e[0])  # noqa: E731
    assert sorted([(tp, t) for tp, t,
                   _ in got if not tp.startswith('/im/refused')]) == sorted([(tp, t) for tp, t,
                                                                             _ in sent])
    by = {(tp, t): m for tp, t, m in got if not tp.startswith('/im/refused')}
    for tp, t, m in sorted(sent, key=key):
        assert by[(tp, t)] == m
    refused = [(tp, m.vector.x) for tp, t, m in got if tp.startswith('/im/refused')]
    assert sorted(refused) == [('/im/refused/im/measured/current', 50.0),
                               ('/im/refused' + T.TRUTH_VOLTAGE, 50.0)]
    meta = info(path).metadata['recording']
    assert meta['refused_unsigned'] == '2' and '/talker@/im/measured/current' in \
        meta['foreign_publishers']
    assert meta['refused_unsigned' + T.TRUTH_VOLTAGE] == '1'


def test_a_late_recorder_keeps_the_newest_of_what_it_cannot_verify_yet(tmp_path):
    """
    Check that a late recorder keeps the newest unverified messages.

    A recorder that joins a running graph may see the lock-step topics before the plant's status
    (discovery under load took 2 s; 27 000 messages): it keeps a bounded window of what it cannot
    verify yet, and when that is full the oldest goes to /im/refused, not the newest — so what it
    keeps reaches up to the moment it learns the run, and the recording has no gap between the kept
    window and what follows (a fresh-clone make test once recorded 0.725 s, then nothing until 0.94
    s).
    """
    ctx = Context()
    rclpy.init(context=ctx, domain_id=random_domain())
    writer = BagWriter(tmp_path / 'late.mcap')
    rec = None
    try:
        rec = RecorderNode(writer, parse_topics(['/im/measured/current']), context=ctx)
        rec.signing.early_max = 10      # the node's bound on what it cannot verify yet
        sign = Signer(rec.signer.key, 'run1').sign
        out = Vector3Out(Signer.frame('alphabeta'))
        sent = [sign('/im/measured/current', out.fill(k * 100_000, 1.0, 0.0)) for k in range(25)]
        handled = []
        for data in sent:
            rec.unsigned_input('/im/measured/current', data, handled.append)
        assert rec.unsigned['/im/measured/current'] == 15
        rec.adopt_run('run1')
        rec.signing.drain()
        assert handled == sent[15:]
    finally:
        writer.close()
        if rec is not None:
            rec.destroy_node()
        rclpy.shutdown(context=ctx)


PERIOD = 100_000
LOCK = ['/im/measured/current', '/im/measured/shaft', '/im/command/voltage', '/im/observer/flux']


class _Run:
    """
    Return a recorder fed signed messages directly, and a listener.

    A recorder on a private context, fed the signed messages of run 'run1' directly (what its
    subscriptions would hand it), and a listener of its acknowledgements on /im/progress.
    """

    def __init__(self, tmp_path):
        self.ctx = Context()
        rclpy.init(context=self.ctx, domain_id=random_domain())
        self.path = tmp_path / 'rec.mcap'
        self.writer = BagWriter(self.path)
        self.rec = RecorderNode(self.writer, parse_topics(LOCK + ['/im/status']), context=self.ctx)
        self.sign = Signer(self.rec.signer.key, 'run1').sign
        self.cb = {t: self.rec._callback(t, self.rec.topics[t], True) for t in LOCK}
        self.v3 = Vector3Out(Signer.frame('alphabeta'))
        self.js = JointStateOut(['rotor'], Signer.frame(''))
        from std_msgs.msg import Header
        self.acks = []
        self.listener = Node('listener', context=self.ctx)
        self.listener.create_subscription(
            Header, '/im/progress',
            lambda h: self.acks.append(h.stamp.sec * 10**9 + h.stamp.nanosec), 10)
        self.ex = SingleThreadedExecutor(context=self.ctx)
        self.ex.add_node(self.rec)
        self.ex.add_node(self.listener)

    def plant(self, state, step, **values):
        self.rec.on_peer_status('plant', state, dict(
            time_master='true', run_id='run1', T_s_ns=str(PERIOD), step=str(step), **values))

    def feed(self, topic, steps):
        for k in steps:
            t = k * PERIOD
            out = self.js.fill(t, (0.1 * k,), (3.0,)) if topic.endswith('shaft') else \
                self.v3.fill(t, 0.5 * k, -1.0 * k)
            self.cb[topic](self.sign(topic, out))

    def spin(self, seconds=0.3):
        t_end = time.monotonic() + seconds
        while time.monotonic() < t_end:
            self.ex.spin_once(timeout_sec=0.02)

    def spin_until(self, condition, hang_s=60.0):
        """Spin until ``condition()`` holds (True) or ``hang_s`` passed (False: a hang)."""
        from im_bringup.testing import wait_until
        return bool(wait_until(lambda: self.ex.spin_once(timeout_sec=0.02) or condition(),
                               hang_s, 0.0))

    def close(self):
        self.writer.close()
        self.rec.destroy_node()
        self.listener.destroy_node()
        rclpy.shutdown(context=self.ctx)


def test_missing_steps_are_counted_before_the_first_between_and_after_the_last(tmp_path):
    """
    Check that the bag metadata counts the steps each topic lacks.

    A recording from the start of a run that got the commands only from step 10 on (its reader
    matched the controller late), lost steps 20-22 of the flux and the last two of the shaft: the
    bag's metadata counts each of them, on its topic, with its range.
    """
    r = _Run(tmp_path)
    try:
        r.plant('running', 0, mode='lockstep', followers='recorder')
        r.feed('/im/measured/current', range(0, 51))
        r.feed('/im/measured/shaft', range(0, 49))
        r.feed('/im/command/voltage', range(10, 50))           # 0-9 never arrived
        r.feed('/im/observer/flux', [k for k in range(0, 51) if not 20 <= k <= 22])
        r.plant('finished', 50, steps='50')
        meta = r.rec.close_metadata(None)
    finally:
        r.close()
    assert meta['missing_steps/im/command/voltage'] == '10'
    assert meta['missing_ranges/im/command/voltage'] == f'0-{9 * PERIOD}'
    assert meta['missing_steps/im/observer/flux'] == '3'
    assert meta['missing_steps/im/measured/shaft'] == '2'
    assert meta['missing_ranges/im/measured/shaft'] == f'{49 * PERIOD}-{50 * PERIOD}'
    assert meta['missing_steps/im/measured/current'] == '0'
    assert meta['missing_steps'] == '15'


def test_a_topic_with_nothing_yet_holds_the_plant_back(tmp_path):
    """
    The acknowledgement on /im/progress is the last step received on *every* lock-step topic.

    While the commands have not reached the recorder, it acknowledges nothing (the plant stays
    within follower_window steps of step 0 and the commands stay in their publisher's history);
    once they arrive it acknowledges the least of the topics' last steps.
    """
    r = _Run(tmp_path)
    try:
        assert r.spin_until(lambda: r.rec.count_subscribers('/im/progress') >= 1), \
            'hang: the listener never matched /im/progress'
        r.plant('running', 0, mode='lockstep', followers='recorder')
        for t in ('/im/measured/current', '/im/measured/shaft', '/im/observer/flux'):
            r.feed(t, range(0, 40))
        r.spin(0.5)     # an absence has no event: 25 periods of the recorder's ack timer
        assert r.acks == []
        r.feed('/im/command/voltage', range(0, 30))
        # the acknowledgement is an event: waited for, not counted after a fixed spin
        r.spin_until(lambda: r.acks and r.acks[-1] >= 29 * PERIOD)
    finally:
        r.close()
    assert r.acks and r.acks[-1] == 29 * PERIOD, r.acks[-3:]


def test_a_recorder_stopped_mid_run_counts_every_topic_to_the_last_step_it_saw(tmp_path):
    """
    A recorder stopped (Ctrl-C) while the run goes on, counted from the run's step 0.

    The commands never arrived and the shaft stopped at step 90 while the plant had announced
    step 100: every lock-step topic is counted from step 0 to the last announced step (the
    commands and estimates of that step are not computed yet: to the step before), the topic
    with nothing recorded included.
    """
    r = _Run(tmp_path)
    try:
        r.plant('running', 0, mode='lockstep', followers='recorder')
        r.feed('/im/measured/current', range(0, 101))
        r.feed('/im/measured/shaft', range(0, 91))
        r.feed('/im/observer/flux', range(0, 100))
        meta = r.rec.close_metadata('SIGINT')
    finally:
        r.close()
    assert meta['missing_steps/im/command/voltage'] == '100'           # 0 .. 99
    assert meta['missing_ranges/im/command/voltage'] == f'0-{99 * PERIOD}'
    assert meta['missing_steps/im/measured/shaft'] == '10'             # 91 .. 100
    assert meta['missing_steps/im/observer/flux'] == '0'
    assert meta['missing_steps/im/measured/current'] == '0'
    assert meta['missing_steps'] == '110'
    assert meta['counted_from_step'] == '0' and meta['counted_to_step'] == '100'
    assert 'joined_at_step' not in meta


def test_a_late_recorder_says_where_it_joined_and_counts_the_topic_it_never_got(tmp_path):
    """
    The issue's recorder: not waited for, it joined late and recorded no command at all.

    It took the writers' history from step 3,683 and was stopped at step 5,140 while the run went
    on: it says it joined at step 3,683 and counts from there to the last announced step on
    every topic — 1,457 commands (3,683 .. 5,139), not 0.
    """
    r = _Run(tmp_path)
    try:
        r.plant('running', 0, mode='lockstep', followers='')
        for t in ('/im/measured/current', '/im/measured/shaft', '/im/observer/flux'):
            r.feed(t, range(3683, 5141))
        meta = r.rec.close_metadata('SIGINT')
    finally:
        r.close()
    assert meta['joined_at_step'] == '3683'
    assert meta['counted_from_step'] == '3683' and meta['counted_to_step'] == '5140'
    assert meta['missing_steps/im/command/voltage'] == '1457'
    assert meta['missing_steps'] == '1457'
    for t in ('/im/measured/current', '/im/measured/shaft', '/im/observer/flux'):
        assert meta[f'missing_steps{t}'] == '0', t


def test_a_setpoint_stamped_0_is_stored_at_the_step_it_took_effect(tmp_path):
    """
    Store a setpoint at the step it took effect, its own stamp as publish time.

    ``ros2 topic pub /im/setpoint`` leaves the stamp 0: the controller applies it at the step the
    run is at. The bag stores it there (log time), with its own stamp kept as publish time; a
    setpoint stamped in the future is stored at its stamp.
    """
    from mcap.reader import make_reader
    r = _Run(tmp_path)
    try:
        sp = r.rec._callback(T.SETPOINT, T.TOPIC_TYPES[T.SETPOINT], True)
        r.rec.counts[T.SETPOINT] = 0
        r.plant('running', 0, mode='lockstep', followers='recorder')
        for t in LOCK:
            r.feed(t, range(0, 51))
        sp(JointStateOut(['rotor'], '').fill(0, (), (100.0,)))
        sp(JointStateOut(['rotor'], '').fill(80 * PERIOD, (), (50.0,)))
        for t in LOCK:
            r.feed(t, range(51, 101))
    finally:
        r.close()
    with open(r.path, 'rb') as f:
        got = [(m.log_time, m.publish_time) for _, ch, m in
               make_reader(f).iter_messages(topics=[T.SETPOINT])]
    assert got == [(50 * PERIOD, 0), (80 * PERIOD, 80 * PERIOD)]


def test_a_step_that_arrives_late_is_no_longer_counted_missing():
    """Out-of-order arrival on one topic: the count is of what is lacking at the end."""
    from im_recording.record_node import StampTrack
    tr = StampTrack()
    for k in (0, 3, 1, 2, 10, 5, 5):                   # 5 twice: a duplicate counts once
        tr.see(k * PERIOD, PERIOD)
    assert tr.missing == 5                              # 4, 6, 7, 8, 9
    assert tr.ranges == [(4 * PERIOD, 4 * PERIOD), (6 * PERIOD, 9 * PERIOD)]
    late = StampTrack()
    for k in (5, 6, 2):                                 # an earlier step after the first
        late.see(k * PERIOD, PERIOD)
    assert (late.first, late.missing, late.ranges) == (2 * PERIOD, 2, [(3 * PERIOD, 4 * PERIOD)])
    assert late.account(0, 8 * PERIOD, PERIOD)[0] == 2 + 2 + 2      # 0-1, 3-4, 7-8


def test_only_the_counted_span_is_counted_missing():
    """
    Gaps between stamps received outside the counted span are not the span's.

    A late recorder stopped mid-run on a crowded machine: its observer-flux subscription matched
    after the step it was stopped at, so the flux it holds is one stamp before its span and the
    ones after; the span lacks every flux step, no more (it said 590 for a span of 531).
    """
    from im_recording.record_node import StampTrack
    flux = StampTrack()
    for k in (430, 1020, 1021):
        flux.see(k * PERIOD, PERIOD)
    assert flux.missing == 1020 - 430 - 1                           # between what it received
    n, ranges = flux.account(437 * PERIOD, 967 * PERIOD, PERIOD)
    assert (n, ranges) == (531, [(437 * PERIOD, 967 * PERIOD)])
    after = StampTrack()                                            # all after the span
    for k in (1000, 1003):
        after.see(k * PERIOD, PERIOD)
    assert after.account(437 * PERIOD, 967 * PERIOD, PERIOD) == (531, [(437 * PERIOD,
                                                                        967 * PERIOD)])
    inside = StampTrack()                       # within the span: counted as before
    for k in (440, 445, 1000):
        inside.see(k * PERIOD, PERIOD)
    assert inside.account(437 * PERIOD, 967 * PERIOD, PERIOD)[0] == 3 + 4 + (967 - 445)
