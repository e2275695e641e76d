"""
Speed-sensorless mode through the ROS graph (issue 26 item 1, docs/sensorless.md).

In one process the graph equals the ROS-free loop, the nodes do not subscribe to the measured
shaft, and a measured speed full of noise changes nothing; the same as separate processes.
"""
from im_bringup.offline import simulate
from im_bringup.testing import assert_all_ended, assert_samples_match, run_graph
from im_common import topics as T
import numpy as np
import pytest

NOISE = {'plant': {'speed_noise_std': 50.0}}


def test_sensorless_graph_equals_the_ros_free_loop_and_ignores_the_measured_speed():
    from im_bringup.offline import Scenario, simulate
    g = run_graph(task='speed', strategy='min_energy', duration=0.05, sensorless=True,
                  parameters=NOISE)
    assert g.summary['ok'], g.summary['failures']
    # the controller node orients on the observed flux in sensorless mode: so does the offline one
    off = simulate(Scenario(task='speed', strategy='min_energy', duration=0.05, sensorless=True,
                            controller_options={'sensorless': True}))
    for key in ('E_in_J', 'E_copper_J', 'dW_magnetic_J'):
        assert g.summary[key] == pytest.approx(off.summary[key], rel=1e-9, abs=1e-12), key
    assert_samples_match(g.trace, off.trace, ('phi_hat_alpha', 'omega_hat'), 500)
    # the plant's measured speed is noise (the graph's shaft topic carries it) ...
    assert np.std(np.asarray(g.trace['omega_r']) - 135.0) > 20.0


def test_sensorless_nodes_do_not_subscribe_to_the_measured_shaft():
    from im_bringup.config import node_parameters
    from im_bringup.graph import DriveGraph
    params = node_parameters('speed', 'min_energy', 'adaptive', duration=0.01, sensorless=True)
    graph = DriveGraph(params, nodes=DriveGraph.NODE_NAMES)
    try:
        subs = {name: {s.topic_name for s in n.subscriptions} for name, n in graph.nodes.items()}
    finally:
        graph.close()
    for name in ('controller', 'observer', 'adapter'):
        assert T.MEAS_SHAFT not in subs[name], name
    assert T.OBS_SPEED in subs['controller'] and T.OBS_SPEED in subs['adapter']


def test_position_task_is_refused_in_sensorless_mode():
    from im_bringup.config import node_parameters
    with pytest.raises(ValueError, match='sensorless.*position task needs the measured shaft'):
        node_parameters('position', sensorless=True)


@pytest.mark.processes
@pytest.mark.slow
def test_sensorless_processes_record_the_speed_estimate_and_ignore_the_measured_speed(tmp_path):
    """
    Check the sensorless graph with every node its own process.

    Every node its own process (as the launch file starts them, ``sensorless:=true``), the plant's
    measured speed made useless: every process exits 0, the recording holds the speed estimate at
    every step, and the numbers equal the in-process run without any noise.
    """
    from im_bringup.testing import random_domain

    from im_recording.bag import iter_raw
    from im_bringup.processes import GraphProcesses, graph_processes
    from im_recording.report import figures_of_merit
    from im_recording.recorded_run import load_run
    bag = tmp_path / 'sensorless.mcap'
    domain = {'ROS_DOMAIN_ID': str(random_domain())}
    with GraphProcesses(graph_processes('speed', 'min_energy', duration=0.02, record=bag,
                                        extra=NOISE, sensorless=True),
                        str(tmp_path / 'logs'), domain) as g:
        codes = g.start().wait(300)
        assert_all_ended(g, codes)
    n_speed = sum(1 for t, *_ in iter_raw(bag) if t == T.OBS_SPEED)
    assert n_speed == 201                                   # steps 0..200
    quiet = run_graph(task='speed', strategy='min_energy', duration=0.02, sensorless=True)
    fig = figures_of_merit(load_run(bag))
    for key in ('E_in_J', 'E_loss_J', 'V_max_V'):
        assert fig[key] == pytest.approx(quiet.summary[key], rel=1e-12), key


def test_sensorless_adapter_hands_its_stator_resistance_to_the_graph_nodes():
    """
    Sensorless, the adapter estimates R_s (docs/sensorless.md §3); the nodes take it.

    At 10 rad/s against 4 N·m with the plant's R_s 30 % above the model's, the graph (the
    estimate travels on the adapter's topic) equals the ROS-free loop (the estimate handed over
    in memory), and R̂_s has moved.
    """
    from dataclasses import replace

    from im_adapt.hook import LockstepAdapter
    from im_studies.study_sensorless import low_speed_hold, R_S_DRIFT
    drift = {'R_s': [{'t': 0.0, 'scale': R_S_DRIFT}]}
    sc = replace(low_speed_hold(), schedule=None, variation=drift, duration=0.05,
                 controller='adaptive')
    # the controller node orients on the observed flux by itself in sensorless mode
    g = run_graph(scenario=replace(sc, controller_options={}))
    assert g.summary['ok'], g.summary['failures']
    hook = LockstepAdapter.build(sc.model_estimates(), sensorless=True)
    off = simulate(replace(sc, controller='nominal'), adapter=hook)
    r_s = np.asarray(hook.samples)[:, 5]
    assert r_s[-1] != r_s[0]
    for key in ('E_in_J', 'E_copper_J', 'dW_magnetic_J'):
        assert g.summary[key] == pytest.approx(off.summary[key], rel=1e-9, abs=1e-12), key
    assert_samples_match(g.trace, off.trace, ('phi_hat_alpha', 'omega_hat'), 50)
