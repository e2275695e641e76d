"""im_common.yamlio and im_common.cli: the one parameter-YAML writer and the one CLI helper."""
import argparse
import math

from im_common import cli, yamlio
import numpy as np
import pytest


def test_parameter_yaml_round_trips_exactly():
    params = {'controller': {'current_gain': np.array([7.076535486730557, 2.2e-17, -2.2e-17, 0.1]),
                             'gain_period': 1e-3, 'flux_coupling': 'cancel', 'enable': True},
              'observer': {'k_e_injection': np.float64(1.0 / 3.0), 'steps': np.int64(4)}}
    text = yamlio.parameters_yaml(params, header='made by a test\nsecond line')
    assert text.startswith('# made by a test\n# second line\ncontroller:\n  ros__parameters:\n')
    assert 'current_gain: [7.076535486730557, 2.2e-17, -2.2e-17, 0.1]' in text   # one line
    back = yamlio.read_parameters(text)
    assert back['controller']['current_gain'] == params['controller']['current_gain'].tolist()
    assert back['observer']['k_e_injection'] == 1.0 / 3.0     # bit-exact, not rounded
    assert back['observer']['steps'] == 4 and back['controller']['enable'] is True


@pytest.mark.parametrize('bad', [math.nan, math.inf, [1.0, math.nan]])
def test_non_finite_parameter_is_rejected_by_name(bad):
    with pytest.raises(ValueError, match=r'controller\.current_gain'):
        yamlio.parameters_yaml({'controller': {'current_gain': bad}})


def test_ros_arguments_are_stripped_before_parsing():
    ap = argparse.ArgumentParser(prog='tool')
    ap.add_argument('--out')
    a = cli.parse_args(ap, ['--out', 'x', '--ros-args', '-r', '__node:=n', '-p', 'a:=1', '--'])
    assert a.out == 'x'
    with pytest.raises(SystemExit):
        cli.parse_args(ap, ['--bogus'])


def test_loggers_write_one_prefixed_line_to_stderr(capsys):
    cli.logger('tool')('hello')
    cli.gated_logger('tool')(False, 'hidden')
    cli.progress(2, 5, 'item', cli.logger('tool'))
    out, err = capsys.readouterr()
    assert out == '' and err == '[tool] hello\n[tool] [2/5] item\n'
    cli.status_line('run: 50.0 %')
    cli.status_line('run: done in 1.0 s', done=True)
    assert capsys.readouterr().err == '\rrun: 50.0 %\rrun: done in 1.0 s\n'


BAD_PARAMS_FILES = {
    'not_yaml': ('plant: {ros__parameters: {T_s: [1,\n', 'not valid YAML (line 2'),
    'a_list': ('- a\n- b\n', 'expected a mapping of node names'),
    'no_ros_parameters': ('plant: 3\n', "node 'plant' needs a 'ros__parameters' mapping"),
    'unknown_node': ('controler:\n  ros__parameters: {k1: 30.0}\n',
                     "unknown node 'controler'; did you mean 'controller'?"),
}


@pytest.mark.parametrize('case', sorted(BAD_PARAMS_FILES))
def test_every_reader_of_a_parameters_file_says_the_same_line(tmp_path, case):
    """
    Check that every path reads a parameters file through one function.

    scenario (merge_yaml), the launch file (load_params_yaml) and a node executable
    (init_args_error, before rclpy.init) read a parameters file through one function: one message,
    naming the file.
    """
    from im_bringup.config import node_parameters
    from im_bringup.processes import load_params_yaml
    from im_bringup.scenario import merge_yaml
    from im_common.lockstep import init_args_error
    text, wanted = BAD_PARAMS_FILES[case]
    f = tmp_path / 'p.yaml'
    f.write_text(text)
    with pytest.raises(ValueError) as a:
        merge_yaml(node_parameters(), str(f))
    with pytest.raises(ValueError) as b:
        load_params_yaml(str(f))
    assert str(a.value) == str(b.value) and str(f) in str(a.value) and wanted in str(a.value)
    assert '\n' not in str(a.value)
    node_line = init_args_error(['controller', '--ros-args', '--params-file', str(f)])
    if case == 'unknown_node':      # a node executable takes sections for other nodes
        assert node_line is None
    else:
        assert node_line == str(a.value)


def test_missing_parameters_file_is_one_line_on_every_reader(tmp_path):
    from im_bringup.processes import load_params_yaml
    from im_common.lockstep import init_args_error
    f = str(tmp_path / 'nope.yaml')
    with pytest.raises(ValueError) as a:
        load_params_yaml(f)
    assert str(a.value) == init_args_error(['x', '--params-file', f])
    assert f in str(a.value) and 'No such file' in str(a.value)
