"""
The run protocol by role, without ROS: the time master, the lossless follower, an input's path.

:class:`im_common.lockstep_protocol.TimeMaster` (the plant's decisions: step 0, its lossless
followers, the end of its run, another time master of its key) and
:class:`im_common.lockstep_protocol.LosslessFollower` (the recorder's: what it acknowledges, the
end of the run); :func:`im_common.lockstep_parts.input_handler`, the one path of every lock-step
input (the plant's command too); the delivery of each topic in the topic table.
"""
from __future__ import annotations

from types import SimpleNamespace

from im_common import topics as T
from im_common.lockstep_parts import (input_handler, logs_refusal, PublisherWatch, Readiness,
                                      unknown_parameter)
from im_common.lockstep_protocol import (DRAINING, ENDED, FAILED, FINISHED, IGNORE, JOINED, LEFT,
                                         LosslessFollower, MASTER_STEPPING, READY, RUNNING, STOP,
                                         STOPPING, TimeMaster, WAITING, WARNING, YIELD)
from im_common.step_gate import LOCKSTEP_DEPTH, StepGate

P = 100_000          # T_s = 1e-4 s in ns
RUN = 'run0'


def _master(wait_for=('controller', 'observer'), window=3, timeout=5.0) -> TimeMaster:
    return TimeMaster(RUN, P, wait_for, window, timeout, domain=42)


def _ready(run=RUN, t_s=P, **values):
    return (READY, dict(values, run_id=run, T_s_ns=str(t_s)))


# The time master ------------------------------------------------------------------------------
def test_step_0_waits_for_every_node_it_waits_for_ready_in_its_own_run():
    m = _master()
    assert m.start_condition({}) == (False, None)
    peers = {'controller': _ready()}
    assert m.start_condition(peers) == (False, None)
    assert m.not_ready(peers) == ['observer']
    peers['observer'] = _ready(run='other')         # ready, but for another run
    assert m.start_condition(peers) == (False, None)
    peers['observer'] = (RUNNING, {'run_id': RUN, 'T_s_ns': str(P)})
    assert m.start_condition(peers) == (True, None)
    assert m.not_ready(peers) == []


def test_a_node_at_another_period_is_a_fault_naming_it_and_both_periods():
    m = _master(wait_for=('controller', 'recorder'))
    ok, fault = m.start_condition({'controller': _ready(t_s=2 * P),
                                   'recorder': _ready(t_s=0)})     # the recorder has no period
    assert not ok
    assert fault == ("node 'controller' runs at T_s = 0.0002 s, the plant at 0.0001 s: give "
                     'every node the same T_s')
    assert _master(wait_for=('recorder',)).start_condition({'recorder': _ready(t_s=0)}) == (
        True, None)


def test_another_live_time_master_of_the_key_blocks_step_0_until_it_ended():
    m = _master(wait_for=())
    assert m.on_peer('plant', WAITING, {'time_master': 'true', 'run_id': 'rival'}, 0.0, 0,
                     False) == (IGNORE, '')
    ok, fault = m.start_condition({})
    assert not ok and "another plant ('plant', run rival)" in fault and 'ROS_DOMAIN_ID=42' in fault
    m.on_peer('plant', FAILED, {'time_master': 'true', 'run_id': 'rival'}, 1.0, 0, False)
    assert m.start_condition({}) == (True, None)


def test_of_two_running_time_masters_the_later_one_yields():
    m = _master(wait_for=())
    m.started_at = 1000.0
    later = {'time_master': 'true', 'run_id': 'later', 'started_at': '1000.5'}
    assert m.on_peer('plant', RUNNING, later, 0.0, 0, True) == (IGNORE, '')
    earlier = {'time_master': 'true', 'run_id': 'earlier', 'started_at': '999.5'}
    what, text = m.on_peer('plant', RUNNING, earlier, 0.0, 0, True)
    assert what == YIELD and 'run earlier' in text
    own = {'time_master': 'true', 'run_id': RUN, 'started_at': '0'}     # its own events
    assert m.on_peer('plant', RUNNING, own, 0.0, 0, True) == (IGNORE, '')


