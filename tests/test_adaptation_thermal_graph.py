"""
The adapter node's ``thermal_tracking`` through the ROS graph (docs/adaptation.md §9).

A run file as a user writes it — a motor file with a ``thermal`` block, ``thermal: motor``,
sensorless, the adaptive controller, ``parameters: {adapter: {thermal_tracking: true}}`` — warms
the plant's windings, and the adapter node's R̂_s and R̂_R follow them: on the estimate topic as
the ROS-free loop computes them. Sensored, the networks carry the least squares' estimates
between updates, on the graph as in the loop. Without the block, or with law 'thesis', one line
naming the parameter.
"""
import os
import subprocess

from im_common.params import shipped_motors_dir
import numpy as np
import pytest
import yaml

#: the thesis file's thermal block with its time constants scaled from minutes to seconds (the
#: cage's 4 min to 2 s, the stator's 17 min to 20 s), so that the speed task's 0.5 s warms the
#: cage by about 19 K (R_R +7.6 %) and the stator by a few K
FAST = {'C_s': 20.0, 'R_th_s': 1.0, 'C_r': 1.0, 'R_th_r': 2.0, 'T_ambient': 25.0, 'T_ref': 25.0}
RUN = """task: speed
controller: {controller}
sensorless: {sensorless}
duration: 0.5
motor: motor.yaml
{thermal}parameters: {{adapter: {{thermal_tracking: true, freeze: {freeze}}}}}
"""


def _motor_file(tmp_path, thermal=FAST):
    """Write the shipped thesis motor file with ``thermal`` as its block (None: no block)."""
    with open(os.path.join(shipped_motors_dir(), 'thesis.yaml')) as f:
        doc = yaml.safe_load(f)
    values = doc['/**']['ros__parameters']
    values.pop('thermal')
    if isinstance(values['saturation'], str):      # a node takes a block as a nested mapping
        values['saturation'] = yaml.safe_load(values['saturation'])
    if thermal is not None:         # a nested mapping, as a ROS parameters file takes it
        values['thermal'] = dict(thermal)
    path = tmp_path / 'motor.yaml'
    path.write_text(yaml.safe_dump(doc))
    return path


def _run_file(tmp_path, sensorless=True, thermal=FAST, controller='adaptive'):
    _motor_file(tmp_path, thermal)
    path = tmp_path / 'run.yaml'
    path.write_text(RUN.format(sensorless='true' if sensorless else 'false',
                               thermal='' if thermal is None else 'thermal: motor\n',
                               controller=controller, freeze='true' if sensorless else 'false'))
    return str(path)


@pytest.mark.slow
def test_graph_adapter_follows_the_warming_cage_as_the_ros_free_loop_does(tmp_path):
    """
    R̂_R and R̂_s on the adapter's topic follow the plant's windings as they warm.

    The plant's R_R rises with the cage, R_R(T) = R_R,ref (1 + α_r (T_rotor − T_ref)); the
    adapter runs the same networks on its own loss estimate, so R̂_R stays on the plant's curve
    throughout: within 2 % of the rise at every truth sample (0.15 % of R_R here; the error left
    is the drive's loss estimate, R̂|i|² from the sampled current and the rotor current from the
    observed flux — docs/adaptation.md §9 measures 0.01 % at the end of a 50 K duty), where the
    cold value would be off by the whole rise. The graph's estimates equal the ROS-free loop's
    (the adapter handed over in memory) to 1e-9, the tolerance of the other graph-against-offline
    tests (tests/test_sensorless_graph.py): not bit for bit, since the controller node's time is
    its step's stamp, ns / 1e9, and the loop's k·T_s, which differ in the last bit at some steps
    (3e-4 against 3·1e-4): the references, and with them the run, differ by rounding (R̂_R by
    ~4e-15 here).
    """
    from dataclasses import replace

    from im_adapt.adaptation import AdaptationGains
    from im_adapt.hook import LockstepAdapter
    from im_bringup.offline import simulate
    from im_bringup.run_file import Scenario
    from im_bringup.testing import assert_samples_match, run_graph
    run = _run_file(tmp_path)
    sc = Scenario.from_file(run)
    params = sc.node_parameters()       # the run's thermal block reaches the adapter too
    thermal = {k: v for k, v in params['plant'].items() if k.startswith('thermal.')}
    assert thermal['thermal.enabled'] and thermal.items() <= params['adapter'].items()
    g = run_graph(scenario=run)
    assert g.summary['ok'], g.summary['failures']
    tr = g.trace
    truth = np.isfinite(tr['R_R'])                 # the plant's truth, every 10th step
    R_R, T_r = tr['R_R'][truth], tr['T_rotor'][truth]
    R_R_hat, R_s_hat, R_s = tr['R_R_hat'][truth], tr['R_s_hat'][truth], tr['R_s'][truth]
    th = sc.thermal
    # the plant's cage: R_R on its temperature's line, warmed by > 15 K
    np.testing.assert_allclose(R_R / R_R[0], 1.0 + th['alpha_r'] * (T_r - th['T_ref']),
                               rtol=1e-9)
    rise = R_R[-1] / R_R[0] - 1.0
    assert T_r[-1] - T_r[0] > 15.0 and rise > 0.06
    assert np.all(np.diff(T_r) > 0.0)
    # the adapter's R̂_R on the plant's line (and R̂_s on the stator's) the whole run
    assert np.max(np.abs(R_R_hat / R_R - 1.0)) < 0.02 * rise
    assert np.max(np.abs(R_s_hat / R_s - 1.0)) < 0.02 * (R_s[-1] / R_s[0] - 1.0)
    assert g.summary['R_R_hat_final'] == pytest.approx(g.summary['R_R_true_final'],
                                                       rel=0.02 * rise)
    # the ROS-free loop with the same run and the adapter of the same block
    hook = LockstepAdapter.build(sc.model_estimates(), AdaptationGains(freeze=True),
                                 sensorless=True, thermal=th, record_every=1)
    off = simulate(replace(sc, controller='nominal'), adapter=hook)
    for key in ('E_in_J', 'E_copper_J', 'dW_magnetic_J'):
        assert g.summary[key] == pytest.approx(off.summary[key], rel=1e-9, abs=1e-12), key
    s = np.asarray(hook.samples)
    est = {'t': np.asarray(hook.t), 'R_R_hat': s[:, 3], 'R_s_hat': s[:, 5]}
    assert_samples_match(tr, est, ('R_R_hat', 'R_s_hat'), 4900)


