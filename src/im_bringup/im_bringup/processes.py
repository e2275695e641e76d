"""
The drive graph as separate processes: which nodes, with which parameters, started how.

One description, :func:`graph_processes`, serves ``launch/drive.launch.py`` (``ros2 launch``) and
:class:`GraphProcesses`, the small supervisor that the tests, the benchmarks and ``scenario
--processes`` use where ``ros2 launch`` is not installed. Both start every node the way
``launch_ros`` does: the node's executable from the ament index (``lib/<pkg>/<exe>``, what
``ros2 run`` finds), ``--ros-args -r __node:=<name>`` and one ``--params-file`` per node holding
``/**: ros__parameters: {...}``.

What is started:
- ``plant``, ``controller``, ``observer`` always; ``adapter`` when the controller uses it
  (``controller:=adaptive`` / ``adaptive_thesis`` or ``use_adapter:=true``); ``record`` (the
  recorder, a lossless follower) when ``record`` names a file; ``live`` (the live view,
  :mod:`im_bringup.live`) with ``live_port``.
- The plant waits for controller, observer (and adapter, recorder when started) before step 0.
- ``mode`` is the plant's: ``lockstep`` (default) or ``free_run`` (wall-clock fixed rate; give it
  gains certified at that period, e.g. ``gains:=.../config/gains_1ms.yaml`` at ``T_s:=0.001``).
- Discovery stays on this host unless ``ROS_AUTOMATIC_DISCOVERY_RANGE`` is set by the user.
"""
from __future__ import annotations

import atexit
from contextlib import nullcontext
from dataclasses import dataclass, field
import json
import os
import signal
import subprocess
import sys
import time
from typing import Dict, List, Mapping, Optional, Sequence

from im_bringup.config import node_parameters, run_nodes
from im_common import auth
from im_common.stopping import StopSignals
from im_common.timing import CANDIDATE_RATES_HZ
from im_common.yamlio import load_parameters_file, parameters_yaml


#: Order in which the supervisor starts nodes (the time master last: it waits for the others
#: anyway, but starting it last makes its "waiting for" log short).
START_ORDER = ('live', 'recorder', 'controller', 'observer', 'adapter', 'plant')

#: Package and executable of each node of the graph.
EXECUTABLES = {'plant': ('im_plant', 'plant'), 'controller': ('im_controller', 'controller'),
               'observer': ('im_observer', 'observer'), 'adapter': ('im_adapt', 'adapter'),
               'recorder': ('im_recording', 'record'), 'live': ('im_bringup', 'live')}


@dataclass
class NodeProcess:
    """One process of the graph: ``ros2 run <package> <executable>`` with these parameters."""

    name: str
    package: str
    executable: str
    parameters: Dict[str, object] = field(default_factory=dict)
    arguments: List[str] = field(default_factory=list)     # before --ros-args


