"""
The lock-step node shared by every drive node: an rclpy adapter of the ROS-free parts.

Step protocol (``docs/architecture.md``): step k is
  plant publishes measurements stamped t_k → controller computes V_k once it holds every input
  stamped t_k → plant integrates [t_k, t_k+1] with V_k held while the observer predicts x̂_{k+1}
  and the adapter updates p̂_{k+1} from the same step's data, both stamped t_k+1.
Two topic hops per step on the critical path. Every node computes from inputs identified by their
stamps, never by arrival order, so the same run gives the same numbers whatever the scheduling.

The node is a composition of small parts, each in its own module and unit-tested without ROS:
- :class:`im_common.step_gate.StepGate`: a step's inputs collected by stamp, when a step is
  complete, the steps a follower lost;
- :class:`im_common.lockstep_protocol.LockstepProtocol`: which run the node follows, which events
  concern it, when its part of the run is over (the protocol itself is described there; the roles
  :class:`~im_common.lockstep_protocol.TimeMaster` and
  :class:`~im_common.lockstep_protocol.LosslessFollower` too);
- :class:`im_common.signing.NodeSigning`: the tags of its messages and events (keys and tags:
  :mod:`im_common.auth`), and the messages kept for a run not adopted yet;
- :mod:`im_common.lockstep_parts`: who may publish on its inputs, its readiness, its watchdog;
- :mod:`im_common.qos`: every endpoint's QoS, from the topic table (:mod:`im_common.topics`).
:class:`LockstepNode` wires them to rclpy (publishers, subscriptions, the watchdog timer, the log)
and runs the step loop once for every node (:meth:`LockstepNode.ready`): a node shell declares its
inputs and computes one step (:meth:`LockstepNode.step`). Where a node runs (its own process,
real-time scheduling, stop signals, the spin) is :mod:`im_common.host`'s.
"""
from __future__ import annotations

import time
from typing import Callable, Dict, List, Optional, Sequence

from rclpy.clock import Clock, ClockType
from rclpy.node import Node

from . import auth, realtime
from .host import (build_node, EXIT_GRACE_S, flush, init_args_error,  # noqa: F401
                   make_executor, node_main, parameter_table, print_node_help, request_stop,
                   spin_until_done, STOP_FLUSH_S)
from .lockstep_parts import (crosstalk_text, header_stamp, input_handler, InputWatchdog,
                             logs_refusal, providers, PublisherWatch, Readiness, stall_text,
                             stamp_text, waiting_text, WATCHDOG_TICK_S)
from .lockstep_protocol import (END_STATES, FAILED, FINISHED, FINISHING, is_master,  # noqa: F401
                                LockstepProtocol, NOT_STATES, PARAMETERS, READY, RUNNING,
                                STARTING, STOPPED, STOPPING, WAITING, WARNING)
from .node_params import ConfigurationError, declare, declare_lockstep, describe  # noqa: F401
from .qos import data_qos, lockstep_qos, probe_qos, reader, report_qos, status_qos  # noqa: F401
from .signing import NodeSigning
from .status_channel import StatusChannel
from .step_gate import finite, LOCKSTEP_DEPTH, StepGate  # noqa: F401
from .topics import CLOCK, JS, LOCKSTEP_QOS, LOCKSTEP_TOPICS, REPORT_QOS, STATUS, STATUS_QOS
from .topics import TOPIC_TYPES

# The histories, as the topic table states them (im_common.topics: why they are what they are).
LOCKSTEP_HISTORY = LOCKSTEP_QOS.history
LOCKSTEP_READER_HISTORY = LOCKSTEP_QOS.reader_history
REPORT_HISTORY = REPORT_QOS.history
STATUS_READER_DEPTH = STATUS_QOS.reader_history


class TappedPublisher:
    """
    A node's publisher that also hands what it publishes to the node's :attr:`~LockstepNode.tap`.

    The in-process graph records through it (:mod:`im_bringup.graph`): a designed hook of the
    node, not a change of rclpy's classes. Everything but :meth:`publish` is the rclpy
    publisher's own.
    """

    __slots__ = ('_pub', '_node', 'topic_name')

    def __init__(self, pub, node: 'LockstepNode'):
        self._pub = pub
        self._node = node
        self.topic_name = pub.topic_name

    def publish(self, msg) -> None:
        self._pub.publish(msg)
        tap = self._node.tap
        if tap is not None:
            tap(self.topic_name, msg)

    def __getattr__(self, name):
        return getattr(self._pub, name)


