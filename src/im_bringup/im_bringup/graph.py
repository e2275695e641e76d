"""
The four drive nodes spun in one process, on a context of their own, in lock-step.

:class:`DriveGraph` is what the scenario runner, the benchmarks and the integration tests use; it
is also the reusable piece for users' own integration tests (see :mod:`im_bringup.testing` for the
pytest fixture). Each graph owns its ``Context``; its DDS domain is ``ROS_DOMAIN_ID``, as for every
ROS 2 tool (0 when unset), unless ``domain_id`` says otherwise. Several graphs at once — or several
test runs on one machine — need a domain each: the test fixtures give them one.

Recording in-process takes every message a node publishes from the node's own tap
(:attr:`im_common.lockstep.LockstepNode.tap`, called by its publishers after publishing) to the
recording's :class:`im_recording.session.RecordingSession` (the same the ``record`` node feeds:
the same metadata records) with its stamp, without an extra subscription on the hot path and
without changing rclpy's classes; the plant's run events and the run's nodes' parameters go to
it too. Each tapped topic is declared with the QoS profiles
its publishers offer, as the ROS graph reports them (``get_publishers_info_by_topic``, what
rosbag2's recorder and ``record`` store).
"""
from __future__ import annotations

import os
import threading
import time
from typing import Dict, Mapping, Optional

from im_adapt.adapter_node import AdapterNode
from im_bringup.config import run_nodes
from im_common.cli import status_line
from im_common.host import private_domain
from im_common.lockstep import build_node, make_executor
from im_common.step_gate import LOCKSTEP_DEPTH
from im_common.topics import STATUS
from im_controller.controller_node import ControllerNode
from im_observer.observer_node import ObserverNode
from im_plant.plant_node import PlantNode
from im_recording.bag import offered_qos_yaml
import rclpy
from rclpy.clock import Clock, ClockType
from rclpy.context import Context
from rclpy.parameter import Parameter
from rclpy.serialization import serialize_message
from rclpy.task import Future


def _overrides(values: Mapping[str, object]):
    return [Parameter(k, value=v) for k, v in values.items()]


def node_factories() -> Dict[str, object]:
    """Return the node class of each drive node name."""
    return {'plant': PlantNode, 'controller': ControllerNode, 'observer': ObserverNode,
            'adapter': AdapterNode}


def check_parameters(parameters: Mapping[str, Mapping[str, object]]) -> None:
    """
    Check the parameters of every drive node before any process of a graph is started.

    Build every drive node named in ``parameters`` once, with its parameters, on a private
    context that is shut down again, and raise the :class:`im_common.lockstep.ConfigurationError`
    of the first one that refuses them — what its own process would print — before any process
    of a graph is started (``scenario --processes``, the launch file).
    """
    factories = node_factories()
    ctx = Context()
    # args: no ROS arguments. Without them rcl reads this process's own command line — the
    # launch file's 'task:=speed' became "Found remap rule ... deprecated" warnings.
    rclpy.init(args=['check_parameters'], context=ctx, domain_id=private_domain())
    try:
        for name, values in parameters.items():
            if name in factories:
                build_node(factories[name], context=ctx, graph_key=bytes(32),
                           parameter_overrides=_overrides(values)).destroy_node()
    finally:
        rclpy.try_shutdown(context=ctx)


