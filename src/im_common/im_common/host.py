"""
Hosting a drive node: its process, real-time scheduling, stop signals, the spin, ``main``.

A node (:class:`im_common.lockstep.LockstepNode`) computes and speaks the run protocol; where it
runs is decided here. :func:`node_main` runs one node as its own process (Jazzy shutdown idiom,
stop signals, one-line errors) and gives it a :class:`ProcessHost`, which may move the process to
real-time scheduling in free_run; the in-process graph (:mod:`im_bringup.graph`) hosts nodes
without one (it never changes its scheduling). :func:`build_node` is the one place every path
constructs a node and checks its configuration.
"""
from __future__ import annotations

import contextlib
import faulthandler
import os
import random
import signal
import sys
import threading
import time
from typing import Callable, List, Optional

import rclpy
from rclpy.context import Context
from rclpy.duration import Duration
from rclpy.executors import ExternalShutdownException
from rclpy.experimental import EventsExecutor
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.logging import get_logger
from rclpy.signals import SignalHandlerOptions
from rclpy.task import Future

from . import realtime
from .cli import error as cli_error
from .conversions import s_to_ns
from .lockstep_parts import unknown_parameter
from .lockstep_protocol import STOPPED, STOPPING, WARNING
from .node_params import ConfigurationError
from .stopping import StopSignals
from .yamlio import load_parameters_file, ParametersFileError

#: On exit, how long a node waits at most until its readers acknowledged its last samples [s].
STOP_FLUSH_S = 3.0
#: After its run, how long a node process may take to flush, tear down and exit before it is
#: ended with every thread's stack on stderr and exit code 1 [s]. The flushes are bounded
#: (2 s + 3 s); the middleware's and the executor's teardown are not: twice (full test runs on
#: 2026-11-26 and 2026-11-28, not reproduced in hundreds of runs of the same graph alone) a node
#: whose run had finished did not exit in 120 s.
EXIT_GRACE_S = 20.0
#: How long the executor's shutdown may wait for its spin to stop [s] (it is not spinning then).
EXECUTOR_SHUTDOWN_S = 2.0


def guard_exit(grace: float) -> None:
    """
    From here on this process ends within ``grace`` seconds, or is ended.

    A C-level watchdog (it needs no GIL) writes every thread's stack to stderr and exits with
    code 1 if the process has not exited by then. It stays armed through the interpreter's own
    finalization (where the middleware's and the executor's C++ objects are destroyed), so it is
    for a process's main only (:func:`node_main`), never for code that goes on afterwards.
    """
    faulthandler.dump_traceback_later(grace, exit=True)


@contextlib.contextmanager
def yielding_to_middleware():
    """
    While a process tears its middleware down: every thread on one CPU, the calling one below them.

    Fast DDS 2.14's participant teardown (``DomainParticipant::set_listener(nullptr)``, called by
    ``rmw_destroy_node`` for the process's last node) waits for a discovery callback in flight
    with a condition wait that, as built in the wheels, returns at once: it spins, taking its
    mutex again and again, and the callback thread, which needs that mutex once to say it is
    done, almost never gets it. When another process of the graph tore down at the same moment
    (the removal of its endpoints is a discovery callback here) a process hung there for good:
    in stress runs of the 0.02 s graph 3 of about 250 runs, none in 320 with this
    (docs/guarantees.md, "Ending is bounded"). With every thread on one CPU and the spinning one
    below the others (ordinary scheduling at nice 19, also when the process ran real-time), the
    callback thread runs as soon as the spinner lets the mutex go, and the wait ends. Not
    ``SCHED_IDLE``: beside CPU-bound processes on that CPU an idle-class thread hardly ran, and a
    recorder took over 20 s to destroy its node. The scheduling is restored on leaving. Best
    effort: where these calls are refused, :func:`guard_exit` still bounds the teardown. The
    context's value is a list of what was refused (one line each, e.g. an unprivileged process
    may not lower its nice value again), filled on entering and on leaving, for the caller to
    report.
    """
    refused: List[str] = []
    saved = None
    me = threading.get_native_id()
    try:
        saved = (os.sched_getaffinity(0), os.sched_getscheduler(0), os.sched_getparam(0),
                 os.getpriority(os.PRIO_PROCESS, me))
        cpu = min(saved[0])
        for tid in os.listdir('/proc/self/task'):
            try:
                os.sched_setaffinity(int(tid), {cpu})
            except OSError:         # a thread that ended meanwhile
                pass
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
        os.setpriority(os.PRIO_PROCESS, me, YIELD_NICE)
    except (AttributeError, OSError) as exc:
        refused.append(f'yielding to the middleware: {exc}')
    try:
        yield refused
    finally:
        if saved is not None:
            try:
                os.setpriority(os.PRIO_PROCESS, me, saved[3])
            except OSError as exc:
                refused.append(f'restoring the nice value: {exc}')
            try:
                os.sched_setscheduler(0, saved[1], saved[2])
            except OSError as exc:
                refused.append(f'restoring the scheduling policy: {exc}')
            for tid in os.listdir('/proc/self/task'):
                try:
                    os.sched_setaffinity(int(tid), saved[0])
                except OSError:     # a thread that ended meanwhile
                    pass


