"""
Every executable resolves through the ament index exactly as ``ros2 run`` does, and starts.

``ros2 run PKG EXE`` looks up ``get_package_prefix(PKG)/lib/PKG/EXE``; the workspace must have been
built with ``colcon build`` (``make test`` does it) and sourced (``install/setup.bash``).
"""
import os
import subprocess

import pytest

EXECUTABLES = [
    ('im_plant', 'plant'),
    ('im_observer', 'observer'),
    ('im_controller', 'controller'),
    ('im_controller', 'design_gains'),
    ('im_studies', 'robust_study'),
    ('im_adapt', 'adapter'),
    ('im_robust', 'robust_examples'),
    ('im_bringup', 'scenario'),
    ('im_recording', 'record'),
    ('im_recording', 'replay'),
    ('im_recording', 'report'),
    ('im_recording', 'recover'),
    ('im_studies', 'campaign'),
    ('im_bringup', 'commission'),
    ('im_bringup', 'live'),
]


def ros2_run_path(package: str, executable: str) -> str:
    from ament_index_python.packages import PackageNotFoundError, get_package_prefix
    try:
        prefix = get_package_prefix(package)
    except PackageNotFoundError:
        pytest.fail(f"package '{package}' is not in the ament index (AMENT_PREFIX_PATH="
                    f"{os.environ.get('AMENT_PREFIX_PATH')!r}); run `make build` and source "
                    f'install/setup.bash')
    return os.path.join(prefix, 'lib', package, executable)


@pytest.mark.processes
@pytest.mark.parametrize('package,executable', EXECUTABLES)
def test_executable_resolves_and_starts(package, executable):
    path = ros2_run_path(package, executable)
    assert os.access(path, os.X_OK), f'{path} is not an executable file'
    proc = subprocess.run([path, '--help'], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert 'usage' in proc.stdout.lower(), proc.stdout[:500]


@pytest.mark.processes
def test_plant_process_loads_the_thesis_yaml_and_reports_a_missing_controller():
    """
    Check that the installed plant starts with the shipped parameters.

    `ros2 run im_plant plant --ros-args --params-file .../thesis_motor.yaml` starts with the
    shipped parameters; with no controller it says who it waited for and exits 1.
    """
    from im_bringup.testing import random_domain
    from ament_index_python.packages import get_package_share_directory
    yml = os.path.join(get_package_share_directory('im_plant'), 'config', 'thesis_motor.yaml')
    assert os.path.exists(yml)
    env = dict(os.environ, ROS_DOMAIN_ID=str(random_domain()))
    proc = subprocess.run([ros2_run_path('im_plant', 'plant'), '--ros-args', '--params-file', yml,
                           '-p', 'startup_timeout:=0.5', '-p', 'input_timeout:=0.5'],
                          capture_output=True, text=True, timeout=60, env=env)
    assert proc.returncode == 1, proc.stderr[-2000:]
    assert 'not started within 0.5 s' in proc.stderr
    assert 'no publisher yet of /im/command/voltage' in proc.stderr
    assert 'controller (not seen' in proc.stderr and 'Traceback' not in proc.stderr


@pytest.mark.processes
def test_node_process_refuses_an_impossible_parameter_by_name():
    proc = subprocess.run([ros2_run_path('im_plant', 'plant'), '--ros-args', '-p', 'L_sr:=0.09'],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert "'L_sr'" in proc.stderr and 'sigma' in proc.stderr
    assert 'Traceback' not in proc.stderr


@pytest.mark.parametrize('content,needle', [
    (None, 'cannot read parameters file'),
    ('plant: {ros__parameters: {T_s: [1, 2}', 'is not valid YAML'),
    ('- just\n- a list\n', 'is not a ROS 2 parameters file'),
])
@pytest.mark.processes
def test_bad_params_file_is_one_line_without_traceback(tmp_path, content, needle):
    path = tmp_path / 'p.yaml'
    if content is not None:
        path.write_text(content)
    for pkg, exe in (('im_plant', 'plant'), ('im_controller', 'controller')):
        proc = subprocess.run([ros2_run_path(pkg, exe), '--ros-args', '--params-file', str(path)],
                              capture_output=True, text=True, timeout=60)
        assert proc.returncode == 2, proc.stderr
        assert needle in proc.stderr and str(path) in proc.stderr
        assert 'Traceback' not in proc.stderr and len(proc.stderr.strip().splitlines()) == 1


@pytest.mark.processes
def test_misspelt_parameter_is_refused_with_the_nearest_name(tmp_path):
    path = tmp_path / 'p.yaml'
    path.write_text('controller:\n  ros__parameters:\n    K1: 30.0\n')
    proc = subprocess.run([ros2_run_path('im_controller', 'controller'), '--ros-args',
                           '--params-file', str(path)], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2, proc.stderr
    assert "unknown parameter 'K1'" in proc.stderr and "did you mean 'k1'" in proc.stderr
    assert 'Traceback' not in proc.stderr
