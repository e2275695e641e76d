r"""
``ros2 run im_bringup scenario``: one drive run — the four nodes in one process, in lock-step.

Spins plant, controller, observer and adapter on a context of their own as a run file says
(:class:`im_bringup.run_file.Scenario`, docs/running.md; the options below override its keys);
shows progress; optionally records every topic to MCAP (the bag carries the resolved run file as
its ``run`` record) and writes the report; always writes a JSON summary of the figures of merit.

Example::

    ros2 run im_bringup scenario RUN.yaml --set controller=adaptive \
        --record bags/demo.mcap --report bags/demo_report
    ros2 run im_bringup scenario --rerun bags/demo.mcap --record bags/again.mcap
"""
from __future__ import annotations

import argparse
from importlib import metadata
import json
import os
import subprocess
import sys
import time
from typing import Mapping, Optional

from im_bringup.config import CONTROLLERS, STRATEGIES, TASKS, to_yaml
from im_bringup.processes import (check_processes, ends_graph, failure_line, graph_processes,
                                  run_processes)
from im_bringup.run_file import RunFileError, Scenario
from im_common.cli import error as cli_error, parse_args, ros_domain_id
from im_common.node_params import variation_from_parameters
from im_common.params import describe_variation, is_motor_name, SCHEDULES
from im_common.stopping import exit_code_for, StopSignals
from im_common.yamlio import load_parameters_file, yaml_problem
import yaml


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog='scenario', description=__doc__.split('\n\n')[0])
    ap.add_argument('run', nargs='?', metavar='RUN.yaml',
                    help='run file (docs/running.md); the options below override its keys')
    ap.add_argument('--set', action='append', default=[], metavar='KEY=VALUE',
                    help='override one run-file key (YAML value; dotted for nested keys, e.g. '
                         'noise.current=0.05); repeatable')
    ap.add_argument('--rerun', metavar='MCAP',
                    help='run again the run file a bag carries (its "run" record)')
    _add_run_keys(ap)
    _add_output_options(ap)
    return ap


def _add_run_keys(ap: argparse.ArgumentParser) -> None:
    """Add the options that override a run file's keys, from ``--task`` to ``--params-file``."""
    ap.add_argument('--task', choices=TASKS, default=None, help='default: position')
    ap.add_argument('--strategy', choices=STRATEGIES, default=None, help='default: min_energy')
    ap.add_argument('--controller', choices=CONTROLLERS, default=None,
                    help='nominal (default), adaptive with the thesis law or the improved law, '
                         'or a baseline law: current_vector, flux_vector, vhz (docs/baselines.md)')
    ap.add_argument('--variation', choices=tuple(SCHEDULES), default=None,
                    help='a named time variation of the true motor parameters (chapter4: seed '
                         '000 §4.3); breakpoints of your own go in the run file')
    ap.add_argument('--T-s', dest='T_s', type=float, default=None,
                    help='control period [s] (default 1e-4)')
    ap.add_argument('--duration', type=float, default=None,
                    help='simulated seconds (default: the task length, 2.0 / 1.5 s)')
    ap.add_argument('--v-limit', type=float, default=None,
                    help='inverter voltage limit [V] shared by plant and controller (0: none)')
    ap.add_argument('--motor', metavar='YAML',
                    help='motor file (ROS 2 parameters, /**: ros__parameters: R_s, R_r, L_s, L_r, '
                         'L_sr, pole_pairs, J, b, ...) or a shipped motor by name (thesis, '
                         'krause_3hp, krause_50hp: share/im_common/config/motors/); every node '
                         'uses it (default: the thesis motor)')
    ap.add_argument('--estimates', metavar='YAML',
                    help='a different motor file for the controller/observer/adapter model '
                         '(an explicit model mismatch; default: --motor)')
    ap.add_argument('--profile', metavar='FILE',
                    help='setpoints of your own: YAML "setpoints: '
                    '[{t: 0.0, velocity: 100.0}, ...]" '
                         '(position/velocity/effort as on /im/setpoint) or a sampled CSV '
                         '"t,velocity"; the task must match its kind (effort: --task torque)')
    ap.add_argument('--load', metavar='YAML',
                    help='shaft load: YAML {kind: linear, c1: 1.0, c2: 0.001} (kinds none, '
                         "constant tau, pendulum mgl, linear c1 c2); default: the task's load")
    ap.add_argument('--torque-limit', type=float, default=None,
                    help='|tau*| bound [N m] (0: none)')
    ap.add_argument('--current-limit', type=float, default=None,
                    help='stator-current magnitude the torque demand may ask for [A] (0: none)')
    ap.add_argument('--speed-limit', type=float, default=None,
                    help='no torque pushes the shaft beyond this speed [rad/s] (0: none)')
    ap.add_argument('--current-trip', type=float, default=None,
                    help='plant protection: zero voltage above this |i_s| [A] (0: off)')
    ap.add_argument('--speed-trip', type=float, default=None,
                    help='plant protection: zero voltage above this |omega_r| [rad/s] (0: off)')
    ap.add_argument('--sensorless', action='store_true', default=None,
                    help="speed-sensorless: controller, observer and adapter use the observer's "
                         'speed estimate, not the measured shaft (speed and torque tasks; '
                         'docs/sensorless.md)')
    ap.add_argument('--gains', metavar='YAML',
                    help='parameters YAML from `design_gains` (controller current gain, observer '
                         "injection gain): the run file's gains")
    ap.add_argument('--params-file', metavar='YAML',
                    help="extra node parameters to merge (the run file's parameters)")


