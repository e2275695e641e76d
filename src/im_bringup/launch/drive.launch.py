"""
Jazzy launch file: the drive graph as separate processes.

    ros2 launch im_bringup drive.launch.py [run:=RUN.yaml] [task:=position|speed]
        [strategy:=min_energy|...]
        [controller:=nominal|adaptive|adaptive_thesis|adaptive_thesis_pair|robust|current_vector|flux_vector|vhz]
        [T_s:=0.0001] [duration:=2.0]
        [mode:=lockstep|free_run] [use_adapter:=true|false] [record:=bags/run.mcap]
        [force:=true]
        [gains:=FILE.yaml] [params_file:=FILE.yaml] [security:=true] [sensorless:=true]
        [live:=true]

``run`` names a run file (docs/running.md: the run's every key, variation and noise included);
the scenario arguments given (task, strategy, controller, T_s, duration, mode, gains, params_file,
sensorless) override its keys, as ``scenario RUN.yaml --task ...`` does.
Which processes start, with which parameters, comes from :func:`im_bringup.processes.
graph_processes` — the same description the project's tests start the graph from: plant,
controller, observer; the adapter when the controller uses it; the recorder (a lossless follower)
when ``record`` names a file, and the plant then waits for it before step 0; the live view
(:mod:`im_bringup.live`, Foxglove's WebSocket protocol on port 8765) with ``live:=true``. ``gains``
and ``params_file`` are ROS 2 parameters files merged over the scenario's parameters (``gains``
e.g. ``$(ros2 pkg prefix im_bringup)/share/im_bringup/config/gains_1ms.yaml`` with ``T_s:=0.001``,
which ``mode:=free_run`` needs). The parameters are checked before any process starts, by the
nodes' own checks (:func:`im_bringup.processes.check_processes`): a bad file or value is launch's
one "Caught exception" line naming the node and parameter; so is an output that exists (without
``force:=true``) or cannot be written (:func:`im_bringup.scenario.check_launch_outputs`); a
process that still exits with an error shuts the whole launch down at once, but for the recorder
and the live view (off the critical path): one that dies during the run is one line, and the run
goes on without it (unrecorded, docs/guarantees.md). Ctrl-C stops every
process cleanly (exit 0) and closes the recording.
Discovery stays on this host (``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``) unless that variable is
already set (``SUBNET`` opens the graph to other machines on purpose). Every launch makes a fresh
graph key: the nodes refuse lock-step messages and run events of anyone else (docs/security.md).

Needs a full ROS 2 Jazzy install (``launch``/``launch_ros`` are not on PyPI); nothing in the test
suite imports this file.
"""
from launch import LaunchDescription
from launch.actions import (DeclareLaunchArgument, EmitEvent, LogInfo, OpaqueFunction,
                            RegisterEventHandler, SetEnvironmentVariable)
from launch.event_handlers import OnProcessExit
from launch.events import Shutdown
from launch.substitutions import EnvironmentVariable, LaunchConfiguration
from launch_ros.actions import Node

