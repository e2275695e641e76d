"""
The lock-step helper shared by every node: step gate, run protocol, watchdog, and ``main``.

Step protocol (``docs/architecture.md``): step k is
  plant publishes measurements stamped t_k → controller computes V_k once it holds every input
  stamped t_k → plant integrates [t_k, t_k+1] with V_k held while the observer predicts x̂_{k+1}
  and the adapter updates p̂_{k+1} from the same step's data, both stamped t_k+1.
Two topic hops per step on the critical path. Every node computes from inputs identified by their
stamps, never by arrival order, so the same run gives the same numbers whatever the scheduling.

The node is a composition of small parts, each in its own module and unit-tested without ROS:
- :class:`im_common.step_gate.StepGate`: a step's inputs collected by stamp, when a step is
  complete, the steps a follower lost;
- :class:`im_common.run_protocol.RunProtocol`: which run the node follows, which events concern
  it, when its part of the run is over (the protocol itself is described there);
- :class:`im_common.signing.NodeSigning`: the tags of its messages and events (keys and tags:
  :mod:`im_common.auth`), and the messages kept for a run not adopted yet.
:class:`LockstepNode` wires them to rclpy (publishers, subscriptions, the watchdog timer, the log)
and runs the step loop once for every node (:meth:`LockstepNode.ready`): a node shell declares its
inputs and computes one step (:meth:`LockstepNode.step`).
"""
from __future__ import annotations

import difflib
import faulthandler
import sys
import time
from typing import Callable, Dict, List, Optional, Sequence

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
import rclpy
from rclpy.clock import Clock, ClockType
from rclpy.duration import Duration
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from . import auth, realtime
from .cli import error as cli_error
from .conversions import NS_PER_S
from .params import parameter_error
from .run_protocol import (END_STATES, FAILED, FINISHED, FINISHING, is_master,  # noqa: F401
                           NOT_STATES, PARAMETERS, READY, RUNNING, RunProtocol, STOPPED, STOPPING,
                           WaitClock, WAITING, WARNING, watchdog_limit)
from .signing import allowed_publishers, foreign_publishers, NodeSigning
from .step_gate import finite, LOCKSTEP_DEPTH, StepGate
from .stopping import StopSignals

#: Reader history of /im/status (events of every node on the domain while this one starts).
STATUS_READER_DEPTH = 1000

#: History of the lock-step topics (publishers and readers). Deeper is not safer: a reliable
#: writer resends its whole backlog to a reader that lags, from the loop's real-time threads in
#: free_run. Tried with 1000: two free_run graphs on one domain under heavy machine load froze in
#: 2 of 3 runs (a middleware thread of a plant at SCHED_FIFO 50 at 90 % of a core for minutes; its
#: clock thread never ran again). In lock-step the follower window keeps
#: every reader within ``LOCKSTEP_DEPTH // 2`` steps.
LOCKSTEP_HISTORY = LOCKSTEP_DEPTH
#: History of a node's lock-step *readers*: the samples of every writer on a topic share it, so
#: another graph on the domain (or a rogue) that delivers more than a history's worth between two
#: takes of a busy node — its writers' transient-local backlog replayed at a late discovery, or
#: its own run while this node is starved — pushed this graph's untaken sample out, and a
#: lock-step run stalled (docs/security.md). Ten writer histories deep; the writers keep 100, so
#: no writer resends more than before.
LOCKSTEP_READER_HISTORY = 10 * LOCKSTEP_DEPTH

#: Period of a node's watchdog tick [s] (start-up, input timeouts: :class:`WaitClock`).
WATCHDOG_TICK_S = 0.1

#: On exit, how long a node waits at most until its readers acknowledged its last samples [s].
STOP_FLUSH_S = 3.0
#: After its run, how long a node process may take to flush and tear down before it is ended
#: with every thread's stack on stderr and exit code 1 [s]. The flushes are bounded (2 s + 3 s);
#: the middleware's teardown is not: once (a full test run on 2026-11-26, not reproduced in 80
#: runs of the same test alone) an observer whose run had finished did not exit in 120 s.
EXIT_GRACE_S = 20.0


def lockstep_qos(depth: int = LOCKSTEP_HISTORY) -> QoSProfile:
    """Reliable, transient-local, keep-last: a late-joining node still gets the step it needs."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)


def data_qos(depth: int = 100) -> QoSProfile:
    """Reliable, volatile: what a subscriber takes when any publisher must match (setpoints)."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)


#: History of the report topics' writers (ground truth, references, the observer's current): a
#: recorder matched late still gets the last ``REPORT_HISTORY`` reports, ten times the steps at the
#: default decimation — more than the plant may run ahead of a lossless follower.
REPORT_HISTORY = LOCKSTEP_DEPTH


def report_qos(depth: int = REPORT_HISTORY) -> QoSProfile:
    """
    Return the QoS of the report topics: reliable, transient-local, keep-last.

    A recorder matched with a report writer after its first samples still records them: matching
    is per writer, so a recorder's readiness (it has matched the run's lock-step writers) does not
    prove it has matched every report writer — with another graph on the domain it may have seen
    that graph's writers only, and a volatile report of the first steps was lost (the bag lacked
    the references of steps 0, 10 and 20 in one of two runs of two launches on one domain).
    """
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)