def _add_output_options(ap: argparse.ArgumentParser) -> None:
    """Add the options of what a run writes and how it runs, from ``--record`` on."""
    ap.add_argument('--record', metavar='MCAP', help='record every topic to this MCAP file')
    ap.add_argument('--force', action='store_true', help='overwrite an existing recording')
    ap.add_argument('--log-time', choices=('wall', 'simulated'), default='wall',
                    help="the recording's log times: wall (default) offsets them to the "
                         'wall-clock time the recording started, so viewers show the run at its '
                         'date; simulated: log time = stamp. Stamps are simulated time either '
                         'way (docs/recording.md)')
    ap.add_argument('--report', metavar='DIR', help='write the report of the recording here')
    ap.add_argument('--summary', metavar='JSON',
                    help='summary file (default: next to the '
                    'recording, or bags/<task>_<strategy>.json)')
    ap.add_argument('--write-params', metavar='YAML',
                    help='only write the node parameters of this '
                    'scenario (for the launch file) and exit')
    ap.add_argument('--processes', action='store_true',
                    help='run every node as its own process, started as the launch file starts '
                         'them, with the recorder (needs --record); logs next to the recording')
    ap.add_argument('--live', action='store_true',
                    help='serve the running graph to Foxglove (WebSocket, ws://127.0.0.1:8765; '
                         'layout: share/im_bringup/config/foxglove/drive.json)')
    ap.add_argument('--live-port', type=int, default=None, metavar='PORT',
                    help="the live view's port (default 8765, as foxglove_bridge)")
    ap.add_argument('--domain-id', type=int, default=None,
                    help='ROS domain (default: $ROS_DOMAIN_ID, 0 when unset, as every ROS 2 '
                         'tool)')
    ap.add_argument('--no-progress', action='store_true')


def merge_yaml(parameters: dict, path: str) -> dict:
    """
    Merge a ROS 2 parameters YAML (node: {ros__parameters: {...}}) over ``parameters``.

    A file that cannot be used is one :class:`im_common.yamlio.ParametersFileError`
    (ValueError) naming it, the same line the launch file and the node executables give.
    """
    for name, values in load_parameters_file(path, nodes=parameters).items():
        parameters[name].update(values)
    return parameters


def git_revision() -> str:
    try:
        here = os.path.dirname(os.path.abspath(__file__))
        return subprocess.run(['git', 'rev-parse', 'HEAD'], cwd=here, capture_output=True,
                              text=True, timeout=5).stdout.strip() or 'unknown'
    except (OSError, subprocess.SubprocessError):
        return 'unknown'