#: The nice value of the thread that tears the participant down (:func:`yielding_to_middleware`).
YIELD_NICE = 19


def end_process(node, executor) -> None:
    """
    Tear a process's middleware down, bounded: its executor, its node (the last one), rclpy.

    For a process's main only: from here the process exits within :data:`EXIT_GRACE_S` or is
    ended with its stacks (:func:`guard_exit`). The executor and the node's publishers,
    subscriptions, services, clients and timers go first, with the process's own scheduling;
    then the node and rclpy, which take the participant down, yielding to the middleware's
    threads (:func:`yielding_to_middleware`). Either may be None.
    """
    guard_exit(EXIT_GRACE_S)
    name = node.get_name() if node is not None else 'process'
    if executor is not None:
        executor.shutdown(timeout_sec=EXECUTOR_SHUTDOWN_S)
    if node is not None:
        destroy_entities(node)
    with yielding_to_middleware() as refused:
        if node is not None:
            node.destroy_node()     # the process's last node: its participant goes with it
        rclpy.try_shutdown()
    for line in refused:            # not a fault (guard_exit bounds the end), but never silent
        get_logger(name).debug(f'teardown: refused {line}')


def destroy_entities(node) -> None:
    """Destroy a node's publishers, subscriptions, services, clients and timers (rclpy's API)."""
    for timer in list(node.timers):
        node.destroy_timer(timer)
    for sub in list(node.subscriptions):
        node.destroy_subscription(sub)
    for srv in list(node.services):
        node.destroy_service(srv)
    for cli in list(node.clients):
        node.destroy_client(cli)
    for pub in list(node.publishers):
        node.destroy_publisher(pub)


#: The signal on which a node process writes every thread's stack to stderr and goes on.
STACK_SIGNAL = signal.SIGUSR1


def enable_stack_dump() -> None:
    """
    Make ``kill -USR1 <pid>`` write every thread's Python stack to stderr (the process's log).

    A process that does not end can be asked where it is before it is stopped
    (:meth:`im_bringup.processes.GraphProcesses.stacks`); the process goes on.
    """
    faulthandler.register(STACK_SIGNAL, all_threads=True)


def build_node(factory: Callable, **kwargs):
    """
    Construct a drive node and check its configuration.

    Checked: every declared parameter's type and range (``LockstepNode.param``) and no parameter
    given that it does not declare (:func:`im_common.lockstep_parts.unknown_parameter`). A node
    executable
    (:func:`node_main`), the in-process graph and the check a supervisor makes before starting
    processes all build nodes here, so a configuration is refused with the same
    :class:`ConfigurationError` line on every path.
    """
    node = None
    try:
        node = factory(**kwargs)
        bad = unknown_parameter(node.get_name(), getattr(node, '_parameter_overrides', {}),
                                node.list_parameters([], 0).names)
        if bad:                 # a misspelt gain must not silently fall back to its default
            raise ValueError(bad)
        return node
    except (ValueError, rclpy.exceptions.ParameterException) as exc:
        if node is not None:
            node.destroy_node()
        raise ConfigurationError(str(exc).splitlines()[0]) from None


