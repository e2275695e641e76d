"""Issue 10 through the lock-step graph: a motor file, a profile and a load of one's own reach
every node through ``node_parameters`` (the in-process fixture passes them straight on), and the
graph still equals the offline loop with them."""
import os

import numpy as np
import pytest

from im_bringup.config import node_parameters
from im_bringup.testing import assert_samples_match, run_graph
from im_common.params import load_motor_file

HERE = os.path.dirname(os.path.abspath(__file__))
MOTOR = os.path.join(HERE, '..', 'src', 'im_common', 'config', 'motors', 'krause_3hp.yaml')


@pytest.fixture
def files(tmp_path):
    prof = tmp_path / 'profile.yaml'
    prof.write_text('setpoints:\n  - {t: 0.0, velocity: 100.0}\n'
                    '  - {t: 0.01, velocity: 120.0, duration: 0.03}\n')
    load = tmp_path / 'load.yaml'
    load.write_text('kind: linear\nc1: 0.5\nc2: 0.002\n')
    return str(prof), str(load)


def test_motor_profile_and_load_reach_every_node(files):
    prof, load = files
    p = node_parameters('speed', 'min_loss', motor=MOTOR, profile=prof, load=load, v_limit=220.0,
                        limits={'current_limit': 20.0}, protection={'current_trip': 60.0})
    m = load_motor_file(MOTOR)
    for node in ('plant', 'controller', 'observer', 'adapter'):
        assert p[node]['L_sr'] == m.L_sr and p[node]['rated_current'] == m.rated_current, node
    c = p['controller']
    assert c['profile'] == 'setpoint' and c['setpoints'] == [0.0, 100.0, 0.0, 0.01, 120.0, 0.03]
    assert c['load'] == 'linear' and c['load_c1'] == 0.5 and c['current_limit'] == 20.0
    assert p['plant']['load_c2'] == 0.002 and p['plant']['omega0'] == 100.0
    assert p['plant']['current_trip'] == 60.0
    # an explicit mismatch: the model differs from the plant only where asked
    q = node_parameters('speed', 'min_loss', motor=MOTOR,
                        estimates=m.with_values(R_r=1.2 * m.R_r), profile=prof)
    assert q['plant']['R_r'] == m.R_r and q['controller']['R_r'] == q['observer']['R_r'] == 1.2 * m.R_r


def test_node_parameters_refuse_bad_options(files, tmp_path):
    prof, _ = files
    with pytest.raises(ValueError, match='a speed profile for the position task'):
        node_parameters('position', profile=prof)
    with pytest.raises(ValueError, match="invalid limit 'torque'"):
        node_parameters('speed', limits={'torque': 1.0})
    bad = tmp_path / 'm.yaml'
    bad.write_text('/**:\n  ros__parameters:\n    R_s: 1.0\n')
    with pytest.raises(ValueError, match='m.yaml: R_r'):
        node_parameters('speed', motor=str(bad))


def test_graph_equals_the_offline_loop_with_motor_profile_load_and_limits(files):
    from im_bringup.offline import Scenario, simulate
    from im_common.loads import load_file
    from im_controller.profiles import load_profile
    prof, load = files
    limits = {'current_limit': 25.0, 'torque_limit': 15.0}
    g = run_graph(task='speed', strategy='min_loss', duration=0.05, motor=MOTOR, profile=prof,
                  load=load, v_limit=220.0, limits=limits)
    off = simulate(Scenario(task='speed', strategy='min_loss', duration=0.05,
                            motor=load_motor_file(MOTOR), profile=load_profile(prof),
                            load_model=load_file(load), v_limit=220.0, controller_options=limits))
    assert g.summary['ok'], g.summary['failures']
    for key in ('E_in_J', 'E_copper_J', 'dW_magnetic_J'):
        assert g.summary[key] == pytest.approx(off.summary[key], rel=1e-9, abs=1e-12), key
    assert_samples_match(g.trace, off.trace, ('omega_r', 'theta_r'), 400)
    # the profile was followed: the reference reached 120 rad/s
    assert np.nanmax(g.trace['omega_ref']) == pytest.approx(120.0, abs=1e-6)


def test_torque_task_follows_an_effort_profile_in_the_graph_and_offline(tmp_path):
    """The torque task (an effort profile, beyond the thesis): graph and offline loop agree, the
    torque follows the profile once the machine is magnetized."""
    from im_bringup.offline import Scenario, simulate
    from im_controller.profiles import load_profile
    prof = tmp_path / 'effort.yaml'
    prof.write_text('setpoints:\n  - {t: 0.0, effort: 0.0}\n  - {t: 0.03, effort: 2.0, duration: 0.01}\n')
    g = run_graph(task='torque', strategy='constant_flux', duration=0.06, profile=str(prof))
    off = simulate(Scenario(task='torque', strategy='constant_flux', duration=0.06,
                            profile=load_profile(str(prof))))
    assert g.summary['ok'], g.summary['failures']
    assert g.summary['E_in_J'] == pytest.approx(off.summary['E_in_J'], rel=1e-9)
    assert off.trace['tau_ref'][-1] == pytest.approx(2.0)
    with pytest.raises(ValueError, match='torque task needs a profile'):
        node_parameters('torque')