def graph_processes(task: str = 'position', strategy: str = 'min_energy',
                    controller: str = 'nominal', T_s: float = 1e-4,
                    duration: Optional[float] = None, mode: str = 'lockstep',
                    use_adapter: Optional[bool] = None, record: Optional[str] = None,
                    extra: Optional[Mapping[str, Mapping[str, object]]] = None,
                    key_file: Optional[str] = None,
                    record_metadata: Optional[Mapping[str, Mapping[str, str]]] = None,
                    scenario=None, live_port: Optional[int] = None,
                    log_time: str = 'wall', **config) -> List[NodeProcess]:
    """
    Return the processes of one run (see the module docstring).

    ``extra`` = {node: {param: value}} merged last (a gains or parameters YAML), ``config`` goes to
    :func:`im_bringup.config.node_parameters`. ``key_file``: the graph's key (default: a fresh
    one, :func:`im_common.auth.new_key_file`, removed when this process exits), given to every
    node as ``graph_key_file``. ``record_metadata``: named metadata records the recorder writes
    into the bag (``record --metadata``; the scenario runner's
    :func:`im_bringup.scenario.run_metadata`). ``scenario``: a
    :class:`~im_bringup.run_file.Scenario` (a run file) instead of task ... config.
    ``live_port``: also the live view on that port (:mod:`im_bringup.live`). ``log_time``: the
    recording's log times, ``wall`` or ``simulated`` (``record --log-time``).
    """
    if mode not in ('lockstep', 'free_run'):
        raise ValueError(f'invalid mode {mode!r}: lockstep or free_run')
    if log_time not in ('wall', 'simulated'):
        raise ValueError(f'invalid log_time {log_time!r}: wall or simulated')
    if scenario is not None:
        params = scenario.node_parameters(**{k: config.pop(k) for k in (
            'truth_decimation', 'reference_decimation', 'input_timeout') if k in config})
        if config:
            raise ValueError(f'invalid option {next(iter(config))!r} beside a scenario')
    else:
        params = node_parameters(task, strategy, controller, T_s=T_s, duration=duration,
                                 **config)
    adaptive = params['controller'].get('use_adapter', False)
    if use_adapter is not None and use_adapter != adaptive:
        adaptive = bool(use_adapter)
        for node in ('controller', 'observer'):
            params[node]['use_adapter'] = adaptive
        params['adapter']['enable'] = adaptive
    for node, values in (extra or {}).items():
        if node not in params:
            raise ValueError(f"unknown node '{node}' in the extra parameters (expected one of "
                             f"{', '.join(params)})")
        params[node].update(values)
    names = run_nodes(params)[1:]
    params['plant']['mode'] = mode
    params['plant']['wait_for'] = ' '.join(names + (['recorder'] if record else []))
    if key_file is None:
        key_file = graph_key_file()
    procs = [NodeProcess(n, *EXECUTABLES[n], parameters=dict(params[n], graph_key_file=key_file))
             for n in ['plant'] + names]
    if record:
        procs.append(NodeProcess('recorder', *EXECUTABLES['recorder'],
                                 parameters={'graph_key_file': key_file},
                                 arguments=['--out', str(record), '--log-time', log_time] + (
                                     ['--metadata', json.dumps(record_metadata, sort_keys=True)]
                                     if record_metadata else [])))
    if live_port is not None:
        procs.append(NodeProcess('live', *EXECUTABLES['live'],
                                 arguments=['--port', str(int(live_port))]))
    return procs


def graph_key_file() -> str:
    """Return a fresh key for one graph (``docs/security.md``), removed when this process exits."""
    path = auth.new_key_file()
    atexit.register(auth.remove_key_file, path)
    return path


def params_file_text(parameters: Mapping[str, object]) -> str:
    """Return a node's parameters as ``launch_ros`` writes them (``/**: ros__parameters:``)."""
    return parameters_yaml({'/**': dict(parameters)})


def load_params_yaml(path: str) -> Dict[str, Dict[str, object]]:
    """
    Return {node: {param: value}} of a ROS 2 parameters YAML (e.g. from ``design_gains``).

    A file that cannot be used is one :class:`im_common.yamlio.ParametersFileError` naming it.
    """
    return load_parameters_file(path, nodes=node_parameters())


def free_run_gains(T_s: float) -> str:
    """
    Return the shipped gains file certified at ``T_s`` (``config/gains_<ms>ms.yaml``).

    One for each rate the free_run pre-flight may name (``im_common.timing.CANDIDATE_RATES_HZ``;
    ``make gains`` designs them). A period without one is a ValueError naming the ones shipped.
    """
    # heavy: ament_index_python only to find the shipped gains
    from ament_index_python.packages import get_package_share_directory
    config = os.path.join(get_package_share_directory('im_bringup'), 'config')
    for rate in CANDIDATE_RATES_HZ:
        if abs(T_s * rate - 1.0) < 1e-9:
            return os.path.join(config, f'gains_{1000.0 / rate:g}ms.yaml')
    raise ValueError(f'no certified gains shipped for T_s = {T_s:g} s: the free_run rates are '
                     + ', '.join(f'{r} Hz (T_s = {1.0 / r:g} s)' for r in CANDIDATE_RATES_HZ))