class ProcessHost:
    """
    The process of a node that runs alone in it: its scheduling (free_run may make it real-time).

    ``scheduling`` says what it got ('normal', 'fifo:50', 'normal (refused)').
    """

    __slots__ = ('scheduling', 'tried')

    def __init__(self):
        self.scheduling = 'normal'
        self.tried = False

    def enter_realtime(self, node, below_loop: bool = False) -> None:
        """
        Enter free_run: SCHED_FIFO ``node.rt_priority`` for every thread of this process (once).

        ``below_loop``: the recorder's priority, below the control loop's (it has no deadlines,
        but must keep up). If that fails, one warning says why (also on /im/status: the run then
        has no real-time guarantee).
        """
        if self.tried or not node.realtime_capable:
            return
        self.tried = True
        log = node.get_logger()
        what = 'free_run: recording' if below_loop else 'free_run'
        if node.rt_priority <= 0:
            log.info(f'{what} with ordinary scheduling (rt_priority 0)')
            return
        ok, text = realtime.enter(node.rt_priority)
        if ok:
            if not below_loop:          # the loop's collection pauses short (not the recorder's)
                realtime.quiet_gc()
            self.scheduling = node.scheduling = text
            log.info(f'{what} at real-time priority {text}, below the control loop' if below_loop
                     else f'free_run: real-time scheduling ({text})')
            return
        self.scheduling = node.scheduling = 'normal (refused)'
        msg = (f'{what} without real-time scheduling: {text}; '
               + ('a busy machine may starve the recorder (its missing steps are counted)'
                  if below_loop else 'deadlines may be missed'))
        log.warning(msg)
        node.status(WARNING, level=1, reason=msg)


def request_stop(node, signame: str) -> None:
    """
    Take a stop signal for ``node``: say so on /im/status and end it (exit code 0).

    The time master's stop ends the run (``stopped``); any other node's is news for the others
    (``stopping``).
    """
    if node.done:
        return
    where = f' at step {node.current_ns() // node.period}' if node.period else ''
    node.get_logger().info(f'{signame}: stopping' + (' the run' if node.time_master else '')
                           + where)
    node.status(STOPPED if node.time_master else STOPPING, level=1, reason=signame)
    node.done = True


def flush(node, timeout: float = 2.0) -> None:
    """Wait (bounded) until every reliable publisher's data of ``node`` has been acknowledged."""
    deadline = time.monotonic() + timeout
    for pub in list(node.publishers):
        left = deadline - time.monotonic()
        if left <= 0:
            return
        try:
            pub.wait_for_all_acked(Duration(nanoseconds=s_to_ns(left)))
        except Exception:  # noqa: BLE001 - context already shut down: nothing to wait for
            return


def make_executor(context=None):
    """Return an EventsExecutor (≈5× the SingleThreadedExecutor's message rate here)."""
    return EventsExecutor(context=context)


#: How often the spin comes back to look for a stop signal [s] (a node's end returns at once).
SPIN_SLICE_S = 0.05


def spin_until_done(nodes, executor, context=None, stop: Optional[StopSignals] = None) -> None:
    """
    Spin until every node in ``nodes`` is done, one failed, or a stop signal arrived.

    The executor takes the events natively (``spin_until_future_complete``) in slices of
    :data:`SPIN_SLICE_S`, not one ``spin_once`` each: the events of a step follow each other
    without a pass through a Python loop (≈ 5 µs of CPU less an event: the two-process ping-pong
    ran 8 % faster on 7 % less CPU, docs/benchmarks.md). A node's end (``finish``, its
    ``on_stop``) completes the slice's future, so the loop sees it at once; a stop signal is seen
    at the slice's end. After a stop signal every node is asked to stop and spun a little longer
    so that it can say so.
    """
    ended = [Future()]

    def hook(chained):
        def on_stop(node):
            if chained is not None:
                chained(node)
            if not ended[0].done():
                ended[0].set_result(node.get_name())
        return on_stop

    for n in nodes:
        n.on_stop = hook(n.on_stop)
    while rclpy.ok(context=context):
        if any(n.exit_code for n in nodes) or all(n.done for n in nodes):
            return
        if stop is not None and stop.requested:
            for n in nodes:
                request_stop(n, stop.requested)
            return
        if ended[0].done():             # one node of several ended: spin on for the others
            ended[0] = Future()
        executor.spin_until_future_complete(ended[0], timeout_sec=SPIN_SLICE_S)