@pytest.mark.slow
def test_graph_sensored_networks_carry_the_least_squares_as_the_ros_free_loop_does(tmp_path):
    """
    Sensored, ``thermal_tracking`` moves the least squares' R̂_s, R̂_R as the windings warm.

    The same run as above with the measured shaft and the least squares on: the graph's
    estimates equal the ROS-free loop's (1e-9, as above), and R̂_R ends on the warmed cage's
    value, where the cold one is off by the whole rise (within a fifth of it: the least squares'
    0.5 s of a start here, docs/adaptation.md §9 measures 0.03 % after 2 minutes).
    """
    from dataclasses import replace

    from im_adapt.adaptation import AdaptationGains
    from im_adapt.hook import LockstepAdapter
    from im_bringup.offline import simulate
    from im_bringup.run_file import Scenario
    from im_bringup.testing import assert_samples_match, run_graph
    run = _run_file(tmp_path, sensorless=False)
    sc = Scenario.from_file(run)
    g = run_graph(scenario=run)
    assert g.summary['ok'], g.summary['failures']
    rise = g.summary['R_R_true_final'] / sc.model_estimates().R_R - 1.0
    assert rise > 0.06
    assert g.summary['R_R_hat_final'] == pytest.approx(g.summary['R_R_true_final'],
                                                       rel=0.2 * rise)
    hook = LockstepAdapter.build(sc.model_estimates(), AdaptationGains(), thermal=sc.thermal,
                                 record_every=1)
    off = simulate(replace(sc, controller='nominal'), adapter=hook)
    for key in ('E_in_J', 'E_copper_J', 'dW_magnetic_J'):
        assert g.summary[key] == pytest.approx(off.summary[key], rel=1e-9, abs=1e-12), key
    s = np.asarray(hook.samples)
    assert_samples_match(g.trace, {'t': np.asarray(hook.t), 'R_R_hat': s[:, 3]}, ('R_R_hat',),
                         4900)


def _adapter_stderr(args):
    from im_bringup.processes import executable_path
    proc = subprocess.run([executable_path('im_adapt', 'adapter'), '--ros-args'] + args,
                          capture_output=True, text=True, timeout=60)
    return proc.returncode, proc.stderr


@pytest.mark.processes
@pytest.mark.parametrize('sensorless, thermal, law', [(True, None, 'improved'),
                                                      (False, None, 'improved'),
                                                      (True, FAST, 'thesis')],
                         ids=['sensorless_no_block', 'sensored_no_block', 'law_thesis'])
def test_thermal_tracking_without_block_or_with_law_thesis_is_one_line(
        tmp_path, sensorless, thermal, law):
    """
    ``ros2 run im_adapt adapter`` refuses the parameter by name, and so does the run file.

    The process exits 2 with one line naming ``thermal_tracking`` and what it needs; the run
    file's parameters are refused by the same check before any process starts
    (``scenario --processes``, the launch).
    """
    from im_bringup.graph import check_parameters
    from im_bringup.run_file import Scenario
    from im_common.lockstep import ConfigurationError
    motor = _motor_file(tmp_path, thermal)
    code, err = _adapter_stderr(['--params-file', str(motor), '-p', 'thermal_tracking:=true',
                                 '-p', f'sensorless:={str(sensorless).lower()}',
                                 '-p', f'law:={law}'])
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "'thermal_tracking'" in lines[0], err
    assert ('thermal block' if thermal is None else "law 'improved'") in lines[0]
    assert 'Traceback' not in err
    controller = 'adaptive' if law == 'improved' else 'adaptive_thesis'
    params = Scenario.from_file(_run_file(tmp_path, sensorless, thermal,
                                          controller)).node_parameters()
    with pytest.raises(ConfigurationError, match="'thermal_tracking'") as exc:
        check_parameters(params)
    assert '\n' not in str(exc.value)