def test_a_lossless_follower_joins_and_leaves_and_a_node_waited_for_ending_stops_the_run():
    m = _master()
    lossless = {'run_id': RUN, 'lossless': 'true'}
    assert m.on_peer('recorder', READY, lossless, 0.0, 5 * P, False) == (IGNORE, 'recorder')
    assert m.followers['recorder'][0] == 0                  # before step 0: counted from it
    del m.followers['recorder']
    assert m.on_peer('recorder', READY, lossless, 0.0, 5 * P, True) == (JOINED, 'recorder')
    assert m.followers['recorder'][0] == 5 * P              # joined a running run: from there
    assert m.on_peer('recorder', STOPPING, {'run_id': RUN}, 1.0, 0, True) == (
        LEFT, "follower 'recorder' stopping")
    assert m.followers == {}
    assert m.on_peer('adapter', FAILED, {'run_id': RUN}, 1.0, 0, True) == (IGNORE, '')
    assert m.on_peer('adapter', FAILED, {'run_id': RUN, 'reason': 'x'}, 1.0, 0, True,
                     providers=('adapter',)) == (STOP, 'adapter failed (x)')
    assert m.on_peer('observer', FAILED, {'run_id': 'other'}, 1.0, 0, True) == (IGNORE, '')
    assert m.on_peer('observer', WARNING, {'run_id': RUN}, 1.0, 0, True) == (IGNORE, '')
    assert m.on_peer('observer', FINISHED, {'run_id': RUN}, 1.0, 0, True) == (
        STOP, 'observer finished')


def test_the_time_master_holds_a_step_while_a_follower_lags_and_resumes_on_its_ack():
    m = _master(window=3)
    m.on_peer('recorder', READY, {'run_id': RUN, 'lossless': 'true'}, 0.0, 0, False)
    assert not m.hold('step3', 3 * P, 0.1)       # step 3 is 3 steps ahead of the ack of step 0
    assert m.hold('step4', 4 * P, 0.1)           # step 4 would be 4 ahead: parked
    assert m.lagging(4 * P, 0.1) == 'recorder'
    assert m.ack('recorder', P, 0.2)             # acknowledges step 1
    assert m.resume() == 'step4' and m.resume() is None
    assert not m.hold('step4', 4 * P, 0.2)
    assert not m.ack('stranger', P, 0.2)         # not a follower: ignored
    m.ack('recorder', 0, 0.3)                    # an older ack never moves it back
    assert m.followers['recorder'][0] == P


def test_a_silent_follower_is_dropped_after_the_timeout_and_the_run_goes_on():
    m = _master(window=3, timeout=5.0)
    dropped = []
    m.on_dropped = lambda name, ns: dropped.append((name, ns))
    m.on_peer('recorder', READY, {'run_id': RUN, 'lossless': 'true'}, 0.0, 0, False)
    assert m.hold('step9', 9 * P, 4.9)
    assert dropped == []
    assert not m.hold('step9', 9 * P, 5.1)
    assert dropped == [('recorder', 0)] and m.followers == {}


def test_the_end_of_the_run_waits_until_the_followers_acknowledged_the_last_step():
    m = _master(window=3)
    m.on_peer('recorder', READY, {'run_id': RUN, 'lossless': 'true'}, 0.0, 0, False)
    final = 100 * P
    m.ack('recorder', 98 * P, 1.0)
    assert not m.drained(final, 1.0)
    m.ack('recorder', 99 * P, 1.1)      # the command of the last step is never computed
    assert m.drained(final, 1.1)
    assert _master().drained(final, 0.0)          # no follower: over at once
    assert DRAINING in MASTER_STEPPING and RUNNING in MASTER_STEPPING


# The lossless follower -------------------------------------------------------------------------
def _follower():
    return LosslessFollower(T.ACKED_TOPICS, T.LOCKSTEP_TOPICS)


def test_a_follower_acknowledges_the_last_step_received_on_every_acknowledged_topic():
    f = _follower()
    assert f.ack_topics == list(T.ACKED_TOPICS)
    assert T.ADAPT_ESTIMATE not in f.ack_topics
    assert f.next_ack([3 * P, None, 5 * P, 4 * P]) is None    # a topic with nothing holds it
    assert f.next_ack([3 * P, 2 * P, 5 * P, 4 * P]) == 2 * P
    assert f.next_ack([3 * P, 2 * P, 5 * P, 4 * P]) is None    # nothing new
    assert f.next_ack([3 * P, 3 * P, 5 * P, 4 * P]) == 3 * P
    f.announce(RUN, f'{T.ADAPT_ESTIMATE} /not/tracked')       # the adapter said it publishes
    f.set_run(RUN)
    assert T.ADAPT_ESTIMATE in f.ack_topics and '/not/tracked' not in f.ack_topics
    f.set_run('another')
    assert T.ADAPT_ESTIMATE not in f.ack_topics