def _rcl_error():
    return _rclpy.RCLError


def init_args_error(args: List[str]) -> Optional[str]:
    """
    Return a readable line for a bad ``--params-file`` (missing, unreadable, malformed).

    That is before ``rclpy.init`` turns it into a traceback; None when the files look loadable. The
    file is read by :func:`im_common.yamlio.load_parameters_file`, as on every other path.
    """
    for i, a in enumerate(args):
        if a == '--params-file':
            if i + 1 >= len(args):
                return '--params-file needs a file name'
            try:
                load_parameters_file(args[i + 1])
            except ParametersFileError as exc:
                return str(exc)
    return None


def node_main(factory: Callable, argv=None) -> int:
    """
    Run a drive node (its ``main``): Jazzy shutdown idiom, stop signals, one-line errors.

    Exit codes: 0 finished or stopped (signal, or the run ended elsewhere), 1 failed, 2 refused
    configuration. It is a process's main (``sys.exit(node_main(...))``): once the run is over the
    process exits within :data:`EXIT_GRACE_S` or is ended with its stacks (:func:`guard_exit`).
    """
    args = list(sys.argv if argv is None else argv)
    user_args = args[1:args.index('--ros-args')] if '--ros-args' in args else args[1:]
    if '-h' in user_args or '--help' in user_args:
        return print_node_help(factory, args[0])
    prog = args[0].rsplit('/', 1)[-1]
    bad = init_args_error(args)
    if bad:
        return cli_error(prog, bad)
    enable_stack_dump()
    with StopSignals() as stop:
        try:
            rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
        except _rcl_error() as exc:
            return cli_error(prog, str(exc).splitlines()[0])
        node = executor = None
        code = 0
        try:
            try:
                node = build_node(factory)
                node.host = ProcessHost()       # free_run may make this process real-time
            except ConfigurationError as exc:
                return cli_error(prog, exc)
            executor = make_executor()
            executor.add_node(node)
            # the start-up's heap (modules, the node, the middleware's objects) out of the
            # collector's way: a lock-step process paused 12-14 ms once a 2 s run for a full
            # collection of it (free_run freezes again on entering real time)
            realtime.quiet_gc()
            spin_until_done([node], executor, stop=stop)
            code = node.exit_code
            guard_exit(EXIT_GRACE_S)    # the run is over: everything below is bounded
            if not stop.requested:      # let the end of the run reach the others
                flush(node)
        except (KeyboardInterrupt, ExternalShutdownException):
            code = 0 if node is None or not node.exit_code else node.exit_code
        finally:
            # bounded from here to the process's exit, and diagnosable (guard_exit): a teardown
            # or an interpreter exit that hangs ends the process with its stacks and code 1
            guard_exit(EXIT_GRACE_S)
            if node is not None:
                # a stopped node's last samples are still owed to the recorder, which the
                # plant let lag up to follower_window steps: under load 1 s was not always
                # enough
                flush(node, timeout=STOP_FLUSH_S)
            end_process(node, executor)
    return code


def parameter_table(node) -> str:
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


#: DDS domains for a context that joins no graph (a node built only to read its parameters) and
#: for the test suite's graphs (im_bringup.testing): clear of the default 0 and of users' domains.
PRIVATE_DOMAINS = (150, 229)


def private_domain() -> int:
    """Return a random domain of :data:`PRIVATE_DOMAINS`."""
    return random.randint(*PRIVATE_DOMAINS)


def print_node_help(factory, prog: str) -> int:
    """``--help``: build the node in a private context and print its parameters."""
    ctx = Context()
    rclpy.init(args=[prog], context=ctx, domain_id=private_domain())
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
