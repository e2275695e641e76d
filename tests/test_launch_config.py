"""
The launch file and the process supervisor start the same graph.

The launch file and the project's own process supervisor start the same graph (one description,
:func:`im_bringup.processes.graph_processes`), and the shipped example YAML is the scenario
mapping's output (no drift).
"""
import ast
import os

from im_bringup.config import node_parameters
from im_bringup.processes import graph_processes, params_file_text
import pytest
import yaml

HERE = os.path.dirname(os.path.abspath(__file__))
SHIPPED = os.path.join(HERE, '..', 'src', 'im_bringup', 'config', 'drive.yaml')
LAUNCH = os.path.join(HERE, '..', 'src', 'im_bringup', 'launch', 'drive.launch.py')


def test_shipped_yaml_matches_the_scenario_mapping():
    with open(SHIPPED) as f:
        doc = yaml.safe_load(f)
    expected = node_parameters('position', 'min_energy')
    assert set(doc) == set(expected)
    for node, values in expected.items():
        got = dict(doc[node]['ros__parameters'])
        if node != 'plant':
            assert got.pop('use_sim_time') is True
        assert got == values, node


def test_launch_file_declares_the_arguments_and_uses_the_one_description():
    src = open(LAUNCH).read()
    tree = ast.parse(src)          # valid Python, without importing launch
    args = next(n for n in ast.walk(tree) if isinstance(n, ast.Assign)
                and getattr(n.targets[0], 'id', '') == 'ARGUMENTS')
    names = {elt.elts[0].value for elt in args.value.elts}
    assert {'task', 'strategy', 'controller', 'T_s', 'duration', 'mode', 'use_adapter',
            'record'} <= names
    assert 'launch_processes' in src and 'OpaqueFunction' in src


def test_graph_processes_starts_what_the_run_needs():
    names = [p.name for p in graph_processes('position', 'min_energy')]
    assert names == ['plant', 'controller', 'observer']
    procs = {p.name: p for p in graph_processes('speed', 'min_loss', controller='adaptive',
                                                record='x.mcap', mode='free_run')}
    assert set(procs) == {'plant', 'controller', 'observer', 'adapter', 'recorder'}
    assert procs['plant'].parameters['wait_for'] == 'controller observer adapter recorder'
    assert procs['plant'].parameters['mode'] == 'free_run'
    assert procs['controller'].parameters['use_adapter'] is True
    assert procs['recorder'].arguments == ['--out', 'x.mcap', '--log-time', 'wall']
    on = {p.name: p for p in graph_processes('position', 'min_energy', use_adapter=True)}
    assert 'adapter' in on and on['adapter'].parameters['enable'] is True
    with pytest.raises(ValueError, match='mode'):
        graph_processes(mode='fast')
    with pytest.raises(ValueError, match="unknown node 'plnt'"):
        graph_processes(extra={'plnt': {'T_s': 1.0}})


def test_params_file_is_what_launch_ros_writes():
    text = params_file_text({'T_s': 0.001, 'mode': 'free_run'})
    expected = {'T_s': 0.001, 'mode': 'free_run'}
    assert yaml.safe_load(text) == {'/**': {'ros__parameters': expected}}


@pytest.mark.processes
def test_the_launch_files_parameter_check_reads_no_ros_arguments_from_its_command_line():
    """
    ``ros2 launch im_bringup drive.launch.py task:=speed strategy:=min_loss``: no rcl warning.

    The launch file checks the nodes' parameters in the launch process itself
    (:func:`im_bringup.processes.check_processes`); rcl must not take the launch arguments on its
    command line for remap rules ("Found remap rule 'task:=speed'. This syntax is deprecated").
    """
    import subprocess
    import sys
    argv = ['ros2', 'launch', 'im_bringup', 'drive.launch.py', 'task:=speed',
            'strategy:=min_loss', 'duration:=0.1']
    code = (f'import sys; sys.argv = {argv!r}\n'
            'from im_bringup.processes import check_processes\n'
            'from im_bringup.scenario import launch_processes\n'
            "a = dict(arg.split(':=') for arg in sys.argv[4:])\n"
            'check_processes(launch_processes(a))\n'
            "print('checked')\n")
    r = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, timeout=120,
                       env=dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path)))  # this tree
    assert r.returncode == 0 and r.stdout.strip() == 'checked', r.stderr[-2000:]
    assert r.stderr == '', r.stderr


def test_live_true_adds_the_live_view_started_first():
    """``live:=true``: the ``live`` node on foxglove_bridge's port, started before the others."""
    from im_bringup.processes import START_ORDER
    from im_bringup.scenario import launch_processes
    procs = {p.name: p for p in launch_processes({'duration': '0.1', 'live': 'true'})}
    assert (procs['live'].package, procs['live'].executable) == ('im_bringup', 'live')
    assert procs['live'].arguments == ['--port', '8765'] and START_ORDER[0] == 'live'
    assert 'live' not in {p.name for p in launch_processes({'duration': '0.1', 'live': 'false'})}


