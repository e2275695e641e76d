"""
The computational delay (docs/plant.md §10): the command computed at step k acts over step k + d.

One line of commands (im_common.delay.CommandDelay) in the plant and in every part of the drive
that integrates the voltage the motor got: the ideal and the switched plant, the ROS-free loop and
the graph agree to the last bit, and what the delay does to the thesis's law is the closed form's.
"""
import math

from im_bringup.offline import simulate
from im_bringup.run_file import RunFileError, Scenario
from im_common.delay import CommandDelay
from im_common.inverter import Inverter
from im_common.params import InvalidParameter, THESIS_MOTOR
from im_common.plant_sim import PlantSimulator
import numpy as np
import pytest

SWITCHED = {'V_dc': 340.0, 'pwm_frequency': 10000.0, 'deadtime': 2e-6, 'v_on': 1.0,
            'r_on': 0.02}


def _commands(n, seed=3):
    rng = np.random.default_rng(seed)
    return [tuple(float(x) for x in rng.uniform(-150.0, 150.0, 2)) for _ in range(n)]


# ------------------------------------------------------------------------------ the line
def test_the_line_gives_each_command_d_steps_later_and_starts_with_the_first():
    cmds = _commands(6)
    for d in (0, 1, 2):
        line = CommandDelay(d)
        out = [line.push(*c) for c in cmds]
        assert out == [cmds[0]] * d + cmds[:len(cmds) - d]
        assert len(line.pending()) == d


@pytest.mark.parametrize('bad', [-1, 3, 1.0, 1.5, True, '1', None])
def test_a_bad_delay_is_one_line_naming_it(bad):
    with pytest.raises(InvalidParameter, match=r"^invalid parameter 'delay'") as exc:
        CommandDelay(bad)
    assert '\n' not in str(exc.value)


# ------------------------------------------------------------------------------ the block
def test_an_inverter_block_without_v_dc_is_the_ideal_source_with_its_delay():
    inv = Inverter.from_block({'delay': 1})
    assert not inv.switched and inv.delay == 1 and inv.describe() == {'delay': 1}
    switched = Inverter.from_block(dict(SWITCHED, delay=1))
    assert switched.switched and switched.describe()['delay'] == 1
    assert Inverter.from_block(SWITCHED).delay == 0          # today's plant unless asked


@pytest.mark.parametrize('spec, key, why', [
    ({'V_dc': 340.0}, 'inverter.pwm_frequency', 'is missing'),
    ({'pwm_frequency': 1e4, 'delay': 1}, 'inverter.V_dc', 'is missing'),
    ({'delay': 1, 'deadtime': 1e-6}, 'inverter.deadtime', 'needs the switched inverter'),
    ({'C_dc': 1e-3}, 'inverter.C_dc', 'needs the switched inverter'),
    ({'delay': -1}, 'inverter.delay', '>= 0'),
    ({'delay': 3}, 'inverter.delay', '<= 2'),
    ({'delay': 1.5}, 'inverter.delay', 'whole number'),
    ({'delay': True}, 'inverter.delay', 'whole number'),
])
def test_a_bad_inverter_block_is_one_line_naming_the_key(spec, key, why):
    with pytest.raises(InvalidParameter) as exc:
        Inverter.from_block(spec)
    assert exc.value.name == key and why in str(exc.value), str(exc.value)


# ------------------------------------------------------------------------------ the plant
@pytest.mark.parametrize('blocks', [{}, {'inverter': SWITCHED}], ids=['ideal', 'switched'])
def test_a_delayed_plant_is_the_undelayed_one_fed_the_shifted_commands(blocks):
    cmds = _commands(300)
    for d in (1, 2):
        inv = dict(blocks.get('inverter', {}), delay=d)
        late = PlantSimulator(THESIS_MOTOR, inverter=inv)
        now = PlantSimulator(THESIS_MOTOR, **blocks)
        shifted = [cmds[0]] * d + cmds[:-d]
        for c, s in zip(cmds, shifted):
            late.step(*c)
            now.step(*s)
            assert late.x == now.x                       # bit for bit
            assert late.truth()['v_alpha'] == now.truth()['v_alpha']
        assert late.truth()['E_in'] == now.truth()['E_in']


def test_the_ideal_plant_applies_the_command_given_one_step_before():
    cmds = _commands(20)
    plant = PlantSimulator(THESIS_MOTOR, inverter={'delay': 1}, v_limit=None)
    assert plant.real is None                            # the ideal plant's own path
    for k, c in enumerate(cmds):
        plant.step(*c)
        assert (plant.truth()['v_alpha'], plant.truth()['v_beta']) == cmds[max(k - 1, 0)]


def test_the_rating_trips_on_the_command_given_not_on_the_one_that_acts():
    plant = PlantSimulator(THESIS_MOTOR, inverter={'delay': 1}, inverter_rating=500.0)
    plant.step(100.0, 0.0)
    plant.step(100.0, 0.0)
    plant.step(600.0, 0.0)           # above the rating: the gates open at once
    assert plant.trip is not None and plant.trip[0] == pytest.approx(2e-4)
    assert plant.v_applied == (0.0, 0.0)
    with pytest.raises(ValueError, match='non-finite'):
        plant.step(math.nan, 0.0)


# ------------------------------------------------------------------------------ the run
RUN = 'task: speed\nduration: {duration}\ninverter: {{delay: 1}}\n'


def test_the_run_file_carries_the_delay_to_plant_observer_and_adapter(tmp_path):
    p = tmp_path / 'run.yaml'
    p.write_text(RUN.format(duration=0.05))
    sc = Scenario.from_file(str(p))
    assert sc.delay == 1
    params = sc.node_parameters()
    assert params['plant']['inverter.enabled'] is True
    assert params['plant']['inverter.delay'] == 1 and params['plant']['inverter.V_dc'] == 0.0
    assert params['observer']['delay'] == 1 and params['adapter']['delay'] == 1
    again = Scenario.from_mapping(sc.to_mapping())
    assert again.delay == 1 and again.node_parameters() == params
    assert 'delay' not in Scenario(task='speed').node_parameters()['observer']
    p.write_text(RUN.format(duration=0.05).replace('{delay: 1}', '{delay: 2.5}'))
    with pytest.raises(RunFileError, match=r': inverter\.delay: ') as exc:
        Scenario.from_file(str(p))
    assert '\n' not in str(exc.value)


def test_the_graph_and_the_rosfree_loop_agree_with_the_delay(tmp_path):
    from im_bringup.testing import assert_samples_match, run_graph
    p = tmp_path / 'run.yaml'
    p.write_text(RUN.format(duration=0.05))
    sc = Scenario.from_file(str(p))
    off = simulate(sc)
    g = run_graph(scenario=sc)
    assert g.summary['ok'], g.summary['failures']
    for key in ('E_in_J', 'E_copper_J'):
        assert g.summary[key] == pytest.approx(off.summary[key], rel=1e-9, abs=1e-12), key
    assert_samples_match(g.trace, off.trace, ('omega_r', 'theta_r', 'phi_hat_alpha'), 400)
    # and the delay acted: the same run without it is another run
    undelayed = simulate(Scenario.from_mapping(dict(sc.to_mapping(), inverter=None)))
    assert abs(undelayed.summary['E_in_J'] - off.summary['E_in_J']) > 1e-6