class DriveGraph:
    """
    Plant, controller, observer and adapter nodes in one process.

    Parameters
    ----------
    parameters : mapping node name -> {parameter: value}
        The same structure as a ROS 2 parameters YAML (``plant``, ``controller``, ``observer``,
        ``adapter``); see :func:`im_bringup.config.node_parameters`.
    nodes : which nodes to start (default: the run's, :func:`im_bringup.config.run_nodes`: the
        adapter only when the controller uses it, as for the processes of a run). Leaving one
        out exercises the missing-input path: the others report what they waited for and stop.
    recorder : optional sink with ``write(topic, payload)`` (an :class:`im_recording.traces.Tap`):
        every message a node publishes is handed to it (serialized).
    domain_id : DDS domain (default: ``ROS_DOMAIN_ID``, as rcl reads it; 0 when unset).
    graph_key : the key its nodes sign their messages with (default: a random one, in memory;
        ``docs/security.md``).

    """

    NODE_NAMES = ('plant', 'controller', 'observer', 'adapter')

    def __init__(self, parameters: Mapping[str, Mapping[str, object]],
                 nodes=None, recorder=None, domain_id: Optional[int] = None,
                 graph_key: Optional[bytes] = None):
        factories = node_factories()
        if nodes is None:
            nodes = run_nodes(parameters)
        self.context = Context()
        # closed by default (docs/security.md): discovery on this host unless the user chose
        os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
        # this graph's key, in memory only: its nodes accept each other's messages, nobody else's
        self.graph_key = os.urandom(32) if graph_key is None else graph_key
        rclpy.init(context=self.context,                # None: rcl reads ROS_DOMAIN_ID
                   **({} if domain_id is None else {'domain_id': int(domain_id)}))
        self.domain_id = self.context.get_domain_id()
        self.nodes: Dict[str, object] = {}
        self.parameters = parameters
        self.recorder = recorder
        self._stop = None
        self._failures: Dict[str, str] = {}
        try:
            for name in nodes:
                self.nodes[name] = build_node(       # refused: one ConfigurationError line
                    factories[name], context=self.context, graph_key=self.graph_key,
                    parameter_overrides=_overrides(parameters.get(name, {})))
            self.executor = make_executor(self.context)
            for n in self.nodes.values():
                self.executor.add_node(n)
            if recorder is not None:
                self._tap_publishers()
                if hasattr(recorder, 'flush_due') and self.nodes:
                    # durable recording: a chunk open for a second is on disk, run or stall
                    next(iter(self.nodes.values())).create_timer(
                        0.1, recorder.flush_due, clock=Clock(clock_type=ClockType.STEADY_TIME))
        except BaseException:
            self.close()
            raise
        self.wall_s = 0.0
        self.start_s = float('nan')                 # of the last run (see :meth:`run`)
        self.steps_per_s_running = float('nan')

    @property
    def plant(self):
        return self.nodes['plant']

    def _tap_publishers(self) -> None:
        rec = self.recorder
        tapped_topics = {}
        for node in self.nodes.values():
            for pub in list(node.publishers):
                topic = pub.topic_name
                if topic.startswith('/rosout') or topic.startswith('/parameter_events'):
                    continue
                tapped_topics.setdefault(topic, (node, pub.msg_type))
        topics = frozenset(tapped_topics)

        session = getattr(rec, 'session', None)
        master_event = None if session is None else self._master_events(session)

        def tap(topic, msg, _write=rec.write, _topics=topics):
            if topic in _topics:
                if not isinstance(msg, bytes):     # status events: rare, not on the hot path
                    if master_event is not None and topic == STATUS:
                        master_event(msg)
                    msg = serialize_message(msg)
                _write(topic, msg)
        for node in self.nodes.values():        # the nodes' own hook (LockstepNode.tap)
            node.tap = tap
        writer = getattr(rec, 'writer', None)
        if writer is not None:
            self._declare_offers(writer, tapped_topics)
            plant = self.nodes.get('plant')
            if plant is not None and hasattr(writer, 'set_reorder_window'):
                # log-time order: in one process the observer's x̂_{k+1} comes before step k+1
                writer.set_reorder_window(LOCKSTEP_DEPTH * plant.period)
        if session is not None:
            self._record_parameters(session)
        # The observer and adapter publish their initial estimates when they adopt the run,
        # through these tapped publishers; the plant publishes step 0 when the run starts.

    def _master_events(self, session):
        """
        Return the tap's hook that hands the plant's run events to the recording session.

        The session learns the run's period, its first step and its end as the recorder node
        does from ``/im/status``; here from the start (the tap is there before the first step).
        """
        plant = self.nodes.get('plant')
        if plant is not None:
            session.period = plant.period
        master = None if plant is None else plant.get_name()

        def master_event(msg) -> None:
            for st in msg.status:
                if st.name == master:
                    session.master_event(st.message, {kv.key: kv.value for kv in st.values},
                                         counted=True, node=master)
        return master_event

    def _record_parameters(self, session) -> None:
        """
        Record the parameters of the run's nodes (every one, defaults included).

        The run's nodes: :func:`im_bringup.config.run_nodes` (not the adapter when it is off,
        as no adapter process is started then).
        """
        for name in run_nodes(self.parameters):
            node = self.nodes.get(name)
            if node is not None:
                session.add_parameters(name, {p: node.get_parameter(p).value
                                              for p in node.list_parameters([], 0).names})

    def _declare_offers(self, writer, topics) -> None:
        """
        Declare each tapped topic with the profiles this graph's publishers offer.

        One per publisher; the graph's own endpoints are known at once, no discovery needed.
        """
        ours = {(n.get_name(), n.get_namespace()) for n in self.nodes.values()}
        for topic, (node, cls) in topics.items():
            infos = [i for i in node.get_publishers_info_by_topic(topic)
                     if (i.node_name, i.node_namespace) in ours]
            expected = sum(1 for n in self.nodes.values() for p in n.publishers
                           if p.topic_name == topic)
            if len(infos) != expected:
                raise RuntimeError(f"{topic}: the ROS graph lists {len(infos)} of this graph's "
                                   f'{expected} publishers; cannot record their QoS')
            type_name = f"{cls.__module__.split('.')[0]}/msg/{cls.__name__}"
            writer.add_topic(topic, type_name, qos=offered_qos_yaml(i.qos_profile for i in infos))

    def _stopped(self, node) -> None:
        """End the run when the plant is done or a node failed (a node finished or failed)."""
        if (node.exit_code or node is self.nodes.get('plant')) and not self._stop.done():
            self._stop.set_result(node.get_name())

    def fail(self, name: str, reason: str) -> None:
        """
        End the run because a part of it that is not a node failed.

        The in-process recorder, say, whose file cannot be written: the run ends as when a node
        fails, ``failures[name] = reason``.
        """
        self._failures[name] = reason
        if self._stop is not None and not self._stop.done():
            self._stop.set_result(name)

    def run(self, progress: bool = False, wall_limit: Optional[float] = None,
            stop=None) -> dict:
        """
        Spin until the run ends; return run statistics.

        The run ends when the plant reached its duration, a node failed, ``wall_limit`` [s]
        passed (a failure: ``failures['graph']``) or ``stop`` (a
        :class:`~im_common.stopping.StopSignals`) was requested.

        The executor runs natively (``spin_until_future_complete``) in slices of 0.1 s between
        which progress is printed and the stop flag checked; after a failure the others get up to
        a second to report theirs.

        The statistics: ``steps``, ``wall_s`` and ``steps_per_s`` (from the call, the run
        protocol's start-up included), ``ok`` and ``failures``. The graph keeps ``start_s``
        (wall time until the plant's first step) and ``steps_per_s_running`` (the rate from that
        step on, as the plant reports it; the benchmarks' figure).
        """
        nodes = list(self.nodes.values())
        self._stop = Future()
        for n in nodes:
            n.on_stop = self._stopped
            if n.done:
                self._stopped(n)
        plant = self.nodes.get('plant')
        if plant is None:      # nothing ends the run but failures
            wall_limit = wall_limit or 60.0
        t0 = time.perf_counter()
        k0 = plant.sim.k if plant is not None else 0
        failures = self._failures = {}
        self._spin(plant, t0, k0, progress, wall_limit, stop, failures)
        t_end = time.perf_counter()
        self.wall_s = t_end - t0
        first = getattr(plant, 'wall_start', None)     # the plant's first step (lock-step)
        if any(n.exit_code for n in nodes) or self.recorder is not None:
            # after a failure the others get up to a second to report theirs; after the plant's
            # end the followers compute and publish their last step (the observer's estimate
            # of the final step), which a recording holds as the recorder node's does
            t_fail = time.perf_counter()
            while not all(n.done for n in nodes) and time.perf_counter() - t_fail < 1.0:
                self.executor.spin_once(timeout_sec=0.05)
        if progress:
            status_line('', done=True)
        steps = (plant.sim.k - k0) if plant is not None else 0
        failures.update({name: n.failure for name, n in self.nodes.items() if n.exit_code})
        stats = {'steps': steps, 'wall_s': self.wall_s,
                 'steps_per_s': steps / self.wall_s if self.wall_s > 0 else float('nan'),
                 'failures': failures, 'ok': not failures}
        if first is not None and t_end > first and steps:
            # start-up (the run protocol's handshake) apart from the rate of the steps, which the
            # plant's own report and the benchmarks give
            self.start_s = first - t0
            self.steps_per_s_running = steps / (t_end - first)
        refused = {name: getattr(n, 'refused', 0) for name, n in self.nodes.items()}
        if any(refused.values()):
            stats['refused_inputs'] = refused
        unsigned = {name: dict(n.refused_by_topic) for name, n in self.nodes.items()
                    if n.refused_by_topic}
        if unsigned:        # messages not signed by this graph: counted, their publishers named
            stats['refused_unsigned'] = unsigned
            stats['foreign_publishers'] = {
                name: {t: sorted(v) for t, v in n.foreign.items() if v}
                for name, n in self.nodes.items() if any(n.foreign.values())}
        return stats

    def _spin(self, plant, t0, k0, progress, wall_limit, stop, failures) -> None:
        """
        Spin natively until the stop future completes.

        The EventsExecutor does not return from ``spin_until_future_complete`` while events
        keep coming, so a watcher thread prints progress and completes the future on a stop
        request or at the wall-clock limit.
        """
        total = plant.last_step if plant is not None else None
        quit_watch = threading.Event()

        def watch():
            last_print = 0.0
            while not quit_watch.wait(0.05):
                now = time.perf_counter()
                reason = None
                if stop is not None and stop.requested:
                    reason = f'stop signal {stop.requested}'
                elif wall_limit is not None and now - t0 > wall_limit:
                    failures['graph'] = reason = f'wall-clock limit of {wall_limit} s reached'
                if reason is not None:
                    if not self._stop.done():
                        self._stop.set_result(reason)
                    return
                if progress and plant is not None and now - last_print >= 0.5:
                    last_print = now
                    k = plant.sim.k
                    frac = f'{100.0 * k / total:5.1f} %' if total else ''
                    status_line(f'  t = {k * plant.T_s:8.4f} s  step {k}  {frac}  '
                                f'{(k - k0) / (now - t0):8.0f} steps/s')
        watcher = threading.Thread(target=watch, name='graph-watch', daemon=True)
        watcher.start()
        try:
            while not self._stop.done() and rclpy.ok(context=self.context):
                self.executor.spin_until_future_complete(self._stop, timeout_sec=0.5)
        finally:
            quit_watch.set()
            watcher.join()

    def close(self) -> None:
        for n in getattr(self, 'nodes', {}).values():
            try:
                n.destroy_node()
            except Exception:  # noqa: BLE001 - teardown must go on
                pass
        ex = getattr(self, 'executor', None)
        if ex is not None:
            ex.shutdown()
        rclpy.try_shutdown(context=self.context)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