def _launch_function(name):
    """Return the source of a function of the launch file (it imports launch, which tests lack)."""
    tree = ast.parse(open(LAUNCH).read())
    return next(n for n in ast.walk(tree) if isinstance(n, ast.FunctionDef) and n.name == name)


def test_launch_checks_every_output_before_it_returns_a_node():
    """
    ``ros2 launch ... record:=EXISTING``: refused before any node starts, ``force:=true`` offered.

    The launch file's OpaqueFunction checks the outputs first (an exception there is launch's
    one "Caught exception" line and a non-zero exit, no process started), and declares
    ``force``, which reaches the recorder.
    """
    fn = _launch_function('_processes')
    calls = [n.func.id for n in ast.walk(fn) if isinstance(n, ast.Call)
             and isinstance(n.func, ast.Name)]
    assert 'check_launch_outputs' in calls
    assert calls.index('check_launch_outputs') < calls.index('launch_processes')
    src = open(LAUNCH).read()
    tree = ast.parse(src)
    args = next(n for n in ast.walk(tree) if isinstance(n, ast.Assign)
                and getattr(n.targets[0], 'id', '') == 'ARGUMENTS')
    assert 'force' in {elt.elts[0].value for elt in args.value.elts}


def test_the_launch_output_check_refuses_in_one_line_and_force_overrides(tmp_path):
    from im_bringup.scenario import check_launch_outputs, launch_processes
    from im_recording.bag import partial_path
    rec = tmp_path / 'run.mcap'
    check_launch_outputs({'record': str(rec), 'force': 'false'})      # nothing there: fine
    rec.write_bytes(b'an earlier run')
    with pytest.raises(FileExistsError) as ei:
        check_launch_outputs({'record': str(rec), 'force': 'false'})
    line = str(ei.value)
    assert '\n' not in line and str(rec) in line and 'force:=true' in line, line
    check_launch_outputs({'record': str(rec), 'force': 'true'})
    rec.unlink()
    partial_path(rec).write_bytes(b'a killed run')
    with pytest.raises(FileExistsError, match='interrupted recording'):
        check_launch_outputs({'record': str(rec)})
    # an output that is an input, even with force; a directory; a report that exists
    run = tmp_path / 'run.yaml'
    run.write_text('task: speed\n')
    with pytest.raises(FileExistsError, match='also an input'):
        check_launch_outputs({'record': str(run), 'run': str(run), 'force': 'true'})
    with pytest.raises(FileExistsError, match='directory'):
        check_launch_outputs({'record': str(tmp_path)})
    (tmp_path / 'rep').mkdir()
    (tmp_path / 'rep' / 'report.md').write_text('old')
    with pytest.raises(FileExistsError, match='report'):
        check_launch_outputs({'report': str(tmp_path / 'rep')})
    # force:=true reaches the recorder
    procs = {p.name: p for p in launch_processes({'record': str(rec), 'force': 'true'})}
    assert '--force' in procs['recorder'].arguments
    procs = {p.name: p for p in launch_processes({'record': str(rec)})}
    assert '--force' not in procs['recorder'].arguments


def _load_launch_file(monkeypatch, started):
    """
    Import the launch file over stand-ins for ``launch``/``launch_ros`` (not on PyPI).

    ``LaunchConfiguration(name).perform(context)`` reads ``context[name]``; every ``Node`` built
    is appended to ``started``; anything else the file imports is an inert stand-in.
    """
    import importlib.util
    import sys
    import types

    class Inert:

        def __init__(self, *args, **kwargs):
            self.args, self.kwargs = args, kwargs

    class LaunchConfiguration(Inert):

        def perform(self, context):
            return context.get(self.args[0], '')

    class Node(Inert):

        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            started.append(kwargs.get('name'))

    def module(name, **names):
        m = types.ModuleType(name)
        m.__dict__.update(names)
        m.__getattr__ = lambda attr: Inert
        monkeypatch.setitem(sys.modules, name, m)
    for name in ('launch', 'launch.actions', 'launch.event_handlers', 'launch.events',
                 'launch.conditions', 'launch_ros'):
        module(name)
    module('launch.substitutions', LaunchConfiguration=LaunchConfiguration)
    module('launch_ros.actions', Node=Node)
    spec = importlib.util.spec_from_file_location('drive_launch', LAUNCH)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_the_launch_description_refuses_an_existing_record_before_any_node(tmp_path,
                                                                           monkeypatch):
    started = []
    launch_file = _load_launch_file(monkeypatch, started)
    rec = tmp_path / 'run.mcap'
    rec.write_bytes(b'an earlier run')
    args = {name: default for name, default, _ in launch_file.ARGUMENTS}
    with pytest.raises(FileExistsError, match='force:=true'):
        launch_file._processes(dict(args, record=str(rec), duration='0.01'))
    assert started == []                                # refused before a single node
    nodes = launch_file._processes(dict(args, record=str(rec), duration='0.01', force='true'))
    assert started == ['plant', 'controller', 'observer', 'recorder'] and len(nodes) == 4
    assert rec.read_bytes() == b'an earlier run'       # nothing started, nothing touched