def executable_path(package: str, executable: str) -> str:
    from ament_index_python.packages import get_package_prefix  # heavy: only to find a node
    return os.path.join(get_package_prefix(package), 'lib', package, executable)


class GraphProcesses:
    """
    Start the graph's processes, forward stop signals, collect exit codes and logs.

    ``workdir`` receives one ``<name>.yaml`` (parameters) and one ``<name>.log`` (stdout+stderr)
    per process. ``env`` is added to this process's environment (e.g. ``ROS_DOMAIN_ID``).
    """

    def __init__(self, processes: Sequence[NodeProcess], workdir: str,
                 env: Optional[Mapping[str, str]] = None):
        self.processes = {p.name: p for p in processes}
        self.workdir = workdir
        self.env = dict(os.environ)
        self.env.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
        self.env.update(env or {})
        self.env['PYTHONUNBUFFERED'] = '1'
        self.popen: Dict[str, subprocess.Popen] = {}
        self.started_at: Optional[float] = None

    def command(self, p: NodeProcess) -> List[str]:
        cmd = [executable_path(p.package, p.executable)] + list(p.arguments)
        cmd += ['--ros-args', '-r', f'__node:={p.name}']
        if p.parameters:
            path = os.path.join(self.workdir, f'{p.name}.yaml')
            with open(path, 'w') as f:
                f.write(params_file_text(p.parameters))
            cmd += ['--params-file', path]
        return cmd

    def start(self, only: Optional[Sequence[str]] = None) -> 'GraphProcesses':
        os.makedirs(self.workdir, exist_ok=True)
        self.started_at = time.monotonic()
        order = [n for n in START_ORDER if n in self.processes] + [
            n for n in self.processes if n not in START_ORDER]
        for name in order:
            if only is not None and name not in only:
                continue
            self.start_one(name)
        return self

    def start_one(self, name: str) -> subprocess.Popen:
        p = self.processes[name]
        log = open(os.path.join(self.workdir, f'{name}.log'), 'w')
        self.popen[name] = subprocess.Popen(self.command(p), stdout=log, stderr=subprocess.STDOUT,
                                            stdin=subprocess.DEVNULL, env=self.env)
        log.close()
        return self.popen[name]

    def send(self, sig: int, names: Optional[Sequence[str]] = None) -> None:
        for name, proc in self.popen.items():
            if (names is None or name in names) and proc.poll() is None:
                proc.send_signal(sig)

    def wait(self, timeout: float) -> Dict[str, Optional[int]]:
        """Wait until every process exits or ``timeout`` [s] passes; exit codes (None: running)."""
        deadline = time.monotonic() + timeout
        for proc in self.popen.values():
            left = deadline - time.monotonic()
            try:
                proc.wait(timeout=max(left, 0.01))
            except subprocess.TimeoutExpired:
                pass
        return self.returncodes()

    def returncodes(self) -> Dict[str, Optional[int]]:
        return {n: p.poll() for n, p in self.popen.items()}

    def stop(self, grace: float = 10.0) -> Dict[str, Optional[int]]:
        """
        Stop the graph: SIGINT to every running process, then SIGKILL after ``grace`` seconds.

        SIGINT is what ``ros2 launch`` does on Ctrl-C; a process that did not exit after
        ``grace`` seconds is killed (reported as -9).
        """
        self.send(signal.SIGINT)
        codes = self.wait(grace)
        stuck = [n for n, c in codes.items() if c is None]
        if stuck:
            self.send(signal.SIGKILL, stuck)
            codes = self.wait(5.0)
        return codes

    def stacks(self, names: Optional[Sequence[str]] = None, wait: float = 2.0) -> None:
        """
        Ask each running process in ``names`` (default: all) for every thread's stack.

        It writes them to its log and goes on (:func:`im_common.host.enable_stack_dump`): where
        a process that does not end is, before it is stopped. Waits up to ``wait`` seconds for
        the stacks to appear.
        """
        from im_common.host import STACK_SIGNAL  # heavy: im_common.host imports rclpy
        asked = [n for n, p in self.popen.items()
                 if (names is None or n in names) and p.poll() is None]
        before = {n: len(self.log(n)) for n in asked}
        self.send(STACK_SIGNAL, asked)
        deadline = time.monotonic() + wait
        while asked and time.monotonic() < deadline:
            if all('most recent call first' in self.log(n)[before[n]:] for n in asked):
                break
            time.sleep(0.05)

    def ended_text(self, codes: Mapping[str, Optional[int]], tail: int = 3000) -> str:
        """
        Say which processes did not end with exit code 0, each with its log's end.

        A process still running (code None) is first asked for its stacks (:meth:`stacks`), so
        its log ends where it hangs.
        """
        bad = {n: c for n, c in codes.items() if c != 0}
        self.stacks([n for n, c in bad.items() if c is None])
        return '\n'.join(
            f'--- {n}: ' + ('still running' if c is None else f'exit code {c}')
            + f' ---\n{self.log(n)[-tail:]}' for n, c in bad.items())

    def log(self, name: str) -> str:
        try:
            with open(os.path.join(self.workdir, f'{name}.log')) as f:
                return f.read()
        except OSError:
            return ''

    def __enter__(self) -> 'GraphProcesses':
        return self

    def __exit__(self, *exc) -> None:
        if any(p.poll() is None for p in self.popen.values()):
            self.stop(grace=5.0)


