"""
The parts LockstepNode is composed of, each on its own and without ROS.

The step gate (im_common.step_gate), the run protocol's decisions (im_common.lockstep_protocol) and
the node's message signing (im_common.signing); and the one step loop every node shell shares.
"""
from __future__ import annotations

import os
import subprocess
import sys
from types import SimpleNamespace

from im_common import topics as T
from im_common.auth import Signer
from im_common.conversions import Vector3Out
from im_common.lockstep_protocol import (FAILED, FINISHED, FINISHING, LockstepProtocol, READY,
                                         RUNNING, STOPPING, WAITING, WARNING, watchdog_limit)
from im_common.signing import allowed_publishers, foreign_publishers, NodeSigning
from im_common.step_gate import finite, StepGate
import pytest

P = 100_000          # T_s = 1e-4 s in ns
A, B = '/a', '/b'


@pytest.mark.processes
def test_the_parts_import_without_ros():
    code = ('import sys, im_common.step_gate, im_common.lockstep_protocol, im_common.signing, '
            'im_common.lockstep_parts, im_common.topics; '
            "sys.exit(1 if 'rclpy' in sys.modules else 0)")
    assert subprocess.run([sys.executable, '-c', code]).returncode == 0


# Step gate --------------------------------------------------------------------------------
def test_an_exact_gate_hands_over_a_step_once_every_input_of_it_is_there():
    g = StepGate([A, B], P)
    assert g.put(A, 0, 1.0) is None and g.missing() == [B]
    assert g.put(A, P, 2.0) is None                # the next step waits, whatever the order
    assert g.put(B, P, 20.0) is None
    assert g.put(B, 0, 10.0) == {A: 1.0, B: 10.0}
    assert g.advance() == {A: 2.0, B: 20.0}        # already complete
    assert g.step() == 1
    assert g.advance() is None and g.step() == 2 and g.missing() == [A, B]
    assert g.put(A, P, 99.0) is None               # a replay of an earlier step: ignored
    assert g.pending == {}


def test_an_exact_gate_never_skips_a_step():
    g = StepGate([A], P)
    assert g.put(A, 2 * P, 3.0) is None            # step 0 still missing
    assert g.put(A, 3 * P, 4.0) is None
    assert g.expected == 0 and g.gaps == 0 and sorted(g.pending) == [2 * P, 3 * P]


def test_a_follow_gate_jumps_to_a_complete_later_step_and_counts_what_it_lost():
    g = StepGate([A, B], P, follow=True)
    g.put(A, 0, 1.0)                               # step 0 never completes (B lost)
    g.put(A, 3 * P, 4.0)
    assert g.put(B, 3 * P, 40.0) == {A: 4.0, B: 40.0}
    assert g.expected == 3 * P and g.gaps == 3 and g.gap_ranges == [(0, 2 * P)]
    assert g.pending == {}                         # the incomplete step 0 is gone
    assert g.gap_text() == '0.0000-0.0002 s'
    assert g.advance() is None and g.expected == 4 * P
    g.put(B, 4 * P, 50.0)
    assert g.put(A, 6 * P, 7.0) is None
    assert g.put(B, 6 * P, 70.0) == {A: 7.0, B: 70.0}
    assert g.expected == 6 * P and g.gaps == 5 and g.gap_ranges == [(0, 2 * P), (4 * P, 5 * P)]


def test_a_follow_gate_keeps_a_bounded_number_of_pending_steps():
    g = StepGate([A, B], P, follow=True, max_pending=3)
    for k in range(10):
        g.put(A, k * P, float(k))                  # B never comes
    assert len(g.pending) == 3 and min(g.pending) == 7 * P
    assert g.expected == 7 * P and g.gaps == 7


def test_a_gate_skips_to_a_step_its_node_bridged_to():
    """
    Check that a node that bridged steps itself moves its gate past them.

    They are counted as gaps and their inputs dropped; the gate never moves backwards; a step
    already complete is handed over.
    """
    g = StepGate(['a', 'b'], 10, follow=True)
    g.put('a', 0, 1)
    g.put('a', 30, 2)
    g.put('b', 50, 3)
    assert g.skip_to(30) is None and g.expected == 30 and g.gaps == 3
    assert sorted(g.pending) == [30, 50]
    assert g.skip_to(10) is None and g.expected == 30 and g.gaps == 3
    assert g.put('b', 30, 4) == {'a': 2, 'b': 4}
    exact = StepGate(['a', 'b'], 10)
    exact.put('a', 0, 1)
    exact.put('a', 20, 2)
    assert exact.put('b', 20, 3) is None        # an exact gate waits for step 0
    assert exact.skip_to(20) == {'a': 2, 'b': 3} and exact.gaps == 2 and exact.pending == {}


