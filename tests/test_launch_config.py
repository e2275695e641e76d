"""The launch file's parameters YAML is the scenario mapping's output (no drift), and it loads."""
import os

import yaml

from im_bringup.config import node_parameters

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


def test_launch_file_names_every_node_and_the_yaml():
    src = open(LAUNCH).read()
    for pkg, exe in (('im_plant', 'plant'), ('im_controller', 'controller'),
                     ('im_observer', 'observer'), ('im_adapt', 'adapter')):
        assert f"('{pkg}', '{exe}')" in src
    assert "'drive.yaml'" in src
    compile(src, LAUNCH, 'exec')      # valid Python, without importing launch