def test_a_follower_takes_the_runs_first_step_and_its_end_from_the_time_master():
    f = _follower()
    assert not f.master_event('plant', WAITING, {}, P, 'recorder', 0.0)
    assert f.master_event('plant', RUNNING, {'step': '0', 'followers': 'recorder x'}, P,
                          'recorder', 0.0)
    assert f.run_start == 0 and f.from_start
    assert not f.master_event('plant', RUNNING, {'step': '7'}, P, 'recorder', 0.0)  # once
    assert f.end_state is None and not f.drained(9.0, False, 0.0)
    f.master_event('plant', FINISHED, {'step': '100'}, P, 'recorder', 10.0)
    assert f.end_state == FINISHED and f.end_values == {'step': '100', 'node': 'plant'}
    late = _follower()
    late.master_event('plant', RUNNING, {'step': '40', 'followers': ''}, P, 'recorder', 0.0)
    assert late.run_start == 40 * P and not late.from_start


def test_a_follower_ends_after_a_grace_when_complete_or_when_nothing_more_comes():
    f = _follower()
    f.master_event('plant', FINISHED, {'step': '100'}, P, 'recorder', 10.0)
    assert not f.drained(10.2, False, 10.2)
    assert f.drained(10.51, False, 10.2)          # complete: after the end's grace
    # the last lock-step message came late, after the end's grace: the reports of its step,
    # published right after it, still get the grace
    assert not f.drained(10.9, False, 10.8)
    assert f.drained(11.11, False, 10.8)
    assert not f.drained(11.0, True, 10.5)        # behind: messages still coming
    assert f.drained(11.6, True, 10.5)            # behind, but quiet for a second
    # complete, and this graph's messages keep coming: ended after END_LIMIT_S all the same
    assert not f.drained(12.9, False, 12.85)
    assert f.drained(13.01, False, 12.95)


def test_a_time_master_that_leaves_without_a_final_event_ends_the_run_for_the_follower():
    f = _follower()
    gone = lambda: 0                                            # noqa: E731
    assert not f.master_left(1.0, False, gone, None, P)         # nothing of it seen yet
    assert not f.master_left(1.0, True, gone, 50 * P, P)        # gone since 1.0
    assert not f.master_left(1.2, True, gone, 50 * P, P)        # asked at most every 0.5 s
    assert not f.master_left(2.9, True, lambda: 1, 50 * P, P)   # back again
    assert not f.master_left(3.5, True, gone, 50 * P, P)
    assert not f.master_left(5.4, True, gone, 50 * P, P)
    assert f.master_left(5.95, True, gone, 50 * P, P)           # gone for 2 s and more
    assert f.end_state == ENDED and f.end_values['step'] == '50'
    assert not f.master_left(9.0, True, gone, 50 * P, P)        # ended once