@pytest.mark.parametrize('d', [1, 2])
def test_a_lagged_input_is_the_one_that_acts_over_the_step(d):
    """
    A gate lagged by d takes, at step k, the value stamped t_k−d; the first one also at 0..d−1.

    The values step k gets are the delay line's (im_common.delay): the same commands a node
    pushing the command of step k through its own line would integrate, whatever the order.
    """
    from im_common.delay import CommandDelay
    cmds = [(float(j), -float(j)) for j in range(8)]
    line = CommandDelay(d)
    acting = [line.push(*c) for c in cmds]
    g = StepGate([A, B], P, lags={B: d})
    got = []
    # every measurement first (the plant ahead), then the commands one by one
    for k in range(len(cmds)):
        assert g.put(A, k * P, k) is None
    for j, c in enumerate(cmds):
        inputs = g.put(B, j * P, c)
        while inputs is not None:
            got.append(inputs[B])
            assert inputs[A] == g.step()
            inputs = g.advance()
        assert g.step() == min(j + d + 1, len(cmds))    # step j + d, if measured, is done
    assert got == acting
    # the other order: each command before its steps' measurements
    g2 = StepGate([A, B], P, lags={B: d})
    got2 = []
    for j, c in enumerate(cmds):
        assert g2.put(B, j * P, c) is None
        inputs = g2.put(A, j * P, j)
        while inputs is not None:
            got2.append(inputs[B])
            inputs = g2.advance()
    assert got2 == acting
    with pytest.raises(ValueError, match='not required'):
        StepGate([A], P, lags={B: 1})


def test_a_lagged_follow_gate_keeps_the_first_steps_and_jumps_as_unlagged():
    g = StepGate([A, B], P, follow=True, lags={B: 1})
    g.put(A, 0, 0)
    g.put(A, P, 1)                                 # step 1 waits for the command of step 0
    assert g.put(B, 0, 'c0') == {A: 0, B: 'c0'}    # it completes step 0 first, then 1
    assert g.advance() == {A: 1, B: 'c0'} and g.gaps == 0
    g.advance()
    g.put(A, 4 * P, 4)                             # steps 2, 3 lost, the command of 3 came
    assert g.put(B, 3 * P, 'c3') == {A: 4, B: 'c3'}
    assert g.expected == 4 * P and g.gaps == 2


def test_finite_looks_at_every_number_of_a_decoded_input():
    assert finite((1.0, 2.0)) and finite({'R_r': 1.0})
    assert not finite((1.0, float('nan'))) and not finite({'R_r': float('inf')})


# Run protocol -------------------------------------------------------------------------------
def test_a_node_follows_the_latest_waiting_run_and_locks_on_the_one_that_runs():
    p = LockstepProtocol()
    assert p.master_event(WAITING, 'run1') == ('run1', False)
    p.run_id = 'run1'
    assert p.master_event(WAITING, 'run1') == (None, False)
    assert p.master_event(WAITING, 'run2') == (None, False)    # it follows a live run already
    assert p.other_live_runs() == ['run2']
    assert p.master_event(RUNNING, 'run2') == ('run2', True)   # run2 started first
    p.run_id, p.locked = 'run2', True
    assert p.master_event(RUNNING, 'run1') == (None, False)    # final once running
    assert p.masters == {'run1': WAITING, 'run2': RUNNING}


def test_a_run_that_ended_is_adopted_only_by_a_node_following_none():
    p = LockstepProtocol()
    assert p.master_event(FINISHED, 'old') == ('old', False)
    assert p.master_event(WAITING, '') == (None, False)        # no run id: not a run


def test_events_that_do_not_concern_a_node_are_dropped_and_peers_remembered():
    p = LockstepProtocol('run1')
    ours = {'run_id': 'run1'}
    assert not p.accept('observer', 'observer', READY, ours)           # its own
    assert not p.accept('observer', 'controller', WARNING, ours)       # not a state
    assert not p.accept('observer', 'controller', READY, {'run_id': 'run2'})
    assert p.accept('observer', 'controller', READY, ours)
    assert p.accept('observer', 'plant', RUNNING, {'run_id': 'run2', 'time_master': 'true'})
    assert p.peers == {'controller': (READY, ours)}                    # masters are not peers