def probe_qos() -> QoSProfile:
    """Return the QoS of free_run's pre-flight probe and its echoes: reliable, volatile."""
    return data_qos(PROBE_HISTORY)


#: History of the probe topics: the probes of one pre-flight (``im_common.timing``) and more.
PROBE_HISTORY = 500


def status_qos(depth: int = 20) -> QoSProfile:
    """
    Return the QoS of the run-protocol events: reliable and transient-local.

    A node that starts late sees them. Readers ask for a deeper history
    (:data:`STATUS_READER_DEPTH`): while a node is still starting, the events of every node on the
    domain (another graph's too) queue up, and the time master's one ``waiting`` must not be pushed
    out by them.
    """
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)


def describe(description: str, lo=None, hi=None, read_only: bool = False, integer: bool = False,
             step=None) -> ParameterDescriptor:
    d = ParameterDescriptor(description=description, read_only=read_only)
    if lo is not None and hi is not None:
        if integer:
            d.integer_range = [IntegerRange(from_value=int(lo), to_value=int(hi),
                                            step=int(step or 1))]
        else:
            d.floating_point_range = [FloatingPointRange(from_value=float(lo), to_value=float(hi),
                                                         step=float(step or 0.0))]
    return d


class ConfigurationError(ValueError):
    """
    A node refuses its configuration (a parameter unknown, of the wrong type or out of range).

    The message is the one line every path prints (:func:`build_node`).
    """


def build_node(factory: Callable[..., 'LockstepNode'], **kwargs) -> 'LockstepNode':
    """
    Construct a drive node and check its configuration.

    Checked: every declared parameter's type and range (:meth:`LockstepNode.param`) and no
    parameter given that it does not declare (:meth:`LockstepNode.check_overrides`). A node
    executable (:func:`node_main`), the in-process graph and the check a supervisor makes before
    starting processes all build nodes here, so a configuration is refused with the same
    :class:`ConfigurationError` line on every path.
    """
    node = None
    try:
        node = factory(**kwargs)
        node.check_overrides()
        return node
    except (ValueError, rclpy.exceptions.ParameterException) as exc:
        if node is not None:
            node.destroy_node()
        raise ConfigurationError(str(exc).splitlines()[0]) from None