#: Exit code of a node that refused its configuration (``im_common.lockstep.node_main``).
REFUSED = 2
#: The processes off the run's critical path (docs/guarantees.md, "Off the critical path"): the
#: recorder and the live view. One that dies during the run does not end it: the run goes on
#: without it (unrecorded: the plant drops a lossless follower that acknowledged nothing for its
#: ``input_timeout``, 5 s by default, and steps on) and :func:`lost_line` says so once. One that
#: refuses its configuration (exit code 2) still stops the graph at once, as any node's refusal:
#: nothing has run yet, and the run asked for cannot be made.
OFF_CRITICAL_PATH = ('recorder', 'live')


def ends_graph(name: str, code: Optional[int]) -> bool:
    """Tell whether process ``name`` exiting with ``code`` ends the graph (OFF_CRITICAL_PATH)."""
    if code in (None, 0):
        return False
    return code == REFUSED or name not in OFF_CRITICAL_PATH


def exit_text(code: int) -> str:
    """Say how a process ended: ``exit code 1``, or ``killed by SIGKILL (exit code -9)``."""
    if code < 0:
        try:
            return f'killed by {signal.Signals(-code).name} (exit code {code})'
        except ValueError:
            pass
    return f'exit code {code}'


def lost_line(name: str, code: int, arguments: Sequence[str] = ()) -> str:
    """
    Say in one line that a process off the critical path ended with an error and the run goes on.

    For the recorder: the run goes on unrecorded, and where what it wrote is (its ``--out``'s
    ``.part``, for ``recover``). ``arguments``: the process's own (:attr:`NodeProcess.arguments`).
    """
    if name == 'recorder':
        args = list(arguments)
        out = args[args.index('--out') + 1] if '--out' in args[:-1] else None
        where = (f'; what it wrote up to then is in {out}.part: ros2 run im_recording recover '
                 f'{out}.part' if out else '')
        return (f'recorder {exit_text(code)}: the run goes on UNRECORDED (the plant stops '
                f'waiting for its acknowledgements after its input_timeout){where}')
    return f'{name} {exit_text(code)}: the run goes on without it'


#: Seconds the others get to end on their own after a node failed at run time (they see its
#: ``failed`` event) before they are stopped; a refused configuration stops them at once.
FAILURE_GRACE = 2.0