def test_which_events_end_a_nodes_part_of_the_run():
    p = LockstepProtocol('run1')
    p.providers = {'plant': T.MEAS_CURRENT}
    plant = {'time_master': 'true', 'run_id': 'run1'}
    # an exact node still computing its steps waits for them; when finishing or following, ends
    assert p.end_of_part('plant', FINISHED, plant, RUNNING, False, True) is None
    assert p.end_of_part('plant', FINISHED, plant, FINISHING, False, True) == (
        'run ended by plant: finished', False)
    assert p.end_of_part('plant', FINISHED, plant, RUNNING, True, False) is not None
    assert p.end_of_part('plant', FAILED, dict(plant, reason='trip'), RUNNING, False, True) == (
        'run ended by plant: failed (trip)', False)
    # a provider stopping ends a critical reader, which says so; a follower goes on
    assert p.end_of_part('plant', STOPPING, {}, RUNNING, False, True) == (
        "input provider 'plant' stopping", True)
    assert p.end_of_part('plant', STOPPING, {}, RUNNING, True, False) is None
    assert p.end_of_part('adapter', STOPPING, {}, RUNNING, False, True) is None


def test_the_time_master_diagnoses_a_stalled_run_before_the_others():
    assert watchdog_limit(RUNNING, 5.0, 30.0, True) == 5.0
    assert watchdog_limit(READY, 5.0, 30.0, True) == 30.0
    assert watchdog_limit(RUNNING, 5.0, 30.0, False) == 8.5


def test_an_event_says_role_period_step_and_run():
    p = LockstepProtocol('abcd')
    assert p.event_values(True, True, P, 7 * P, {'mode': 'lockstep'}) == {
        'role': 'critical', 'T_s_ns': P, 'step': 7, 'time_master': 'true', 'run_id': 'abcd',
        'mode': 'lockstep'}
    assert p.event_values(False, False, 0, 5, {})['step'] == 0


# Message signing ----------------------------------------------------------------------------
def _msg(k=0, value=1.0):
    return Vector3Out(Signer.frame('alphabeta')).fill(k * P, value, 0.0)


def test_a_node_signs_and_verifies_for_the_run_it_follows():
    key = os.urandom(32)
    s, other = NodeSigning(key, T.STATUS, 8), NodeSigning(key, T.STATUS, 8)
    s.set_run('run1')
    data = s.sign(T.CMD_VOLTAGE, _msg())
    assert not other.verify(T.CMD_VOLTAGE, data)            # follows no run yet
    other.set_run('run1')
    assert other.verify(T.CMD_VOLTAGE, data) and not other.verify(T.OBS_FLUX, data)
    assert not NodeSigning(os.urandom(32), T.STATUS, 8).signer_for('run1').verify(
        T.CMD_VOLTAGE, data)


def test_status_events_are_signed_over_their_content():
    s = NodeSigning(os.urandom(32), T.STATUS, 8)
    kv = SimpleNamespace(key='run_id', value='run1')
    msg = SimpleNamespace(header=SimpleNamespace(stamp=SimpleNamespace(sec=1, nanosec=2),
                                                 frame_id=''),
                          status=[SimpleNamespace(level=b'\x00', name='plant', message=RUNNING,
                                                  hardware_id='im_drive', values=[kv])])
    msg.header.frame_id = s.status_tag(msg)
    assert s.status_verifies(msg)
    kv.value = 'run2'
    assert not s.status_verifies(msg)
    assert not NodeSigning(os.urandom(32), T.STATUS, 8).status_verifies(msg)


def _handler(data):
    raise AssertionError('only called when the kept messages are drained')


def test_messages_of_a_run_not_adopted_yet_are_kept_only_if_they_may_be_of_it():
    key = os.urandom(32)
    s = NodeSigning(key, T.STATUS, 3)
    ours = NodeSigning(key, T.STATUS, 3)
    ours.set_run('next')
    foreign = NodeSigning(os.urandom(32), T.STATUS, 3)
    foreign.set_run('next')
    mine = ours.sign(T.MEAS_CURRENT, _msg())
    rogue = foreign.sign(T.MEAS_CURRENT, _msg())
    assert s.keep_early(T.MEAS_CURRENT, rogue, _handler, None) is None      # no time master yet
    assert s.keep_early(T.MEAS_CURRENT, rogue, _handler, ['next']) == (T.MEAS_CURRENT, rogue)
    assert s.keep_early(T.MEAS_CURRENT, mine, _handler, ['next']) is None
    assert [d for _t, d, _h in s.take_early()] == [rogue, mine] and s.early == []