def stamp_text(ns: int) -> str:
    return f'{ns / NS_PER_S:.9f} s'


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
    Base of the drive nodes: parameters with descriptors, the run protocol, the watchdog.

    A subclass sets ``self.gate`` (a :class:`StepGate`), declares its gate inputs with
    :meth:`gate_input`, implements :meth:`step` (one complete step's computation) and calls
    :meth:`start_protocol` at the end of its ``__init__``. ``critical`` nodes (the default) use an
    exact gate and a watchdog in lock-step; ``critical = False`` nodes follow. The parts it
    composes: ``self.gate``, ``self.protocol`` (:class:`RunProtocol`) and ``self.signing``
    (:class:`NodeSigning`).
    """

    critical = True
    time_master = False
    #: Moves to SCHED_FIFO in free_run when it runs as its own process (not the recorder).
    realtime_capable = True
    #: Default of ``rt_priority`` (the recorder's is below the loop's).
    default_rt_priority = realtime.DEFAULT_PRIORITY
    #: ``tap(topic, msg)`` receives every message this node publishes (serialized or a message
    #: object), after it was published; None: none (an in-process recorder sets it)
    tap = None

    def create_publisher(self, *args, **kwargs) -> TappedPublisher:
        """Create the rclpy publisher, returned with the node's recording tap on it."""
        return TappedPublisher(super().create_publisher(*args, **kwargs), self)

    def __init__(self, name: str, graph_key: Optional[bytes] = None, **kwargs):
        super().__init__(name, **kwargs)
        self.done = False
        self.exit_code = 0
        self.failure: Optional[str] = None
        self.gate: Optional[StepGate] = None
        self.state = 'starting'
        self.period = 0
        self.last_step: Optional[int] = None
        self.inputs: List[str] = []
        self.protocol = RunProtocol()
        self.free_run = False
        self._foreign_said = False
        self._running_run = ''              # the run on_run_running was called for
        self._publishers_checked = 0.0
        self._refused_asked = 0.0
        self._reported_publishers: set = set()
        self._timeout = 5.0
        self._startup_timeout = 30.0
        self._since = time.monotonic()
        self._last_wait_log = 0.0
        self._watchdog = None
        self._wait_clock = WaitClock(WATCHDOG_TICK_S)    # the input watchdog's time
        self.on_stop: Optional[Callable[['LockstepNode'], None]] = None   # set by a graph
        #: Key/values in every event of this node (the plant: its ``mode``).
        self.event_context: Dict[str, str] = {}
        self.own_process = False      # set by node_main: real-time scheduling is this process's
        self.scheduling = 'normal'
        self.refused_by_topic: Dict[str, int] = {}
        self.foreign: Dict[str, set] = {}           # topic -> foreign publishers seen on it
        self._foreign_status_said: set = set()
        self.rt_priority = self.param(
            'rt_priority', self.default_rt_priority,
            'free_run, this node as its own process: SCHED_FIFO priority of its threads (0: '
            'ordinary scheduling); needs root, CAP_SYS_NICE or an rtprio limit', 0, 99)
        key_file = self.param(
            'graph_key_file', '',
            "file holding the graph's key (empty: $IM_GRAPH_KEY_FILE, else "
            '$ROS_HOME/im_drive/graph.key, created on first use); see docs/security.md')
        self.allowed = self._allowed_publishers(self.param(
            'allowed_publishers', '',
            "publishers allowed on this node's inputs besides the topic table's: space-separated "
            'topic=node items (e.g. /im/command/voltage=/ctl2)'))
        if graph_key is None:
            path = key_file or auth.default_key_file()
            graph_key = auth.read_key_file(path, create=not key_file)
        self.signing = NodeSigning(graph_key, _status_topic(), self.EARLY_MAX,
                                   self.EARLY_KEEP_NEWEST)
        self.signer = self.signing.signer               # the followed run's (set_run in place)
        self.status_signer = self.signing.status_signer
        from diagnostic_msgs.msg import DiagnosticArray
        self._status_pub = self.create_publisher(DiagnosticArray, _status_topic(), status_qos())
        self.create_subscription(DiagnosticArray, _status_topic(), self._on_status,
                                 status_qos(STATUS_READER_DEPTH))
        if not self.time_master:
            from std_msgs.msg import Header
            from .topics import PROBE, PROBE_ECHO
            self._echo_pub = self.create_publisher(Header, PROBE_ECHO, probe_qos())
            self.create_subscription(Header, PROBE, self.echo_probe, probe_qos())

    @property
    def run_id(self) -> str:
        """Return the time master's run this node follows ('' until it has seen one)."""
        return self.protocol.run_id

    @run_id.setter
    def run_id(self, run_id: str) -> None:
        self.protocol.run_id = run_id

    @property
    def peers(self) -> Dict[str, tuple]:
        """Return node name -> (state, values) of its last event in the run followed."""
        return self.protocol.peers

    @property
    def providers(self) -> Dict[str, str]:
        """Return publisher node name -> one topic of this node's inputs it provides."""
        return self.protocol.providers

    @property
    def master_state(self) -> str:
        """Return the last state of the time master (plant) of the run followed."""
        return self.protocol.master_state

    # Parameters -----------------------------------------------------------------------
    def param(self, name: str, default, description: str, lo=None, hi=None, read_only: bool = True,
              choices: Optional[Sequence[str]] = None):
        """Declare a parameter with a descriptor and return its value (validated)."""
        integer = isinstance(default, int) and not isinstance(default, bool)
        desc = describe(description + (f' (one of: {", ".join(choices)})' if choices else ''),
                        lo, hi, read_only=read_only, integer=integer)
        given = getattr(self, '_parameter_overrides', {}).get(name)
        if given is not None:       # one line naming node and parameter (docs/architecture.md)
            bad = parameter_error(given.value, default, lo, hi)
            if bad:
                raise ConfigurationError(f"invalid parameter '{name}' = {given.value!r} for node "
                                         f"'{self.get_name()}': {bad}")
        value = self.declare_parameter(name, default, desc).value
        if choices is not None and value not in choices:
            raise ConfigurationError(f"invalid parameter '{name}' = {value!r} for node "
                                     f"'{self.get_name()}': must be one of {', '.join(choices)}")
        return value

    def check_overrides(self) -> None:
        """
        Refuse parameters given for this node (YAML, ``-p``) that it does not declare.

        The error names the nearest valid one: a misspelt gain must not silently fall back to its
        default.
        """
        declared = set(self.list_parameters([], 0).names)
        unknown = sorted(n for n in getattr(self, '_parameter_overrides', {}) if n not in declared
                         and not n.startswith('qos_overrides.'))
        if unknown:
            name = unknown[0]
            near = difflib.get_close_matches(name, sorted(declared), n=1, cutoff=0.5)
            hint = f"; did you mean '{near[0]}'?" if near else ''
            also = f' (also unknown: {", ".join(unknown[1:])})' if unknown[1:] else ''
            raise ValueError(f"unknown parameter '{name}' for node '{self.get_name()}'{hint}"
                             + also)

    # Status ------------------------------------------------------------------------------
    def status(self, state: str, level: int = 0, stamp_ns: Optional[int] = None,
               **values) -> None:
        """Publish a run-protocol event on /im/status; keep it as this node's state."""
        from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
        if state not in NOT_STATES:
            self.state = state
        msg = DiagnosticArray()
        ns = self.current_ns() if stamp_ns is None else stamp_ns
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(int(ns), NS_PER_S)
        st = DiagnosticStatus(level=bytes([level]), name=self.get_name(), message=state,
                              hardware_id='im_drive')
        base = self.protocol.event_values(self.critical, self.time_master, self.period, ns,
                                          dict(self.event_context, **values))
        st.values = [KeyValue(key=str(k), value=str(v)) for k, v in base.items()]
        msg.status = [st]
        msg.header.frame_id = self.signing.status_tag(msg)
        try:
            self._status_pub.publish(msg)
        except Exception as exc:  # noqa: BLE001 - a closed context during shutdown: log, go on
            if rclpy.ok(context=self.context):
                raise
            self.get_logger().debug(f'status {state} not published: {exc}')

    def current_ns(self) -> int:
        return self.gate.expected if self.gate is not None else 0

    def _on_status(self, msg) -> None:
        if not self.signing.status_verifies(msg):
            self._foreign_status(msg)
            return
        own = self.get_name()
        for st in msg.status:
            values = {kv.key: kv.value for kv in st.values}
            if self.protocol.accept(own, st.name, st.message, values):
                self.on_peer_status(st.name, st.message, values)

    def _foreign_status(self, msg) -> None:
        """
        Report a run-protocol event not signed by this graph, once per sender; never act on it.

        The sender is another graph with its own key, or a rogue.
        """
        for st in msg.status:
            key = (st.name, st.message)
            if st.name in self._foreign_status_said or len(self._foreign_status_said) > 100:
                continue
            self._foreign_status_said.add(st.name)
            pubs = self.foreign_publishers(_status_topic())
            self.get_logger().warning(
                f"ignoring {_status_topic()} event '{key[1]}' from '{key[0]}': not signed by "
                f'this graph (another graph with its own key, or a foreign node'
                + (f"; publishers not of this graph: {', '.join(pubs)}" if pubs else '') + ')')

    def echo_probe(self, msg) -> None:
        """
        Send the time master's pre-flight probe straight back, named (free_run, before step 0).

        Only a probe of the run this node follows: the plant times the round trip through this
        node's executor (``im_common.timing.assess_probe``).
        """
        run = self.run_id
        if run and msg.frame_id == run:
            msg.frame_id = f'{run} {self.get_name()}'
            self._echo_pub.publish(msg)

    def adopt_run(self, run_id: str) -> None:
        """Follow the time master's run ``run_id``: the lock-step messages of that run verify."""
        if run_id == self.run_id:
            return
        self.protocol.run_id = run_id
        self.signing.set_run(run_id)
        if run_id:
            self.on_run_adopted()
            self._drain_early()

    def on_run_adopted(self) -> None:
        """Act on following a run from now on (a hook)."""

    def on_run_running(self) -> None:
        """
        Act on the followed run's time master running (a hook, once per run).

        Nodes publishing an initial estimate (stamped at the run's first step) do it here, signed
        for that run: not at adoption, when a lossless follower may not follow the run yet — it
        keeps a message it cannot verify yet among a bounded number of others, and another graph's
        flood on the domain pushed a run's x̂_0 out of a recorder's (the bag lacked
        /im/observer/flux stamped 0). The time master runs only once its followers are ready,
        i.e. follow the run.
        """

    def enter_realtime(self) -> None:
        """
        Enter free_run, as its own process: SCHED_FIFO for every thread of this process.

        If that fails, one warning says why (also on /im/status: the run then has no real-time
        guarantee).
        """
        if not self.own_process or not self.realtime_capable or self.scheduling != 'normal':
            return
        if self.rt_priority <= 0:
            self.get_logger().info('free_run with ordinary scheduling (rt_priority 0)')
            return
        ok, text = realtime.enter(self.rt_priority)
        if ok:
            realtime.quiet_gc()
            self.scheduling = text
            self.get_logger().info(f'free_run: real-time scheduling ({text})')
        else:
            self.scheduling = 'normal (refused)'
            msg = f'free_run without real-time scheduling: {text}; deadlines may be missed'
            self.get_logger().warning(msg)
            self.status(WARNING, level=1, reason=msg)

    def follow_master(self, state: str, run: str) -> bool:
        """
        Take a time master's event: choose the run to follow, tell whether the event belongs to it.

        The run followed is the one running, else the latest waiting to start.
        """
        adopt, lock = self.protocol.master_event(state, run)
        if adopt is not None:
            self.adopt_run(adopt)
        if lock:
            self.lock_run()
        return bool(run) and run == self.run_id

    def lock_run(self) -> None:
        """
        Make the followed run final.

        What was kept for another run and does not verify for this one is refused now.
        """
        self.protocol.locked = True
        self._drain_early()

    def on_peer_status(self, name: str, state: str, values: dict) -> None:
        """
        React to another node's event.

        The time master's end ends this node; a provider that stops or fails ends this node's part
        of the run.
        """
        master = is_master(values)
        if master and not self.time_master:
            run = values.get('run_id', '')
            if not self.follow_master(state, run):
                if self.run_id and run != self.run_id and not self._foreign_said:
                    self._foreign_said = True
                    self.get_logger().warning(
                        f"ignoring '{name}' of another run ({run}) on this ROS domain; this "
                        f'node follows run {self.run_id}')
                return
            self.protocol.master_state = state
            if values.get('mode') == 'free_run':
                # already at the time master's 'waiting': a node that became real-time only at
                # 'running' sat at ordinary priority while another graph's free_run loop (real-
                # time, on the same cores) starved it, and lost its own run's first steps from
                # its reader histories
                self.enter_realtime()
            if state == RUNNING:
                self.free_run = values.get('mode') == 'free_run'
                if self.free_run and self.gate is not None:
                    self.gate.follow = True
                if self._running_run != run:
                    self._running_run = run
                    self.on_run_running()
        if self.done:
            return
        following = not self.critical or (self.gate is not None and self.gate.follow)
        end = self.protocol.end_of_part(name, state, values, self.state, following,
                                        self.critical)
        if end is not None:
            self.end_run(*end)

    def end_run(self, reason: str, notify: bool = False) -> None:
        """End this node's part of the run (not a failure of this node)."""
        if self.done:
            return
        self.get_logger().info(reason)
        if notify:
            self.status(STOPPED, reason=reason)
        self.done = True
        if self.on_stop is not None:
            self.on_stop(self)

    # Protocol ----------------------------------------------------------------------------
    @property
    def input_timeout(self) -> float:
        """Return how long an input may stay silent before the node fails or drops it [s]."""
        return self._timeout

    def start_protocol(self, input_timeout: float, startup_timeout: float) -> None:
        """Announce ``waiting``; go ``ready`` once every input has a publisher; watch inputs."""
        self._timeout = float(input_timeout)
        self._startup_timeout = float(startup_timeout)
        self._since = time.monotonic()
        self._missing_said = None
        self.state = WAITING
        self._watchdog = self.create_timer(WATCHDOG_TICK_S, self._tick,
                                           clock=Clock(clock_type=ClockType.STEADY_TIME))
        self._tick()

    def _tick(self) -> None:
        if self.done:
            return
        if self.state == WAITING:
            self._check_ready()
        elif self.state == FINISHING:
            if time.monotonic() - self._since > max(self._timeout, 1.0):
                self.end_run(f'finished step {self.last_step - 1}; the plant did not confirm '
                             f'the end within {max(self._timeout, 1.0):.1f} s')
        else:
            self.check_inputs()
            self.check_publishers()

    # Who may publish ------------------------------------------------------------------------
    def _allowed_publishers(self, text: str) -> Dict[str, set]:
        """Return topic -> allowed publisher nodes ('/ns/name') (:func:`allowed_publishers`)."""
        return allowed_publishers(self.get_namespace(), text)

    def foreign_publishers(self, topic: str) -> List[str]:
        """Return the publishers of ``topic`` (graph API) not allowed on it, as '/ns/name'."""
        return foreign_publishers(self.allowed.get(topic),
                                  self.get_publishers_info_by_topic(topic))

    def check_publishers(self, now: Optional[float] = None) -> None:
        """
        Report publishers the allow-list does not name, about every second.

        Also before the first step: a publisher of an input (or of /clock) that the allow-list
        does not name is reported once (node, namespace, topic) on the log and
        on /im/status; its messages are refused anyway, since they do not carry this graph's tag
        (and /clock only sets ROS time, which no computation of the drive uses).
        """
        now = time.monotonic() if now is None else now
        if now - self._publishers_checked < 1.0:
            return
        self._publishers_checked = now
        from .topics import CLOCK
        watched = list(self.inputs) + ([] if self.time_master else [CLOCK])
        for t in watched:
            seen = self.foreign.setdefault(t, set())
            for node in self.foreign_publishers(t):
                if node in seen:
                    continue
                seen.add(node)
                effect = ('its messages are refused' if t != CLOCK else
                          'ignored: the drive computes on step stamps, never on ROS time')
                text = (f'foreign publisher {node} on {t} (allowed: '
                        f"{', '.join(sorted(self.allowed.get(t, ())))}): {effect}")
                self.get_logger().error(text)
                self.status(WARNING, level=1, reason=text, topic=t, foreign_node=node)

    #: Messages kept while this node does not yet follow a running run (they may be signed for
    #: the run it is about to follow): checked again when it adopts or locks a run.
    EARLY_MAX = 4 * LOCKSTEP_DEPTH
    #: When that buffer is full: False refuses the new message (a follower needs the first steps
    #: of its run, which come first); True refuses the oldest kept one instead (the recorder: it
    #: records contiguously from where it joined, so what it keeps must reach up to now).
    EARLY_KEEP_NEWEST = False

    def unsigned_input(self, topic: str, data: bytes, handler: Callable) -> None:
        """
        Keep or refuse ``data``, which does not verify for the run this node follows now.

        Before that run is running it may belong to the run this node is about to follow (kept,
        bounded, and handed to ``handler`` again when the run is adopted or starts:
        :meth:`NodeSigning.keep_early`); afterwards it is refused.
        """
        p = self.protocol
        refused = (topic, data)
        if not p.locked and not self.time_master:
            refused = self.signing.keep_early(topic, data, handler,
                                              p.other_live_runs() if p.masters else None)
        if refused is not None:
            self.refuse_unsigned(*refused)

    def _drain_early(self) -> None:
        for _topic, data, handler in self.signing.take_early():
            handler(data)

    def sign(self, topic: str, data: bytes) -> bytes:
        """Tag a lock-step message of this node for the run it follows."""
        return self.signing.sign(topic, data)

    def refuse_unsigned(self, topic: str, data: bytes) -> None:
        """
        Refuse and count a message without this graph's tag for this run.

        Its topic's foreign publishers are named (the graph API is asked at the first one, then at
        most 10 times a second). Cheap: another graph on the domain (its own key, the same node
        names) sends thousands a second, and a node that fell behind them would lose its own
        graph's samples from its reader history.
        """
        self.refused_by_topic[topic] = self.refused_by_topic.get(topic, 0) + 1
        now = time.monotonic()
        if now - self._refused_asked >= 0.1:
            self._refused_asked = now
            self._publishers_checked = 0.0
            self.check_publishers(now)
        n = getattr(self, 'refused', 0) + 1
        if n > 20 and n % 1000:             # counted; refuse() logs only these
            self.refused = n
            return
        try:
            ns = _U32x2.unpack_from(data, 4)
            ns = ns[0] * NS_PER_S + ns[1]
        except Exception:  # noqa: BLE001 - too short to hold a stamp
            ns = None
        pubs = sorted(self.foreign.get(topic, ()))
        who = (f"foreign publisher{'s' if len(pubs) > 1 else ''} on it: {', '.join(pubs)}"
               if pubs else 'its publisher uses an allowed name: another graph with its own '
               'key, or a node of an earlier run')
        self.refuse(topic, ns, f"not signed by this graph for run {self.run_id or '(none yet)'}"
                    f' ({who})')

    def missing_inputs(self) -> List[str]:
        return [t for t in self.inputs if self.count_publishers(t) == 0]

    def _check_ready(self) -> None:
        missing = self.missing_inputs()
        if missing != self._missing_said:      # tell the time master what this node waits for
            self._missing_said = missing
            self.status(WAITING, waiting_for=' '.join(missing))
        waited = time.monotonic() - self._since
        if not missing and not self.time_master and not self.run_id:
            missing_master = True
        else:
            missing_master = False
        if not missing and not missing_master and self.ready_to_start():
            providers = self.protocol.providers = {}
            for t in self.inputs:
                for n in sorted({i.node_name for i in self.get_publishers_info_by_topic(t)}):
                    providers.setdefault(n, t)
            self.check_publishers(now=time.monotonic() + 1.0)
            self.on_ready()
            return
        if waited > self._startup_timeout:
            self.fail(f'not started within {self._startup_timeout:.1f} s: '
                      + self.waiting_text(missing))
            return
        if waited - self._last_wait_log >= 2.0:
            self._last_wait_log = waited
            self.get_logger().info(f'waiting ({waited:.0f} s): {self.waiting_text(missing)}')

    def waiting_text(self, missing: List[str]) -> str:
        if missing:
            return 'no publisher yet of ' + ', '.join(missing)
        if not self.time_master and not self.run_id:
            return "no run-protocol event of a time master (plant) signed with this graph's key"
        return 'waiting'

    def ready_to_start(self) -> bool:
        return True

    def on_ready(self) -> None:
        self._since = time.monotonic()
        self.status(READY, publishes=' '.join(self.lockstep_outputs()))

    def lockstep_outputs(self) -> List[str]:
        """
        Return the lock-step topics this node publishes.

        Its ``ready`` says so: a lossless follower then knows which topics the run has and waits
        for each.
        """
        from .topics import LOCKSTEP_TOPICS
        return [p.topic_name for p in self.publishers if p.topic_name in LOCKSTEP_TOPICS]

    def check_inputs(self) -> None:
        """Watchdog of an exact gate: a critical input missing for ``input_timeout`` is a fault."""
        g = self.gate
        if g is None or g.follow or self.state != RUNNING and self.state != READY:
            return
        limit = watchdog_limit(self.state, self._timeout, self._startup_timeout,
                               self.time_master)
        if self._wait_clock.waited(g.since, time.monotonic()) > limit:
            missing = g.missing()
            gone = [t for t in missing if self.count_publishers(t) == 0]
            hint = (f' ({", ".join(gone)} no longer has a publisher)' if gone else '')
            hint += self.crosstalk_hint()
            self.fail(f"no {', '.join(missing)} stamped {stamp_text(g.expected)} "
                      f'(step {g.step()}) within {limit:.1f} s of wall time this process ran'
                      f'{hint}; stopping')

    def crosstalk_hint(self) -> str:
        """
        Name the lock-step topics with more than one publisher, or '' if there are none.

        More than one publisher means another graph on this domain.
        """
        from .topics import LOCKSTEP_TOPICS
        busy = [t for t in LOCKSTEP_TOPICS if self.count_publishers(t) > 1]
        if not busy:
            return ''
        return (f'; {", ".join(busy)} ha{"ve" if len(busy) > 1 else "s"} more than one publisher:'
                f' another graph is on this ROS domain (ROS_DOMAIN_ID='
                f'{self.context.get_domain_id()}) — give each graph its own')

    def gate_input(self, topic: str, extract: Callable) -> None:
        """
        Subscribe (serialized, lock-step QoS) to ``topic`` and feed the step gate.

        ``extract(data)`` = (stamp_ns, value) goes into the step gate; complete steps go to
        ``self.ready(inputs)``.
        A payload that cannot be decoded is refused with its topic and counted, never fatal.
        """
        from geometry_msgs.msg import Vector3Stamped
        from sensor_msgs.msg import JointState
        from .topics import JS, TOPIC_TYPES
        cls = JointState if TOPIC_TYPES[topic] == JS else Vector3Stamped
        self.inputs.append(topic)
        gate = self.gate
        ready = self.ready

        last_good = {}

        verify = self.signer.verify

        def on_data(data, topic=topic):
            if not verify(topic, data):
                self.unsigned_input(topic, data, on_data)
                return
            try:
                ns, value = extract(data)
            except (ValueError, KeyError, IndexError) as exc:
                self.refuse(topic, None, f'cannot decode: {exc}')
                return
            if not finite(value):
                held = last_good.get(topic)
                self.refuse(topic, ns, f'non-finite value {value!r}; '
                            + ('holding the previous one' if held is not None
                               else 'nothing to hold yet'))
                if held is None:
                    return
                value = held
            else:
                last_good[topic] = value
            inputs = gate.put(topic, ns, value)
            if inputs is not None:          # the step is complete
                ready(inputs)
            elif gate.follow:
                self.on_incomplete(topic, ns)
        self.create_subscription(cls, topic, on_data, lockstep_qos(LOCKSTEP_READER_HISTORY),
                                 raw=True)

    def on_incomplete(self, topic: str, ns: int) -> None:
        """
        Act on an input that completes no step of a follow gate (free_run).

        ``topic`` stamped ``ns`` arrived and no step is complete yet. The observer bridges
        a stalled loop here.
        """

    def refuse(self, topic: str, ns: Optional[int], reason: str) -> None:
        """Count and log an input that is refused (the node keeps running)."""
        self.refused = getattr(self, 'refused', 0) + 1
        where = f' stamped {stamp_text(ns)}' if ns is not None else ''
        if self.refused <= 20 or self.refused % 1000 == 0:
            self.get_logger().error(f'refused {topic}{where}: {reason} (refused so far: '
                                    f'{self.refused})')

    def ready(self, inputs) -> None:
        """
        Run the step loop, the one of every node.

        Compute the complete step ``inputs`` (its stamp is ``self.gate.expected``), then every
        following step whose inputs are already there, until one is incomplete, the node held a
        step back (:meth:`hold_step`), reached its last step, or is done.
        """
        gate = self.gate
        while inputs is not None and not self.done:
            if self.hold_step(inputs):
                return
            self.mark_started()
            self.step(inputs)
            if self.done or self.state != RUNNING:
                return
            inputs = gate.advance()

    def hold_step(self, inputs) -> bool:
        """
        Tell whether to keep the complete step ``inputs`` for later (a hook).

        True keeps them; the node resumes them by calling :meth:`ready` again; the plant holds
        while a lossless follower lags.
        """
        return False

    def step(self, inputs: dict) -> None:  # pragma: no cover - each node defines it
        """Compute the step stamped ``self.gate.expected`` from its inputs (topic -> value)."""
        raise NotImplementedError

    def mark_started(self) -> None:
        if self.state != RUNNING and self.state != FINISHING:
            self.state = RUNNING

    def reached_last_step(self) -> None:
        """Note that this node computed its last step: wait for the plant to confirm the end."""
        self.state = FINISHING
        self._since = time.monotonic()
        if self.master_state in END_STATES:
            self.end_run('finished')

    def fail(self, reason: str, **values) -> None:
        self.get_logger().error(reason)
        self.failure = reason
        self.exit_code = 1
        self.status(FAILED, level=2, reason=reason, **values)
        self.done = True
        if self.on_stop is not None:
            self.on_stop(self)

    def finish(self, **values) -> None:
        self.done = True
        if self.on_stop is not None:
            self.on_stop(self)

    def request_stop(self, signame: str) -> None:
        """
        Take a stop signal: say so on /im/status and end (exit code 0).

        The time master's stop ends the run (``stopped``); any other node's is news for the others
        (``stopping``).
        """
        if self.done:
            return
        where = f' at step {self.current_ns() // self.period}' if self.period else ''
        self.get_logger().info(f'{signame}: stopping' + (' the run' if self.time_master else '')
                               + where)
        self.status(STOPPED if self.time_master else STOPPING, level=1, reason=signame)
        self.done = True

    def flush(self, timeout: float = 2.0) -> None:
        """Wait (bounded) until every reliable publisher's data has been acknowledged."""
        deadline = time.monotonic() + timeout
        for pub in list(self.publishers):
            left = deadline - time.monotonic()
            if left <= 0:
                return
            try:
                pub.wait_for_all_acked(Duration(nanoseconds=int(left * 1e9)))
            except Exception:  # noqa: BLE001 - context already shut down: nothing to wait for
                return


_U32x2 = __import__('struct').Struct('<iI')


def _status_topic() -> str:
    from .topics import STATUS
    return STATUS


def make_executor(context=None):
    """Return an EventsExecutor (≈5× the SingleThreadedExecutor's message rate here)."""
    from rclpy.experimental import EventsExecutor
    return EventsExecutor(context=context)


def spin_until_done(nodes, executor, context=None, stop: Optional[StopSignals] = None) -> None:
    """
    Spin until every node in ``nodes`` is done, one failed, or a stop signal arrived.

    After a stop signal every node is asked to stop and spun a little longer so that it can say so.
    """
    while rclpy.ok(context=context):
        if any(n.exit_code for n in nodes) or all(n.done for n in nodes):
            return
        if stop is not None and stop.requested:
            for n in nodes:
                n.request_stop(stop.requested)
            return
        executor.spin_once(timeout_sec=0.05)


def _rcl_error():
    from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
    return _rclpy.RCLError


def init_args_error(args: List[str]) -> Optional[str]:
    """
    Return a readable line for a bad ``--params-file`` (missing, unreadable, malformed).

    That is before ``rclpy.init`` turns it into a traceback; None when the files look loadable. The
    file is read by :func:`im_common.yamlio.load_parameters_file`, as on every other path.
    """
    from im_common.yamlio import ParametersFileError, load_parameters_file
    for i, a in enumerate(args):
        if a == '--params-file':
            if i + 1 >= len(args):
                return '--params-file needs a file name'
            try:
                load_parameters_file(args[i + 1])
            except ParametersFileError as exc:
                return str(exc)
    return None


def node_main(factory: Callable[..., LockstepNode], argv=None) -> int:
    """
    Run a drive node (its ``main``): Jazzy shutdown idiom, stop signals, one-line errors.

    Exit codes: 0 finished or stopped (signal, or the run ended elsewhere), 1 failed, 2 refused
    configuration.
    """
    from rclpy.signals import SignalHandlerOptions
    args = list(sys.argv if argv is None else argv)
    user_args = args[1:args.index('--ros-args')] if '--ros-args' in args else args[1:]
    if '-h' in user_args or '--help' in user_args:
        return print_node_help(factory, args[0])
    prog = args[0].rsplit('/', 1)[-1]
    bad = init_args_error(args)
    if bad:
        return cli_error(prog, bad)
    with StopSignals() as stop:
        try:
            rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
        except _rcl_error() as exc:
            return cli_error(prog, str(exc).splitlines()[0])
        node = None
        code = 0
        try:
            try:
                node = build_node(factory)
                node.own_process = True         # free_run may make this process real-time
            except ConfigurationError as exc:
                return cli_error(prog, exc)
            executor = make_executor()
            executor.add_node(node)
            spin_until_done([node], executor, stop=stop)
            code = node.exit_code
            if not stop.requested:      # let the end of the run reach the others
                node.flush()
        except (KeyboardInterrupt, ExternalShutdownException):
            code = 0 if node is None or not node.exit_code else node.exit_code
        finally:
            # bounded from here on, and diagnosable: a C-level watchdog (no GIL needed) dumps
            # every thread's stack and exits 1 if the flush and teardown below hang
            faulthandler.dump_traceback_later(EXIT_GRACE_S, exit=True)
            try:
                if node is not None:
                    # a stopped node's last samples are still owed to the recorder, which the
                    # plant let lag up to follower_window steps: under load 1 s was not always
                    # enough
                    node.flush(timeout=STOP_FLUSH_S)
                    node.destroy_node()
                rclpy.try_shutdown()
            finally:
                faulthandler.cancel_dump_traceback_later()    # node_main may run in a caller
    return code


def parameter_table(node: Node) -> str:
    """Markdown table of a node's declared parameters (name, default, range, description)."""
    rows = ['| parameter | default | range | live | description |',
            '| --- | --- | --- | --- | --- |']
    for name in sorted(node.list_parameters([], 0).names):
        if name in ('use_sim_time', 'start_type_description_service'):
            continue
        d = node.describe_parameter(name)
        rng = ''
        if d.floating_point_range:
            r = d.floating_point_range[0]
            rng = f'[{r.from_value:g}, {r.to_value:g}]'
        elif d.integer_range:
            r = d.integer_range[0]
            rng = f'[{r.from_value}, {r.to_value}]'
        value = node.get_parameter(name).value
        live = '' if d.read_only else 'yes'
        rows.append(f'| `{name}` | `{value!r}` | {rng} | {live} | {d.description} |')
    return '\n'.join(rows)


def print_node_help(factory, prog: str) -> int:
    """``--help``: build the node in a private context and print its parameters."""
    import os
    import random
    from rclpy.context import Context
    ctx = Context()
    rclpy.init(args=[prog], context=ctx, domain_id=random.randint(150, 229))
    try:
        node = factory(context=ctx, graph_key=bytes(32))    # --help signs nothing
        print(f'usage: {os.path.basename(prog)} [--ros-args -p name:=value ... '
              f'--params-file FILE.yaml]\n')
        print((node.__doc__ or '').strip().splitlines()[0] if node.__doc__ else '')
        print(parameter_table(node))
        node.destroy_node()
    finally:
        rclpy.shutdown(context=ctx)
    return 0