def run_processes(processes: Sequence[NodeProcess], workdir: str, timeout: float,
                  env: Optional[Mapping[str, str]] = None, progress: bool = False,
                  stop=None) -> Dict[str, Optional[int]]:
    """
    Start the graph, wait for every process to exit, stop it after ``timeout``; return the codes.

    SIGINT/SIGTERM to this process stop the graph cleanly. A process that exits
    with an error stops the graph: at once when it refused its configuration (exit code 2),
    after :data:`FAILURE_GRACE` otherwise — nobody waits out a startup timeout for a node that
    is gone. :func:`failure_line` says which and why. A process off the critical path (the
    recorder, the live view: :data:`OFF_CRITICAL_PATH`) that dies during the run does not stop
    it: :func:`lost_line` is printed once (stderr) and the run goes on to its end.
    ``stop``: the caller's :class:`im_common.stopping.StopSignals` (so it knows it was asked to
    stop); by default one of its own.
    """
    g = GraphProcesses(processes, workdir, env)
    said = set()
    with (StopSignals() if stop is None else nullcontext(stop)) as stop:
        g.start()
        t0 = time.monotonic()
        stop_at = None
        while time.monotonic() - t0 < timeout:
            if stop.requested:
                break
            codes = g.returncodes()
            if all(c is not None for c in codes.values()):
                return codes
            for name, c in codes.items():
                if c not in (None, 0) and not ends_graph(name, c) and name not in said:
                    said.add(name)
                    print(('\n' if progress else '') + lost_line(
                        name, c, g.processes[name].arguments), file=sys.stderr, flush=True)
            failed = [c for n, c in codes.items() if ends_graph(n, c)]
            if failed and stop_at is None:
                stop_at = time.monotonic() + (0.0 if REFUSED in failed else FAILURE_GRACE)
            if stop_at is not None and time.monotonic() >= stop_at:
                break
            if progress:
                running = [n for n, c in codes.items() if c is None]
                print(f'\r  {time.monotonic() - t0:6.1f} s  running: {" ".join(running):50s}',
                      end='', file=sys.stderr, flush=True)
            time.sleep(0.1)
        if progress:
            print(file=sys.stderr)
        return g.stop()


def failure_line(workdir: str, codes: Mapping[str, Optional[int]]) -> Optional[str]:
    """
    Return ``'<node>: <its error line>'`` for the process that ended the graph.

    A refused configuration first, then a process that ends the graph (:func:`ends_graph`), in
    start order, from its log in ``workdir``; None when every process exited 0.
    """
    failed = [n for n, c in codes.items() if c not in (None, 0)]
    if not failed:
        return None
    order = list(START_ORDER)
    failed.sort(key=lambda n: (codes[n] != REFUSED, not ends_graph(n, codes[n]),
                               order.index(n) if n in order else 99))
    name = failed[0]
    try:
        with open(os.path.join(workdir, f'{name}.log')) as f:
            lines = [ln.strip() for ln in f if ln.strip()]
    except OSError:
        lines = []
    said = [ln for ln in lines if 'error: ' in ln and not ln.startswith('[')]
    said = said or [ln for ln in lines if ln.startswith('[ERROR]') or ln.startswith('[FATAL]')]
    if not said:
        return f'{name}: {exit_text(codes[name])} (see {workdir}/{name}.log)'
    line = said[0]
    if line.startswith('['):                        # a ROS log line: [LEVEL] [stamp] [node]: text
        line = line.split(']: ', 1)[-1]
    return f"{name}: {line.split('error: ', 1)[-1]}"


def check_processes(processes: Sequence[NodeProcess]) -> None:
    """
    Refuse a configuration that a node's own process would refuse, before any process is started.

    Each node is built once with its parameters (:func:`im_bringup.graph.check_parameters`);
    raises :class:`im_common.lockstep.ConfigurationError` (one line).
    """
    from im_bringup.graph import check_parameters  # heavy: the in-process graph imports rclpy
    check_parameters({p.name: p.parameters for p in processes})