def package_versions() -> dict:
    out = {}
    for dist in ('ros-jazzy-rclpy', 'ros-jazzy-common-interfaces', 'ros-rclpy',
                 'ros-common-interfaces', 'ros-rmw-fastrtps-cpp', 'numpy', 'scipy', 'mcap',
                 'rosbags'):
        try:
            out[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            out[dist] = 'not installed'
    return out


def run_metadata(task: str, strategy: str, controller: str, variation: str,
                 extra: Optional[dict] = None, scenario=None) -> dict:
    """
    Return the named metadata records of a scenario's recording.

    ``scenario``, ``run`` (the resolved run file, ``{'yaml': text}``, when ``scenario`` is
    given), ``versions``, ``git`` (and ``extra``) — as strings: the one source for the
    in-process bag and for the ``--processes`` recorder (``record --metadata``).
    ``parameters/<node>`` come from the running nodes, ``recorder`` and ``recording`` from the
    recording itself (:class:`im_recording.session.RecordingSession`).
    """
    meta = {'scenario': {'task': task, 'strategy': strategy, 'controller': controller,
                         'variation': variation},
            'versions': package_versions(), 'git': {'revision': git_revision()}}
    if scenario is not None:
        meta['run'] = {'yaml': scenario.to_yaml()}
    meta.update(extra or {})
    return {k: {kk: str(vv) for kk, vv in v.items()} for k, v in meta.items()}


def launch_processes(arguments: Mapping[str, str]) -> list:
    """
    Return the processes ``ros2 launch im_bringup drive.launch.py`` starts for its arguments.

    The arguments are strings as launch gives them, '' = not given: the ``run`` file, overridden
    by the scenario
    arguments given (``task``, ``strategy``, ``controller``, ``T_s``, ``duration``, ``mode``,
    ``sensorless``, ``gains``, ``params_file``), with the recorder when ``record`` names a file
    (the bag gets the ``run`` record, :func:`im_bringup.scenario.run_metadata`) and the live view
    when ``live`` is ``true``.
    """
    a = {k: str(v) for k, v in arguments.items()}
    over = {key: yaml.safe_load(a[key])
            for key in ('task', 'strategy', 'controller', 'T_s', 'duration', 'mode', 'sensorless')
            if a.get(key)}
    over.update({('parameters' if key == 'params_file' else key): os.path.abspath(a[key])
                 for key in ('gains', 'params_file') if a.get(key)})
    sc = (Scenario.from_file(a['run'], overrides=over, override_source='launch arguments')
          if a.get('run') else
          Scenario.from_mapping({}, source='launch arguments', overrides=over,
                                override_source='launch arguments'))
    record = a.get('record') or None
    from im_bringup.live import DEFAULT_PORT  # heavy: im_bringup.live imports the ROS messages
    live = a.get('live', '').lower() == 'true'
    procs = graph_processes(
        scenario=sc, mode=sc.mode, record=record, live_port=DEFAULT_PORT if live else None,
        log_time=a.get('log_time') or 'wall',
        use_adapter={'': None, 'true': True, 'false': False}[a.get('use_adapter', '').lower()],
        record_metadata=run_metadata(sc.task, sc.strategy, sc.controller, sc.variation_label,
                                     scenario=sc) if record else None)
    if record and a.get('force', '').lower() == 'true':     # force:=true
        for p in procs:
            if p.name == 'recorder':
                p.arguments.append('--force')
    return procs


#: launch arguments that name an output, and what each is
LAUNCH_OUTPUTS = (('record', 'record:= file'), ('summary', 'summary:= file'),
                  ('report', 'report:= directory'))


def check_launch_outputs(arguments: Mapping[str, str]) -> None:
    """
    Refuse, before any process starts, a launch whose outputs cannot be written.

    Every output the launch arguments name (``record``; ``summary`` and ``report`` where the
    launch has them) is checked as ``scenario`` checks its own: an existing file without
    ``force:=true`` (the recording's interrupted ``.part`` too), a directory, an output that is
    also an input (``run``, ``gains``, ``params_file``), one that cannot be created. One
    :class:`FileExistsError` or :class:`OSError` line naming the argument and the file; the
    launch file raises it before it returns a single node, so ``ros2 launch`` exits non-zero
    without starting one.
    """
    # heavy: im_recording imports the ROS message packages
    from im_recording.bag import check_output, partial_path
    a = {k: str(v) for k, v in arguments.items()}
    force = a.get('force', '').lower() == 'true'
    inputs = [os.path.abspath(a[k]) for k in ('run', 'gains', 'params_file') if a.get(k)]
    for key, what in LAUNCH_OUTPUTS:
        if not a.get(key):
            continue
        out = a[key] if key != 'report' else os.path.join(a[key], 'report.md')
        paths = [(out, what)]
        if key == 'record':
            paths.append((str(partial_path(out)), 'interrupted recording of record:= (recover '
                                                  'it, or force:=true)'))
        for path, name in paths:
            if os.path.lexists(path) and not os.path.isdir(path) and not force:
                raise FileExistsError(f'{path}: the {name} exists; refusing to overwrite it '
                                      '(pass force:=true)')
            check_output(path, inputs, force=True, what=name)


def run_scenario(run, *, record: Optional[str] = None, force: bool = False,
                 progress: bool = True, domain_id: Optional[int] = None,
                 metadata: Optional[dict] = None, live_port: Optional[int] = None,
                 log_time: str = 'wall') -> dict:
    """
    Run ``run`` (a :class:`~im_bringup.run_file.Scenario`) through the lock-step graph.

    Return its summary (figures of merit). The graph's parameters, the summary's task,
    strategy, controller and variation and the bag's ``run`` record all come from ``run``.
    ``log_time``: the recording's log times, ``wall`` or ``simulated``
    (:func:`im_recording.bag.log_time_offset_for`). ``domain_id``: the ROS domain (default
    ``ROS_DOMAIN_ID``). ``live_port``: serve every message live on that port too
    (:mod:`im_bringup.live`).
    """
    parameters = run.node_parameters()
    task, strategy, controller = run.task, run.strategy, run.controller
    variation = plant_variation(parameters)
    # heavy: the in-process graph imports rclpy, im_recording the ROS message packages
    from im_bringup.graph import DriveGraph
    from im_recording.recorded_run import load_step_time
    from im_recording.traces import Tap
    writer = None
    if record:
        # heavy: im_recording imports the ROS message packages
        from im_recording.bag import BagWriter, log_time_offset_for
        writer = BagWriter(record, force=force, metadata=run_metadata(
            task, strategy, controller, variation, metadata, scenario=run),
            log_time_offset_ns=log_time_offset_for(log_time))
    # bounded memory: running figures (a load step's too), no per-step trace
    sink = Tap(writer, keep=False, load_step=load_step_time(parameters=parameters),
               held=held_estimates(parameters))
    sink, view = _live(sink, live_port, writer)
    graph = None
    with StopSignals() as stop:         # a signal only sets a flag: nothing is cut mid-write
        try:
            graph = DriveGraph(parameters, recorder=sink, domain_id=domain_id)
            sink.on_error = lambda line: graph.fail('recorder', line)   # e.g. the disk is full
            if stop.requested:
                stats = {'steps': 0, 'wall_s': 0.0, 'steps_per_s': float('nan'),
                         'failures': {}, 'ok': True}
            else:
                stats = graph.run(progress=progress, stop=stop)
        finally:
            if graph is not None:
                graph.close()
            if view is not None:
                if graph is not None:       # the last messages reach the viewers
                    from im_bringup.live import END_GRACE_S  # heavy: the ROS messages
                    time.sleep(END_GRACE_S)
                view.close()
            if writer is not None and graph is None:    # refused before the run: no file
                writer.discard()
            elif writer is not None and not writer.failed:
                _record_refusals(writer, graph)
                sink.close(stop.requested)      # the 'recording' record: interrupted or not
        signal = stop.requested
    summary = summarize(parameters, stats, sink, task=task, strategy=strategy,
                        controller=controller, variation=variation)
    return _ending(summary, signal, record, writer)


def _live(sink, live_port: Optional[int], writer):
    """Return (the sink, the live view): the sink served on ``live_port`` too, if given."""
    if live_port is None:
        return sink, None
    from im_bringup.live import LiveTap, LiveView  # heavy: imports the ROS messages
    try:
        view = LiveView(port=live_port)
    except OSError:
        if writer is not None:
            writer.discard()
        raise
    print(f'live view: {view.url} (Foxglove: Open connection, Foxglove WebSocket)',
          file=sys.stderr, flush=True)
    return LiveTap(sink, view), view


def _ending(summary: dict, signal, record: Optional[str], writer) -> dict:
    """Add how the run ended to its summary: interrupted, its bag, a failed recording."""
    if signal is not None:
        summary['interrupted'] = signal
        summary['failures'] = {'run': f'interrupted by {signal}'}
    if record:
        summary['bag'] = record
    if writer is not None and writer.failed:   # its .part holds what was written (recover)
        summary['bag'] = None
        summary['partial_recording'] = str(writer.part)
        summary['ok'] = False
        summary.setdefault('failures', {})['recorder'] = str(writer.failed)
    if not summary.get('ok', True) or signal is not None:
        summary['partial'] = True       # the figures are those of the steps that ran
    return summary


def _record_refusals(writer, graph) -> None:
    """
    Write the nodes' counts of messages not signed by this graph, and who sent them, to the bag.

    The in-process tap records only the graph's own messages; the ``refusals`` record keeps what
    the nodes refused (:func:`im_recording.report.refusals` reads it).
    """
    record = {}
    for name, node in graph.nodes.items():
        for topic, n in getattr(node, 'refused_by_topic', {}).items():
            record[f'refused_unsigned/{name}{topic}'] = str(n)
        for topic, pubs in getattr(node, 'foreign', {}).items():
            if pubs:
                record[f'foreign_publishers/{name}{topic}'] = ' '.join(sorted(pubs))
    if record:
        writer.add_metadata('refusals', record)


def held_estimates(parameters: dict) -> dict:
    """
    Return the estimates a run without an adapter holds: its controller's model ({}: adaptive).

    The summary then compares them with the truth as an adaptive run's (``<n>_hat_final``,
    ``<n>_true_final``, :func:`im_recording.recorded_run.held_model_estimates`), so rows compare.
    """
    # heavy: im_recording imports the ROS message packages
    from im_recording.recorded_run import held_model_estimates
    if parameters.get('controller', {}).get('use_adapter'):
        return {}
    return held_model_estimates(parameters['controller'])


def summarize(parameters: dict, stats: dict, tap, *, task: str, strategy: str,
              controller: str, variation: str) -> dict:
    """
    Return the figures of merit of a graph run, plus the run's statistics.

    They are computed from the captured messages by the report's own code
    (:func:`im_recording.report.figures_of_merit`).
    """
    # heavy: im_recording imports the ROS message packages
    from im_recording.report import figures_of_merit
    T_s = parameters['plant']['T_s']
    run = tap.run(metadata={'scenario': {'task': task}})
    summary = {'task': task, 'strategy': strategy, 'controller': controller,
               'variation': variation, 'rate_hz': round(1.0 / T_s, 6)}
    summary.update(figures_of_merit(run))
    summary.update({'steps': stats['steps'], 'wall_s': stats['wall_s'],
                    'steps_per_s': stats['steps_per_s'], 'ok': stats['ok'],
                    'failures': stats['failures']})
    for k, v in stats.items():          # anything else the graph counts (e.g. rejected inputs)
        summary.setdefault(k, v)
    gaps = run.running.gaps() if run.running is not None else {}
    if gaps:
        summary['lockstep_gaps'] = gaps
    if run.late:
        summary['late_messages'] = run.late
    summary['_run'] = run
    return summary


def rclpy_errors():
    from rclpy.exceptions import InvalidParameterValueException  # heavy: rclpy only for a graph
    return InvalidParameterValueException


def print_summary(s: dict) -> None:
    keys = ['E_in_J', 'E_dc_J', 'E_inverter_J', 'E_switching_J', 'E_loss_J', 'E_copper_J',
            'E_core_J', 'W_load_J', 'E_friction_J',
            'dE_kinetic_J', 'dW_magnetic_J', 'balance_residual_J', 'pos_err_max_rad',
            'pos_err_rms_rad', 'speed_err_max_rad_s', 'speed_dip_rad_s', 'speed_recovery_s',
            'torque_err_max_Nm', 'V_max_V', 'i_max_A',
            'steps', 'wall_s', 'steps_per_s']
    print(f"{s['task']} task, {s['strategy']}, {s['controller']} controller, "
          f"{s['rate_hz']:g} Hz, variation {s['variation']}")
    for k in keys:
        if k in s:
            print(f'  {k:22s} {s[k]:14.6g}')
    for node, topics in s.get('refused_unsigned', {}).items():
        print(f'  refused by {node} (not signed by this graph): '
              + ', '.join(f'{n} on {t}' for t, n in topics.items()))
    for node, topics in s.get('foreign_publishers', {}).items():
        print(f'  foreign publishers seen by {node}: '
              + '; '.join(f"{t}: {', '.join(names)}" for t, names in topics.items()))


#: scenario options that override the run-file key of the same name
OVERRIDE_OPTIONS = ('task', 'strategy', 'controller', 'variation', 'T_s', 'duration', 'v_limit',
                    'motor', 'estimates', 'profile', 'load', 'torque_limit', 'current_limit',
                    'speed_limit', 'current_trip', 'speed_trip', 'sensorless', 'gains')
FILE_OPTIONS = ('motor', 'estimates', 'profile', 'load', 'gains', 'params_file')


def plant_variation(parameters: dict) -> str:
    """
    Return the variation the plant will really run, from its parameters.

    A ``parameters:``/``--params-file`` override of the plant included: what the summary and
    header say.
    """
    plant = parameters.get('plant', {})
    name = plant.get('variation', 'none')
    if name == 'schedule':
        return describe_variation(variation_from_parameters(plant) or {})
    if name == 'custom':
        return (f"custom {plant.get('variation_parameter', 'R_r')} "
                f"{plant.get('variation_kind', 'ramp')}")
    return name


def rerun_mapping(bag: str) -> dict:
    """
    Return the run file a bag carries (its ``run`` record), as a mapping.

    One ValueError line when the bag has none (recorded before run files, or not by this
    stack) or when it does not parse; a BagError line when the bag's data section, where the
    record lives, fails its CRC (a damaged record is never re-run as if it were the run).
    """
    # heavy: im_recording imports the ROS message packages
    from im_recording.bag import check_data_crc, info
    meta = info(bag).metadata
    check_data_crc(bag)
    if 'run' not in meta or 'yaml' not in meta['run']:
        raise ValueError(f'{bag}: no "run" record (recorded before run files existed, or not by '
                         'the scenario runner); cannot re-run it')
    try:
        doc = yaml.safe_load(meta['run']['yaml'])
    except yaml.YAMLError as exc:
        raise ValueError(f'{bag}: its "run" record is {yaml_problem(exc)}; cannot re-run it') \
            from None
    if not isinstance(doc, dict):
        raise ValueError(f'{bag}: its "run" record is not a mapping of run-file keys; '
                         'cannot re-run it')
    return doc


def scenario_from_args(args):
    """
    Return the :class:`~im_bringup.run_file.Scenario` of the command line.

    The run file (or the bag's ``run`` record with ``--rerun``), overridden by the options
    given and ``--set``.
    """
    over = {}
    for key in OVERRIDE_OPTIONS + ('params_file',):
        value = getattr(args, key, None)
        if value is None:
            continue
        if key in FILE_OPTIONS and not (key in ('motor', 'estimates') and is_motor_name(value)
                                        and not os.path.isfile(value)):   # a shipped motor
            value = os.path.abspath(value)
        over['parameters' if key == 'params_file' else key] = value
    for item in args.set:
        key, eq, text = item.partition('=')
        if not eq or not key:
            raise RunFileError('--set', item, 'must be KEY=VALUE')
        try:
            over[key.strip()] = yaml.safe_load(text)
        except yaml.YAMLError as exc:
            raise RunFileError('--set', key, f'value is not YAML ({str(exc).splitlines()[0]})') \
                from None
    if args.rerun:
        if args.run:
            raise RunFileError('--rerun', args.rerun, 'takes no run file besides the bag')
        return Scenario.from_mapping(rerun_mapping(args.rerun), source=f'{args.rerun} (run)',
                                     overrides=over)
    if args.run:
        return Scenario.from_file(args.run, overrides=over)
    return Scenario.from_mapping({}, source='command line', overrides=over)


def main(argv=None) -> int:
    from im_recording.bag import BagError  # heavy: im_recording imports the ROS message packages
    args = parse_args(build_parser(), argv)
    try:
        sc = scenario_from_args(args)
        parameters = sc.node_parameters()
    except (ValueError, BagError) as exc:
        return cli_error('scenario', exc)
    args.task, args.strategy, args.controller = sc.task, sc.strategy, sc.controller
    args.T_s, args.duration, args.variation = sc.T_s, sc.duration, plant_variation(parameters)
    # heavy: im_recording imports the ROS message packages
    from im_recording.bag import check_output, write_atomic
    if args.write_params:
        try:
            check_output(args.write_params, [args.gains, args.params_file, args.run], args.force,
                         what='--write-params file')
            write_atomic(args.write_params, to_yaml(parameters))
        except OSError as exc:
            return cli_error('scenario', _os_line(exc, args.write_params))
        print(f'parameters written to {args.write_params}')
        return 0
    if args.processes and not args.record:       # a usage error, before any file is looked at
        return cli_error('scenario',
                         '--processes needs --record (the figures come from the recording)')
    try:
        args.domain_id = ros_domain_id(args.domain_id)
    except ValueError as exc:
        return cli_error('scenario', exc)
    if args.live or args.live_port is not None:
        from im_bringup.live import DEFAULT_PORT  # heavy: imports the ROS messages
        args.live_port = DEFAULT_PORT if args.live_port is None else args.live_port
    out = args.summary or (os.path.splitext(args.record)[0] + '.json' if args.record
                           else os.path.join('bags', f'{args.task}_{args.strategy}.json'))
    try:
        _check_outputs(args, out)
    except OSError as exc:
        return cli_error('scenario', exc)
    if args.processes:
        return _run_processes(args, sc, parameters, out)
    try:
        summary = run_scenario(sc, record=args.record, force=args.force,
                               progress=not args.no_progress, domain_id=args.domain_id,
                               live_port=args.live_port, log_time=args.log_time)
    except (ValueError, OSError, rclpy_errors()) as exc:
        return cli_error('scenario', exc)
    except BagError as exc:         # the recording failed before the run started
        return cli_error('scenario', exc, 1)
    summary.pop('_run', None)
    print_summary(summary)          # on the console even if the summary file cannot be written
    written = _write_summary(out, summary)
    if written:
        print(f'summary: {out}')
    if args.record and summary.get('bag'):
        print(f'recording: {args.record}')
    if summary.get('interrupted'):
        print(f"interrupted by {summary['interrupted']} after {summary['steps']} steps; the "
              'summary and the recording (if any) are complete up to there', file=sys.stderr)
        return exit_code_for(summary['interrupted'])
    if not summary['ok']:
        return cli_error('scenario', 'the run stopped early: ' + '; '.join(
            f'{n}: {r}' for n, r in summary['failures'].items()), 1)
    if not written:
        return 1
    if args.report and args.record:
        return _write_report(args.record, args.report)
    return 0


def _check_outputs(args, out: str) -> None:
    """Refuse (OSError) a recording, summary ``out`` or report that would overwrite a file."""
    # heavy: im_recording imports the ROS message packages
    from im_recording.bag import check_output, partial_path
    inputs = [args.gains, args.params_file, args.run, args.rerun]
    if args.record:
        if _same(args.record, out):
            raise FileExistsError(f'{out}: --record and --summary name the same file; '
                                  'choose two different files')
        check_output(args.record, inputs, args.force, what='--record file')
        check_output(partial_path(args.record), inputs, args.force,
                     what='interrupted recording (recover it, or --force)')
    check_output(out, inputs + [args.record], args.force, what='--summary file')
    if args.report:
        check_output(os.path.join(args.report, 'report.md'), inputs + [args.record],
                     args.force, what='report')


def _os_line(exc: OSError, path: str) -> str:
    """One line for an OS error on ``path`` (the file and the cause, no errno noise)."""
    if exc.strerror:
        return f'{exc.filename or path}: {exc.strerror}'
    return str(exc)


def _write_summary(out: str, summary: dict) -> bool:
    """Write the summary JSON; a write error (disk full, ...) is one line and False."""
    # heavy: im_recording imports the ROS message packages
    from im_recording.bag import write_atomic
    from im_recording.report import jsonable
    try:
        write_atomic(out, json.dumps(jsonable(summary), indent=2, allow_nan=False))
    except OSError as exc:
        cli_error('scenario', f'the summary cannot be written: {_os_line(exc, out)} (its figures '
                  'are printed above)')
        return False
    return True


def _write_report(record: str, report: str) -> int:
    from im_recording.bag import BagError  # heavy: im_recording imports the ROS message packages
    from im_recording.report import write_report
    try:
        write_report([record], report)
    except OSError as exc:
        return cli_error('scenario', f'the report cannot be written: {_os_line(exc, report)}', 1)
    except BagError as exc:
        return cli_error('scenario', exc, 1)
    print(f'report: {report}/')
    return 0


def _run_processes(args, sc, parameters: dict, out: str) -> int:
    """
    Run ``--processes``: the scenario's nodes as separate processes, plus the recorder.

    The scenario's nodes as separate processes (``im_bringup.processes``, what ``ros2 launch
    im_bringup drive.launch.py`` starts) plus the recorder; the figures come from the
    recording, by the report's own code.
    """
    # heavy: im_common.lockstep imports rclpy, im_recording the ROS message packages
    from im_common.lockstep import ConfigurationError
    from im_recording.bag import partial_path
    procs = graph_processes(scenario=sc, mode=parameters['plant'].get('mode', 'lockstep'),
                            record=args.record, extra=parameters, live_port=args.live_port,
                            log_time=args.log_time,
                            record_metadata=run_metadata(args.task, args.strategy,
                                                         args.controller, args.variation,
                                                         scenario=sc))
    try:            # what a node's own process would refuse, before any process starts
        check_processes(procs)
    except ConfigurationError as exc:
        return cli_error('scenario', exc)
    for p in procs:
        if p.name == 'recorder' and args.force:
            p.arguments.append('--force')
    logs = os.path.splitext(args.record)[0] + '_logs'
    with StopSignals() as stop:
        codes = run_processes(procs, logs, timeout=24 * 3600.0,
                              env={'ROS_DOMAIN_ID': str(args.domain_id)},
                              progress=not args.no_progress, stop=stop)
    summary = {'task': args.task, 'strategy': args.strategy, 'controller': args.controller,
               'variation': args.variation, 'rate_hz': round(1.0 / args.T_s, 6),
               'processes': codes, 'logs': logs, 'ok': all(c == 0 for c in codes.values())}
    if stop.requested:              # as in one process; the figures are those of the steps run
        summary.update(interrupted=stop.requested, partial=True,
                       failures={'run': f'interrupted by {stop.requested}'})
    failure = failure_line(logs, codes)
    if failure:
        summary['failures'] = {failure.split(':', 1)[0]: failure.split(': ', 1)[-1]}
    lost = {n: c for n, c in codes.items() if c not in (None, 0) and not ends_graph(n, c)}
    if lost and not any(ends_graph(n, c) for n, c in codes.items()):
        # the run went on to its end without them (docs/guarantees.md): said once during the
        # run; the summary and the exit code say that its recording is not the whole run
        part = str(partial_path(args.record))
        failure = f'the run went on to its end without it: {failure}'
        if 'recorder' in lost and part not in failure and os.path.exists(part):
            failure += (f'; what the recorder wrote up to then is in {part}: '
                        f'`ros2 run im_recording recover {part}`')
    failure = _recorded_figures(args.record, summary, stop.requested, failure)
    if not summary['ok']:
        summary['partial'] = True       # the figures are those of the steps that ran
    print_summary(summary)
    written = _write_summary(out, summary)
    if written:
        print(f'summary: {out}')
    print(f'logs: {logs}/')
    if os.path.exists(args.record):
        print(f'recording: {args.record}')
    if not summary['ok']:
        return cli_error('scenario', failure or f'exit codes {codes} (see {logs}/<node>.log)', 1)
    if stop.requested:          # as in one process: the user's stop, not a failure
        print(f'interrupted by {stop.requested}; the summary and the recording (if any) are '
              'complete up to there', file=sys.stderr)
        return exit_code_for(stop.requested)
    if not written:
        return 1
    if args.report:
        return _write_report(args.record, args.report)
    return 0


def _recorded_figures(record: str, summary: dict, stopped, failure):
    """
    Add the figures of the recording ``record`` (else of its partial file) to ``summary``.

    Returns ``failure``, or the early stop the recording shows when every process ended
    cleanly (``stopped``: no stop signal).
    """
    # heavy: im_recording imports the ROS message packages
    from im_recording.bag import BagError, partial_path
    from im_recording.recover import load_salvaged
    from im_recording.report import figures_of_merit, refusals, run_status
    from im_recording.recorded_run import load_run
    if os.path.exists(record):
        run = load_run(record)
        fig = figures_of_merit(run)
        summary.update(fig)
        # as the in-process graph counts them, per node and topic, and who sent them
        summary.update({k: v for k, v in refusals(run).items() if v})
        status = run_status(run, fig)
        if summary['ok'] and status['partial'] and not stopped:
            # every process ended cleanly, but before the run's end: a node stopped it (a Ctrl-C
            # to one of them) — the recording says so, and so do the summary and the exit code
            summary['ok'] = False
            failure = 'the run stopped early: ' + '; '.join(status['notes'])
            summary['failures'] = {'run': failure}
    elif partial_path(record).exists():     # the recorder failed: recover reads it
        summary['partial_recording'] = str(partial_path(record))
        try:            # the figures of every step that reached the disk
            run, _ = load_salvaged(partial_path(record))
            summary.update(figures_of_merit(run))
            summary.update({k: v for k, v in refusals(run).items() if v})
        except (BagError, OSError) as exc:
            summary['partial_figures'] = f'none: {exc}'
    return failure


def _same(a: str, b: str) -> bool:
    return os.path.realpath(a) == os.path.realpath(b)


if __name__ == '__main__':
    sys.exit(main())