ARGUMENTS = (
    ('run', '', 'run file (docs/running.md); the arguments below that are given override it'),
    ('task', '', 'position (default), speed or torque (seed 000 §3.4.4-3.4.5)'),
    ('strategy', '', 'flux strategy: min_energy (default), constant_flux, min_loss or optimal'),
    ('controller', '', 'nominal (default), adaptive (improved law, inverse-Gamma feed), '
                   'adaptive_thesis (thesis law), adaptive_thesis_pair (improved law, thesis '
                   "pair feed), robust, or a baseline law in the thesis law's place: "
                   'current_vector, flux_vector, vhz (docs/baselines.md)'),
    ('T_s', '', 'control period [s] (default 0.0001)'),
    ('duration', '', 'simulated seconds (empty: the task length)'),
    ('mode', '', 'lockstep (default, simulated time) or free_run (wall-clock fixed rate)'),
    ('use_adapter', '', 'true/false: controller and observer use the adapter (empty: as '
                        'the controller argument implies)'),
    ('record', '', 'MCAP file to record the run to (empty: no recorder)'),
    ('log_time', 'wall', "the recording's log times: wall (offset to the wall-clock time it "
                         'started, so viewers show the run at its date) or simulated (log time = '
                         'stamp); stamps are simulated time either way'),
    ('force', 'false', 'true: overwrite existing outputs (record; otherwise the launch refuses '
                       'them before any node starts)'),
    ('gains', '', 'parameters YAML from design_gains (current and observer gains)'),
    ('params_file', '', 'extra parameters YAML merged last'),
    ('sensorless', '', 'true: speed-sensorless, controller/observer/adapter use the '
                       "observer's speed estimate, not the measured shaft (speed and torque "
                       'tasks; docs/sensorless.md)'),
    ('live', 'false', 'true: serve the running graph to Foxglove on ws://127.0.0.1:8765 (layout: '
                      'share/im_bringup/config/foxglove/drive.json; docs/commands.md)'),
    ('security', 'false', 'true: start each node in its SROS2 enclave /im_drive/<node> (needs a '
                          'keystore from config/sros2/policy.xml and a middleware with DDS '
                          'security; docs/security.md)'),
)


def _processes(context):
    from im_bringup.processes import check_processes
    from im_bringup.scenario import check_launch_outputs, launch_processes
    a = {name: LaunchConfiguration(name).perform(context) for name, _, _ in ARGUMENTS}
    check_launch_outputs(a)     # every output writable (or force:=true), before any node starts
    procs = launch_processes(a)     # with a fresh graph key, removed when ros2 launch exits
    check_processes(procs)      # what a node would refuse, refused before any process starts
    secure = a['security'].lower() == 'true'
    return [Node(package=p.package, executable=p.executable, name=p.name,
                 parameters=[p.parameters] if p.parameters else [], arguments=p.arguments,
                 ros_arguments=['--enclave', f'/im_drive/{p.name}'] if secure else [],
                 output='screen', sigterm_timeout='10', sigkill_timeout='5')
            for p in procs]


def _node_name(event) -> str:
    """Return the graph's name of the node whose process exited (``recorder``), or its process."""
    from im_bringup.processes import EXECUTABLES
    try:
        return event.action.node_name.rsplit('/', 1)[-1]
    except (AttributeError, RuntimeError):
        process = getattr(event, 'process_name', None) or 'a node'     # e.g. 'record-5'
        exe = process.rsplit('-', 1)[0]
        return next((n for n, (_, e) in EXECUTABLES.items() if e == exe), process)


def _stop_on_failure(event, _context):
    """
    End the launch at once when a node exits with an error (a refused configuration: 2).

    The others do not wait out their startup timeout for it. A process off the critical path
    (the recorder, the live view: :func:`im_bringup.processes.ends_graph`) that dies during the
    run does not end it: one line says so and the run goes on to its end (docs/guarantees.md).
    """
    from im_bringup.processes import ends_graph, lost_line
    if not event.returncode:
        return None
    name = _node_name(event)
    if not ends_graph(name, event.returncode):
        return [LogInfo(msg=lost_line(name, event.returncode,
                                      [str(a) for a in (getattr(event, 'cmd', None) or [])]))]
    return [EmitEvent(event=Shutdown(reason=f'{name} exited with code {event.returncode}'))]


def generate_launch_description():
    return LaunchDescription(
        [DeclareLaunchArgument(name, default_value=default, description=doc)
         for name, default, doc in ARGUMENTS]
        # discovery stays on this host unless the user opened it on purpose
        + [SetEnvironmentVariable('ROS_AUTOMATIC_DISCOVERY_RANGE', EnvironmentVariable(
            'ROS_AUTOMATIC_DISCOVERY_RANGE', default_value='LOCALHOST')),
           RegisterEventHandler(OnProcessExit(on_exit=_stop_on_failure)),
           OpaqueFunction(function=_processes)])