# The topic table's delivery ---------------------------------------------------------------------
def test_every_topic_has_its_delivery_in_the_table():
    for t in T.TOPICS:
        q = t.qos
        assert q.history <= q.reader_history <= q.record_history or not q.latched, t.name
        if t.critical:
            assert q is T.LOCKSTEP_QOS and q.latched and q.reliable
        elif t.signed:
            assert q is T.REPORT_QOS and q.latched
    assert T.qos_of(T.STATUS).latched and T.qos_of(T.STATUS).reader_history == 1000
    assert not T.qos_of(T.SETPOINT).latched and not T.qos_of('/not/in/the/table').latched
    assert T.ACKED_TOPICS == (T.MEAS_CURRENT, T.MEAS_SHAFT, T.CMD_VOLTAGE, T.OBS_FLUX)
    # lossless: the plant keeps within follower_window <= LOCKSTEP_DEPTH // 2 steps of the
    # recorder, and every lock-step writer keeps LOCKSTEP_DEPTH samples: none is overwritten
    assert T.LOCKSTEP_QOS.history >= 2 * (LOCKSTEP_DEPTH // 2)


# One path for every input ------------------------------------------------------------------------
class _Node:
    """What input_handler uses of a node: its gate, signer, step loop and refusals."""

    def __init__(self, gate):
        self.gate = gate
        self.signer = SimpleNamespace(verify=lambda topic, data: not data.startswith(b'forged'))
        self.rejected = 0
        self.refusals, self.unsigned, self.steps, self.incomplete = [], [], [], []
        self.ready = self.steps.append

    def refuse(self, topic, ns, reason):
        self.refusals.append((topic, ns, reason))

    def unsigned_input(self, topic, data, handler):
        self.unsigned.append(data)

    def on_incomplete(self, topic, ns):
        self.incomplete.append(ns)


def _decode(data: bytes):
    if data == b'garbage':
        raise ValueError('too short')
    ns, vx, vy = data.decode().split()
    return int(ns), (float(vx), float(vy))


def test_an_input_is_verified_decoded_checked_finite_then_taken_into_the_step_gate():
    node = _Node(StepGate([T.CMD_VOLTAGE], P))
    on_data = input_handler(node, T.CMD_VOLTAGE, _decode, hold=(0.0, 0.0))
    on_data(b'forged 0 1 1')
    assert node.unsigned == [b'forged 0 1 1'] and node.steps == []
    on_data(b'garbage')
    assert node.rejected == 1 and 'cannot decode: too short' in node.refusals[-1][2]
    on_data(b'0 nan 1')                     # before any good one: the hold value (0 V)
    assert node.rejected == 2 and 'holding the previous one' in node.refusals[-1][2]
    assert node.steps == [{T.CMD_VOLTAGE: (0.0, 0.0)}]
    node.gate.advance()
    on_data(b'100000 3 4')
    node.gate.advance()
    on_data(b'200000 inf 4')                # holds the last good command
    assert node.steps[-1] == {T.CMD_VOLTAGE: (3.0, 4.0)}
    without = _Node(StepGate([T.CMD_VOLTAGE], P))
    input_handler(without, T.CMD_VOLTAGE, _decode)(b'0 nan 1')
    assert without.steps == [] and 'nothing to hold yet' in without.refusals[-1][2]


def test_take_may_keep_an_input_from_the_gate():
    node = _Node(StepGate([T.CMD_VOLTAGE], P))
    taken = []

    def take(ns, value):
        taken.append((ns, value))
        return ns > 0                       # the plant: not before step 0
    on_data = input_handler(node, T.CMD_VOLTAGE, _decode, take=take)
    on_data(b'0 1 2')
    assert taken == [(0, (1.0, 2.0))] and node.steps == []
    node.gate.advance()
    on_data(b'100000 1 2')
    assert node.steps == [{T.CMD_VOLTAGE: (1.0, 2.0)}]


# The node's bookkeeping -------------------------------------------------------------------------
def test_foreign_publishers_are_reported_once_and_the_graph_asked_at_a_bounded_rate():
    w = PublisherWatch('/', '')
    first = w.new_foreign(T.CMD_VOLTAGE, ['/rogue'], ros_time=False)
    assert first == [('/rogue', 'foreign publisher /rogue on /im/command/voltage '
                      '(allowed: /controller): its messages are refused')]
    assert w.new_foreign(T.CMD_VOLTAGE, ['/rogue'], ros_time=False) == []
    assert 'never on ROS time' in w.new_foreign(T.CLOCK, ['/rogue'], ros_time=True)[0][1]
    assert 'foreign publisher on it: /rogue' in w.unsigned_text(T.CMD_VOLTAGE, 'r1')
    assert w.due(10.0) and not w.due(10.5) and w.due(11.0)
    assert w.after_refusal(11.05) and not w.after_refusal(11.1) and w.due(11.1)
    logged = [n for n in range(1, 3001) if logs_refusal(n)]
    assert logged == list(range(1, 21)) + [1000, 2000, 3000]


def test_a_waiting_node_says_what_it_waits_for_only_when_that_changes():
    r = Readiness(startup_timeout=3.0, now=100.0)
    assert r.announce(['/a']) and not r.announce(['/a']) and r.announce([])
    assert not r.log_due(101.0) and r.log_due(102.0) and not r.log_due(103.0)
    assert not r.over(103.0) and r.over(103.1)


def test_an_unknown_parameter_is_refused_naming_the_nearest():
    assert unknown_parameter('controller', ['k_1', 'zz'], ['k1', 'k2']) == (
        "unknown parameter 'k_1' for node 'controller'; did you mean 'k1'? (also unknown: zz)")
    assert unknown_parameter('c', ['qos_overrides./x.depth'], []) is None