@pytest.mark.parametrize('keep_newest', [False, True])
def test_the_early_buffer_is_bounded(keep_newest):
    s = NodeSigning(os.urandom(32), T.STATUS, 2, keep_newest=keep_newest)
    msgs = [_msg(k) for k in range(3)]
    assert s.keep_early(T.MEAS_CURRENT, msgs[0], _handler, None) is None
    assert s.keep_early(T.MEAS_CURRENT, msgs[1], _handler, None) is None
    refused = s.keep_early(T.MEAS_CURRENT, msgs[2], _handler, None)
    # a follower needs the first steps of its run; the recorder the newest (no gap after them)
    assert refused == (T.MEAS_CURRENT, msgs[0] if keep_newest else msgs[2])
    assert [d for _t, d, _h in s.early] == (msgs[1:] if keep_newest else msgs[:2])


def test_who_may_publish_on_a_nodes_inputs():
    allowed = allowed_publishers('/drive/', '/im/command/voltage=ctl2 /im/setpoint=/ops/panel')
    assert allowed[T.CMD_VOLTAGE] == {'/drive/controller', '/drive/ctl2'}
    assert allowed[T.SETPOINT] == {'/drive/user', '/ops/panel'}    # the table names 'user'
    with pytest.raises(ValueError, match="'allowed_publishers' item 'controller'"):
        allowed_publishers('/', 'controller')
    pub = lambda ns, name: SimpleNamespace(node_namespace=ns, node_name=name)  # noqa: E731
    infos = [pub('/drive', 'controller'), pub('/', 'rogue'), pub('/', 'rogue'),
             pub('/', '_NODE_NAME_UNKNOWN_'), pub('/drive', 'ctl2')]
    assert foreign_publishers(allowed[T.CMD_VOLTAGE], infos) == ['/rogue']
    assert foreign_publishers(None, infos) == []


# The step loop -------------------------------------------------------------------------------
def test_the_step_loop_has_one_home():
    """
    Check that the node shells share one step loop.

    Every node shell computes one step (``step``); none copies the loop that takes complete
    steps from its gate (``LockstepNode.ready``).
    """
    from im_adapt.adapter_node import AdapterNode
    from im_common.lockstep import LockstepNode
    from im_controller.controller_node import ControllerNode
    from im_observer.observer_node import ObserverNode
    from im_plant.plant_node import PlantNode
    for cls in (AdapterNode, ControllerNode, ObserverNode, PlantNode):
        assert 'ready' not in vars(cls) and 'step' in vars(cls), cls.__name__
    assert 'ready' in vars(LockstepNode)


# Hosting ---------------------------------------------------------------------------------------
class _Logger:
    """A node's log, kept."""

    def __init__(self):
        self.lines = []

    def info(self, text):
        self.lines.append(('info', text))

    def warning(self, text):
        self.lines.append(('warning', text))


class _Hosted:
    """What a ProcessHost uses of a node: its priority, log, scheduling and events."""

    realtime_capable = True

    def __init__(self, rt_priority):
        self.rt_priority = rt_priority
        self.scheduling = 'normal'
        self.logger = _Logger()
        self.events = []

    def get_logger(self):
        return self.logger

    def status(self, state, level=0, **values):
        self.events.append((state, values['reason']))


def test_a_process_host_enters_real_time_once_and_says_when_it_cannot(monkeypatch):
    """The node asks at every free_run event; the process tries once, a refusal is a warning."""
    from im_common import host, realtime
    tries = []

    def refused(priority):
        tries.append(priority)
        return False, 'no permission'
    monkeypatch.setattr(realtime, 'enter', refused)
    loop, process = _Hosted(50), host.ProcessHost()
    process.enter_realtime(loop)
    process.enter_realtime(loop)
    assert tries == [50] and loop.scheduling == process.scheduling == 'normal (refused)'
    assert loop.events == [(WARNING, 'free_run without real-time scheduling: no permission; '
                                     'deadlines may be missed')]
    monkeypatch.setattr(realtime, 'enter', lambda priority: (True, f'fifo:{priority}'))
    monkeypatch.setattr(realtime, 'quiet_gc', lambda: tries.append('gc'))
    recorder = _Hosted(40)
    host.ProcessHost().enter_realtime(recorder, below_loop=True)
    assert recorder.scheduling == 'fifo:40' and 'gc' not in tries
    assert recorder.logger.lines == [('info', 'free_run: recording at real-time priority fifo:40, '
                                              'below the control loop')]
    ordinary = _Hosted(0)
    host.ProcessHost().enter_realtime(ordinary)
    assert ordinary.scheduling == 'normal' and 'rt_priority 0' in ordinary.logger.lines[0][1]