class LockstepNode(Node):
    """
    Base of the drive nodes: the rclpy adapter of the step gate, run protocol and watchdog.

    A subclass sets ``self.gate`` (a :class:`StepGate`), declares its inputs (:meth:`gate_input`),
    computes one complete step (:meth:`step`) and ends its ``__init__`` with
    :meth:`start_protocol`. ``critical`` nodes (the default) use an exact gate and a watchdog in
    lock-step; others follow. Its parts: ``gate``, ``protocol``, ``signing``, ``events``
    (:class:`StatusChannel`), ``watch``, ``readiness``, ``watchdog``; ``host``: the process
    hosting it alone (:class:`im_common.host.ProcessHost`), None in a graph of one process.
    """

    critical = True
    time_master = False
    realtime_capable = True     # SCHED_FIFO in free_run when it runs as its own process
    default_rt_priority = realtime.DEFAULT_PRIORITY     # of ``rt_priority``
    #: ``tap(topic, msg)`` gets every message it published (set by the in-process recorder)
    tap = host = None
    #: Messages kept before the run followed is running (:meth:`NodeSigning.keep_early`); when
    #: full, the new one is refused (a follower needs its run's first steps), or the oldest (True).
    EARLY_MAX, EARLY_KEEP_NEWEST = 4 * LOCKSTEP_DEPTH, False

    def __init__(self, name: str, graph_key: Optional[bytes] = None, **kwargs):
        super().__init__(name, **kwargs)
        self.done, self.exit_code, self.failure = False, 0, None
        self.gate: Optional[StepGate] = None
        self.state, self.period, self.last_step = STARTING, 0, None
        self.inputs: List[str] = []
        self.protocol, self.free_run, self.scheduling = LockstepProtocol(), False, 'normal'
        self.watchdog, self.readiness = InputWatchdog(), None
        self.refused = self.rejected = 0            # inputs refused; of them, not decodable/finite
        self.refused_by_topic: Dict[str, int] = {}  # of them, not signed by this graph
        self.on_stop: Optional[Callable[['LockstepNode'], None]] = None   # set by a graph
        self.event_context: Dict[str, str] = {}     # key/values in every event (plant: mode)
        self.rt_priority, key_file, allowed = declare_lockstep(self)
        self.watch = PublisherWatch(self.get_namespace(), allowed)
        self.allowed, self.foreign = self.watch.allowed, self.watch.foreign
        if graph_key is None:
            try:
                graph_key = auth.read_key_file(key_file or auth.default_key_file(),
                                               create=not key_file)
            except auth.GraphKeyError as exc:
                if not key_file:
                    raise
                raise auth.GraphKeyError(f"invalid parameter 'graph_key_file' = {key_file!r}: "
                                         f'{exc}') from None
        self.signing = NodeSigning(graph_key, STATUS, self.EARLY_MAX, self.EARLY_KEEP_NEWEST)
        self.signer = self.signing.signer               # the followed run's (set_run in place)
        self.sign = self.signer.sign                    # tag a lock-step message for that run
        self.status_signer = self.signing.status_signer
        self.events = StatusChannel(self)

    def create_publisher(self, *args, **kwargs) -> TappedPublisher:
        """Create the rclpy publisher, returned with the node's recording tap on it."""
        return TappedPublisher(super().create_publisher(*args, **kwargs), self)

    run_id = property(lambda self: self.protocol.run_id,
                      lambda self, run: setattr(self.protocol, 'run_id', run),
                      doc="The time master's run this node follows ('' until it has seen one).")
    peers = property(lambda self: self.protocol.peers,
                     doc='Node name -> (state, values) of its last event in the run followed.')
    providers = property(lambda self: self.protocol.providers,
                         doc='Publisher node name -> one topic of its inputs it provides.')
    master_state = property(lambda self: self.protocol.master_state,
                            doc='The last state of the time master of the run followed.')
    input_timeout = property(lambda self: self.watchdog.timeout,
                             doc='How long an input may stay silent [s] (then fail or drop it).')

    def param(self, name: str, default, description: str, lo=None, hi=None, read_only: bool = True,
              choices: Optional[Sequence[str]] = None):
        """Declare a parameter with a descriptor and return its value (validated)."""
        return declare(self, name, default, description, lo, hi, read_only, choices)

    # Run protocol ----------------------------------------------------------------------------
    def status(self, state: str, level: int = 0, stamp_ns: Optional[int] = None,
               **values) -> None:
        """Publish a run-protocol event on /im/status; keep it as this node's state."""
        if state not in NOT_STATES:
            self.state = state
        self.events.publish(state, level, stamp_ns, values)

    def current_ns(self) -> int:
        return self.gate.expected if self.gate is not None else 0

    def adopt_run(self, run_id: str) -> None:
        """Follow the time master's run ``run_id``: the lock-step messages of that run verify."""
        if run_id != self.run_id:
            self.protocol.run_id = run_id
            self.signing.set_run(run_id)
            if run_id:
                self.on_run_adopted()
                self.signing.drain()

    def on_run_adopted(self) -> None:
        """Act on following a run from now on (a hook)."""

    def on_run_running(self) -> None:
        """Act on the followed run running, once (a hook: initial estimates, docs/architecture)."""

    def go_realtime(self) -> None:
        """Ask the process hosting this node alone for real-time scheduling (free_run)."""
        if self.host is not None:
            self.host.enter_realtime(self)

    def follow_master(self, state: str, run: str) -> bool:
        """Take a time master's event: choose the run to follow; tell whether it is of that run."""
        adopt, lock = self.protocol.master_event(state, run)
        if adopt is not None:
            self.adopt_run(adopt)
        if lock:
            self.lock_run()
        return bool(run) and run == self.run_id

    def lock_run(self) -> None:
        """Make the followed run final: what was kept for another run is refused now."""
        self.protocol.locked = True
        self.signing.drain()

    def on_peer_status(self, name: str, state: str, values: dict) -> None:
        """React to another node's event (the time master's: the run; a provider's end)."""
        p = self.protocol
        if is_master(values) and not self.time_master:
            run = values.get('run_id', '')
            if not self.follow_master(state, run):
                if p.first_foreign(run):
                    self.get_logger().warning(p.foreign_text(name, run))
                return
            free, first_running = p.followed(state, values)
            if free:    # at its 'waiting' already: a follower real-time only at 'running' was
                self.go_realtime()      # starved by another graph's loop, lost its first steps
            if state == RUNNING:
                self.free_run = free
                if free and self.gate is not None:
                    self.gate.follow = True
                if first_running:
                    self.on_run_running()
        if not self.done:
            end = p.end_of_part(name, state, values, self.state, not self.critical or (
                self.gate is not None and self.gate.follow), self.critical)
            if end is not None:
                self.end_run(*end)

    def end_run(self, reason: str, notify: bool = False) -> None:
        """End this node's part of the run (not a failure of this node)."""
        if not self.done:
            self.get_logger().info(reason)
            if notify:
                self.status(STOPPED, reason=reason)
            self.finish()

    # Start-up and watchdog -------------------------------------------------------------------
    def start_protocol(self, input_timeout: float, startup_timeout: float) -> None:
        """Announce ``waiting``; go ``ready`` once every input has a publisher; watch inputs."""
        self.watchdog = InputWatchdog(input_timeout, startup_timeout)
        self.readiness = Readiness(startup_timeout, time.monotonic())
        self.state = WAITING
        self.create_timer(WATCHDOG_TICK_S, self._tick,
                          clock=Clock(clock_type=ClockType.STEADY_TIME))
        self._tick()

    def _tick(self) -> None:
        if self.done:
            return
        if self.state == WAITING:
            self._check_ready()
        elif self.state == FINISHING:
            if self.watchdog.finish_over(time.monotonic()):
                self.end_run(self.watchdog.finish_text(self.last_step))
        else:
            self.check_inputs()
            self.check_publishers()

    def _check_ready(self) -> None:
        r, now = self.readiness, time.monotonic()
        missing = [t for t in self.inputs if self.count_publishers(t) == 0]
        if r.announce(missing):         # tell the time master what this node waits for
            self.status(WAITING, waiting_for=' '.join(missing))
        if not missing and (self.time_master or self.run_id) and self.ready_to_start():
            self.protocol.providers = providers(self.inputs, lambda t: (
                i.node_name for i in self.get_publishers_info_by_topic(t)))
            self.check_publishers(now=now + 1.0)
            self.on_ready()
        elif r.over(now):
            self.fail(f'not started within {r.startup_timeout:.1f} s: '
                      + self.waiting_text(missing))
        elif r.log_due(now):
            self.get_logger().info(f'waiting ({r.waited(now):.0f} s): '
                                   + self.waiting_text(missing))

    def waiting_text(self, missing: List[str]) -> str:
        return waiting_text(missing, self.time_master, self.run_id)

    def ready_to_start(self) -> bool:
        return True

    def on_ready(self) -> None:
        """Say ``ready``, with the lock-step topics this node publishes (a follower waits on)."""
        self.watchdog.since = time.monotonic()
        self.status(READY, publishes=' '.join(p.topic_name for p in self.publishers
                                              if p.topic_name in LOCKSTEP_TOPICS))

    def check_inputs(self) -> None:
        """Watchdog of an exact gate: a critical input missing for ``input_timeout`` is a fault."""
        g = self.gate
        if g is None or g.follow:
            return
        limit = self.watchdog.stalled(self.state, g.since, time.monotonic(), self.time_master)
        if limit is not None:
            missing = g.missing()
            gone = [t for t in missing if self.count_publishers(t) == 0]
            busy = [t for t in LOCKSTEP_TOPICS if self.count_publishers(t) > 1]
            self.fail(stall_text(missing, gone, g.expected, g.step(), limit,
                                 crosstalk_text(busy, self.context.get_domain_id())))

    # Who may publish -------------------------------------------------------------------------
    def foreign_publishers(self, topic: str) -> List[str]:
        """Return the publishers of ``topic`` (graph API) not allowed on it, as '/ns/name'."""
        return self.watch.outsiders(topic, self.get_publishers_info_by_topic(topic))

    def check_publishers(self, now: Optional[float] = None) -> None:
        """Report (log, /im/status) each publisher of an input or /clock not allowed, once."""
        if not self.watch.due(time.monotonic() if now is None else now):
            return
        for t in self.inputs + ([] if self.time_master else [CLOCK]):
            for node, text in self.watch.new_foreign(t, self.foreign_publishers(t), t == CLOCK):
                self.get_logger().error(text)
                self.status(WARNING, level=1, reason=text, topic=t, foreign_node=node)

    def unsigned_input(self, topic: str, data: bytes, handler: Callable) -> None:
        """Keep ``data`` (not of the run followed) for a run to come, bounded; else refuse it."""
        refused = self.signing.unsigned(topic, data, handler, self.protocol, self.time_master)
        if refused is not None:
            self.refuse_unsigned(*refused)

    def refuse_unsigned(self, topic: str, data: bytes) -> None:
        """Refuse and count a message without this graph's tag for this run (cheap: a flood)."""
        self.refused_by_topic[topic] = self.refused_by_topic.get(topic, 0) + 1
        now = time.monotonic()
        if self.watch.after_refusal(now):
            self.check_publishers(now)
        if not logs_refusal(self.refused + 1):      # counted; refuse() logs only these
            self.refused += 1
            return
        self.refuse(topic, header_stamp(data), self.watch.unsigned_text(topic, self.run_id))

    # The step --------------------------------------------------------------------------------
    def gate_input(self, topic: str, extract: Callable, take: Optional[Callable] = None,
                   hold=None) -> None:
        """Subscribe to input ``topic``: the one path of every input (:func:`input_handler`)."""
        from geometry_msgs.msg import Vector3Stamped
        from sensor_msgs.msg import JointState
        self.inputs.append(topic)
        cls = JointState if TOPIC_TYPES[topic] == JS else Vector3Stamped
        self.create_subscription(cls, topic, input_handler(self, topic, extract, take, hold),
                                 reader(topic), raw=True)

    def on_incomplete(self, topic: str, ns: int) -> None:
        """Act on ``topic`` stamped ``ns`` completing no step of a follow gate (a hook)."""

    def refuse(self, topic: str, ns: Optional[int], reason: str) -> None:
        """Count and log an input that is refused (the node keeps running)."""
        self.refused += 1
        if logs_refusal(self.refused):
            where = f' stamped {stamp_text(ns)}' if ns is not None else ''
            self.get_logger().error(f'refused {topic}{where}: {reason} (refused so far: '
                                    f'{self.refused})')

    def ready(self, inputs) -> None:
        """Run the step loop of every node: ``inputs``, then each next step already complete."""
        gate, hold_step, step = self.gate, self.hold_step, self.step
        # no step at or past the run's end: a gate lagged by the delay completes step last_step
        # (its measurement and the command of last_step - d), which no node computes
        end = None if self.last_step is None else self.last_step * self.period
        while inputs is not None and not self.done:
            if end is not None and gate.expected >= end:
                return
            if hold_step(inputs):
                return
            if self.state != RUNNING and self.state != FINISHING:
                self.state = RUNNING
            step(inputs)
            if self.done or self.state != RUNNING:
                return
            inputs = gate.advance()

    def hold_step(self, inputs) -> bool:
        """Tell whether to keep the complete step for later (a hook; resumed by :meth:`ready`)."""
        return False

    def step(self, inputs: dict) -> None:  # pragma: no cover - each node defines it
        """Compute the step stamped ``self.gate.expected`` from its inputs (topic -> value)."""
        raise NotImplementedError

    def reached_last_step(self) -> None:
        """Note that this node computed its last step: wait for the plant to confirm the end."""
        self.state = FINISHING
        self.watchdog.since = time.monotonic()
        if self.master_state in END_STATES:
            self.end_run('finished')

    def fail(self, reason: str, **values) -> None:
        self.get_logger().error(reason)
        self.failure, self.exit_code = reason, 1
        self.status(FAILED, level=2, reason=reason, **values)
        self.finish()

    def finish(self, **values) -> None:
        self.done = True
        if self.on_stop is not None:
            self.on_stop(self)
