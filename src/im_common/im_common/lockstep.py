"""The lock-step helper shared by every node: step gate, watchdog, parameters, and ``main``.

Protocol (DESIGN.md §3): step k is
  plant publishes measurements stamped t_k → controller computes V_k once it holds every input
  stamped t_k → plant integrates [t_k, t_k+1] with V_k held while the observer predicts x̂_{k+1}
  and the adapter updates p̂_{k+1} from the same step's data, both stamped t_k+1.
Two topic hops per step on the critical path (measurement → command → next measurement; the
observer's and adapter's outputs travel in parallel with the plant's integration).

Every node computes from inputs identified by their stamps, never by arrival order, so the same run
gives the same numbers whatever the scheduling. A node waiting longer than ``input_timeout`` (wall
clock) for an input reports the topic and stamp it waited for and stops with a non-zero exit code.
"""
from __future__ import annotations

import sys
import time
from typing import Callable, Dict, Optional, Sequence

import rclpy
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.clock import Clock, ClockType
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from .conversions import NS_PER_S


def lockstep_qos(depth: int = 10) -> QoSProfile:
    """Reliable, transient-local, keep-last: a late-joining node still gets the step it needs."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)


def data_qos(depth: int = 100) -> QoSProfile:
    """Ground truth, references and other analysis topics: reliable, volatile."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)


class StepGate:
    """Collects the inputs of step k by stamp; ``put`` returns them once all have arrived.

    Inputs stamped before the expected step (replays of transient-local history) are ignored;
    inputs for later steps wait in ``pending`` until their step comes.
    """

    __slots__ = ('required', 'n', 'period', 'expected', 'pending', 'since')

    def __init__(self, required: Sequence[str], period_ns: int, first_ns: int = 0):
        self.required = tuple(required)
        self.n = len(self.required)
        self.period = int(period_ns)
        self.expected = int(first_ns)
        self.pending: Dict[int, dict] = {}
        self.since = time.monotonic()

    def put(self, topic: str, ns: int, value) -> Optional[dict]:
        if ns < self.expected:
            return None
        slot = self.pending.get(ns)
        if slot is None:
            slot = self.pending[ns] = {}
        slot[topic] = value
        if ns == self.expected and len(slot) == self.n:
            del self.pending[ns]
            return slot
        return None

    def advance(self) -> Optional[dict]:
        """Move to the next step; return its inputs if they are already complete."""
        self.expected += self.period
        self.since = time.monotonic()
        slot = self.pending.get(self.expected)
        if slot is not None and len(slot) == self.n:
            del self.pending[self.expected]
            return slot
        return None

    def missing(self) -> list:
        have = self.pending.get(self.expected, {})
        return [t for t in self.required if t not in have]


def describe(description: str, lo=None, hi=None, read_only: bool = False, integer: bool = False,
             step=None) -> ParameterDescriptor:
    d = ParameterDescriptor(description=description, read_only=read_only)
    if lo is not None and hi is not None:
        if integer:
            d.integer_range = [IntegerRange(from_value=int(lo), to_value=int(hi), step=int(step or 1))]
        else:
            d.floating_point_range = [FloatingPointRange(from_value=float(lo), to_value=float(hi),
                                                         step=float(step or 0.0))]
    return d


class LockstepNode(Node):
    """Base of the four drive nodes: parameters with descriptors, the watchdog, a clean stop."""

    def __init__(self, name: str, **kwargs):
        super().__init__(name, **kwargs)
        self.done = False
        self.exit_code = 0
        self.gate: Optional[StepGate] = None
        self._timeout = 5.0
        self._startup_timeout = 30.0
        self._started = False
        self._watchdog = None
        self.on_stop: Optional[Callable[['LockstepNode'], None]] = None   # set by a graph

    # Parameters -----------------------------------------------------------------------
    def param(self, name: str, default, description: str, lo=None, hi=None, read_only: bool = True,
              choices: Optional[Sequence[str]] = None):
        """Declare a parameter with a descriptor and return its value (validated)."""
        integer = isinstance(default, int) and not isinstance(default, bool)
        desc = describe(description + (f' (one of: {", ".join(choices)})' if choices else ''),
                        lo, hi, read_only=read_only, integer=integer)
        value = self.declare_parameter(name, default, desc).value
        if choices is not None and value not in choices:
            raise ValueError(f"invalid parameter '{name}' = {value!r}: must be one of "
                             f"{', '.join(choices)}")
        return value

    def use_sim_time(self) -> None:
        if not self.has_parameter('use_sim_time'):
            self.declare_parameter('use_sim_time', True)
        self.set_parameters([Parameter('use_sim_time', Parameter.Type.BOOL, True)])

    # Watchdog --------------------------------------------------------------------------
    def start_watchdog(self, input_timeout: float, startup_timeout: float) -> None:
        self._timeout = float(input_timeout)
        self._startup_timeout = float(startup_timeout)
        self._watchdog = self.create_timer(0.05, self._check_inputs,
                                           clock=Clock(clock_type=ClockType.STEADY_TIME))

    def _check_inputs(self) -> None:
        g = self.gate
        if g is None or self.done:
            return
        limit = self._timeout if self._started else max(self._timeout, self._startup_timeout)
        waited = time.monotonic() - g.since
        if waited > limit:
            missing = g.missing()
            step = g.expected // g.period
            self.fail(f"no {', '.join(missing)} stamped {g.expected / NS_PER_S:.9f} s "
                      f"(step {step}) within {limit:.1f} s of wall time; stopping")

    def gate_input(self, topic: str, extract: Callable) -> None:
        """Subscribe (serialized, lock-step QoS) to ``topic`` and feed ``extract(data)`` =
        (stamp_ns, value) into the step gate; complete steps go to ``self.ready(inputs)``."""
        from geometry_msgs.msg import Vector3Stamped
        from sensor_msgs.msg import JointState
        from .topics import JS, TOPIC_TYPES
        cls = JointState if TOPIC_TYPES[topic] == JS else Vector3Stamped
        put = self.gate.put
        ready = self.ready

        def on_data(data, topic=topic):
            ns, value = extract(data)
            ready(put(topic, ns, value))
        self.create_subscription(cls, topic, on_data, lockstep_qos(), raw=True)

    def ready(self, inputs) -> None:  # pragma: no cover - each node defines it
        raise NotImplementedError

    def mark_started(self) -> None:
        self._started = True

    def fail(self, reason: str) -> None:
        self.get_logger().error(reason)
        self.failure = reason
        self.exit_code = 1
        self.done = True
        if self.on_stop is not None:
            self.on_stop(self)

    def finish(self) -> None:
        self.done = True
        if self.on_stop is not None:
            self.on_stop(self)


def make_executor(context=None):
    """The EventsExecutor (≈5× the SingleThreadedExecutor's message rate on these machines)."""
    from rclpy.experimental import EventsExecutor
    return EventsExecutor(context=context)


def spin_until_done(nodes, executor, context=None, wall_limit: Optional[float] = None) -> None:
    """Spin until every node in ``nodes`` is done (or one failed, or the context shut down)."""
    t0 = time.monotonic()
    while rclpy.ok(context=context):
        if any(n.exit_code for n in nodes) or all(n.done for n in nodes):
            return
        executor.spin_once(timeout_sec=0.05)
        if wall_limit is not None and time.monotonic() - t0 > wall_limit:
            raise TimeoutError(f'run exceeded {wall_limit} s of wall time')


def node_main(factory: Callable[..., LockstepNode], argv=None) -> int:
    """``main`` of a drive node: Jazzy shutdown idiom, parameter errors as one-line messages."""
    args = sys.argv if argv is None else argv
    user_args = args[1:args.index('--ros-args')] if '--ros-args' in args else args[1:]
    if '-h' in user_args or '--help' in user_args:
        return print_node_help(factory, args[0])
    rclpy.init(args=args)
    node = None
    code = 0
    try:
        try:
            node = factory()
        except (ValueError, rclpy.exceptions.InvalidParameterValueException,
                rclpy.exceptions.ParameterException) as exc:
            print(f'error: {exc}', file=sys.stderr)
            return 2
        executor = make_executor()
        executor.add_node(node)
        spin_until_done([node], executor)
        code = node.exit_code
    except (KeyboardInterrupt, ExternalShutdownException):
        code = 0 if node is None or not node.exit_code else node.exit_code
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return code


def parameter_table(node: Node) -> str:
    """Markdown table of a node's declared parameters (name, default, range, description)."""
    rows = ['| parameter | default | range | description |', '| --- | --- | --- | --- |']
    for name in sorted(node._parameters):
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
        rows.append(f'| `{name}` | `{value!r}` | {rng} | {d.description} |')
    return '\n'.join(rows)


def print_node_help(factory, prog: str) -> int:
    """``--help``: build the node in a private context and print its parameters."""
    import os
    import random
    from rclpy.context import Context
    ctx = Context()
    rclpy.init(args=[prog], context=ctx, domain_id=random.randint(150, 229))
    try:
        node = factory(context=ctx)
        print(f'usage: {os.path.basename(prog)} [--ros-args -p name:=value ... '
              f'--params-file FILE.yaml]\n')
        print((node.__doc__ or '').strip().splitlines()[0] if node.__doc__ else '')
        print(parameter_table(node))
        node.destroy_node()
    finally:
        rclpy.shutdown(context=ctx)
    return 0
