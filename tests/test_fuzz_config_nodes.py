"""
Property-based fuzzing of the nodes' parameter checks (issue 47, item 2; files: test_fuzz_config).

Three ways a user hands a node parameters: at start-up (``--ros-args -p``, a parameters file, the
run file's ``parameters:``; every path builds the node through ``im_common.host.build_node``),
``ros2 param set`` on a running node (the node's set-parameters checks, called in-process here),
and the same through the node's ``set_parameters`` service (a few end to end). The property:
accepted, and the node runs with it (a live change applies at the next step without a refusal
there), or refused in one line naming the parameter (a ConfigurationError at start-up, a failed
SetParametersResult while running). Never another exception.
"""
import json
import math

from hypothesis import given, strategies as st
from im_adapt.adapter_node import AdapterNode
from im_common.host import build_node
from im_common.node_params import ConfigurationError
from im_controller.controller_node import ControllerNode
from im_controller.parameters import LIVE_PARAMETERS
from im_observer.observer_node import ObserverNode
from im_plant.plant_node import PlantNode
import pytest
import rclpy
from rclpy.parameter import Parameter


NODES = {'plant': PlantNode, 'controller': ControllerNode, 'observer': ObserverNode,
         'adapter': AdapterNode}

FLOATS = st.one_of(st.floats(allow_nan=True, allow_infinity=True),
                   st.sampled_from([0.0, -1.0, -0.5, 1e-300, 1e300, -1e300, 1e6, 2.0, 0.1]))
INTS = st.one_of(st.integers(-2**63, 2**63 - 1), st.sampled_from([0, -1, 1, 2, 3, 10**6]))
JSON_TEXT = st.recursive(
    st.one_of(st.none(), st.booleans(), FLOATS, st.text(max_size=6)),
    lambda inner: st.one_of(st.lists(inner, max_size=3),
                            st.dictionaries(st.sampled_from(['V_dc', 'pwm_frequency', 'R_r',
                                                             't', 'scale', 'beta', 'S', 'C_s',
                                                             'adc_bits', 'x']), inner,
                                            max_size=3)),
    max_leaves=6).map(lambda v: json.dumps(v, allow_nan=True))
# every type a ROS 2 parameter may hold, garbage included; empty arrays have no type in rclpy
VALUES = st.one_of(
    st.booleans(), INTS, FLOATS,
    st.text(max_size=12), JSON_TEXT, st.sampled_from(['', 'none', 'schedule', 'lockstep', 'x']),
    st.lists(FLOATS, min_size=1, max_size=9), st.lists(INTS, min_size=1, max_size=9),
    st.lists(st.booleans(), min_size=1, max_size=4),
    st.lists(st.text(max_size=5), min_size=1, max_size=4))


@pytest.fixture(scope='module')
def declared(context):
    """Return {node: [the names it declares]} (of nodes built with the defaults)."""
    out = {}
    for name, factory in NODES.items():
        node = build_node(factory, context=context)
        out[name] = sorted(n for n in node.list_parameters([], 0).names
                           if n not in ('use_sim_time', 'start_type_description_service'))
        node.destroy_node()
    return out


def one_line_naming(text, names):
    assert text and '\n' not in text and 'Traceback' not in text, repr(text)
    assert any(n in text for n in names), (names, text)


# Start-up: the node builds from what it is given, or refuses it in one line ---------------
@given(data=st.data(), which=st.sampled_from(sorted(NODES)))
def test_fuzz_node_start_up_parameters(context, declared, data, which):
    given = {}
    for _ in range(data.draw(st.integers(1, 3))):
        given[data.draw(st.sampled_from(declared[which]))] = data.draw(VALUES)
    overrides = [Parameter(k, value=v) for k, v in given.items()]
    try:
        node = build_node(NODES[which], context=context, parameter_overrides=overrides)
    except ConfigurationError as exc:
        one_line_naming(str(exc), list(given))
        return
    node.destroy_node()


def test_a_graph_key_file_that_cannot_be_read_is_refused_naming_the_parameter(context):
    # the line named the file alone: 'graph key file 0: No such file or directory'
    with pytest.raises(ConfigurationError) as err:
        build_node(ControllerNode, context=context,
                   parameter_overrides=[Parameter('graph_key_file', value='0')])
    one_line_naming(str(err.value), ["invalid parameter 'graph_key_file' = '0': graph key file"])


# A running node: ros2 param set, through the node's own checks ---------------------------
@pytest.fixture(scope='module')
def running(context):
    nodes = {name: build_node(factory, context=context) for name, factory in NODES.items()}
    yield nodes
    for node in nodes.values():
        node.destroy_node()


def _applied(node, which) -> bool:
    """Put accepted live changes in force as the next step does; return whether they took."""
    said = []
    node.status = lambda state, *a, **kw: said.append(state)
    try:
        if which == 'controller' and node._pending_changes:
            node._apply_changes(1)      # logs an error and announces nothing if it refuses
            return said == ['parameters'] and node._pending_changes is None
        if which == 'plant' and node._load_offset_next is not None:
            node._apply_load_offset()
            return math.isfinite(node.sim.load_offset)
        return True
    finally:
        del node.status


@given(data=st.data(), which=st.sampled_from(sorted(NODES)))
def test_fuzz_live_parameters_on_a_running_node(running, declared, data, which):
    node = running[which]
    live = {'controller': list(LIVE_PARAMETERS), 'plant': ['load_offset'],
            'adapter': ['enable'], 'observer': []}[which]
    names = data.draw(st.lists(st.sampled_from(live + declared[which]) if live else
                               st.sampled_from(declared[which]), min_size=1, max_size=3,
                               unique=True))
    params = [Parameter(n, value=data.draw(VALUES)) for n in names]
    results = node.set_parameters(params)
    for prm, res in zip(params, results):
        assert isinstance(res.successful, bool)
        if not res.successful:
            one_line_naming(res.reason, [prm.name])
    assert _applied(node, which)


@pytest.mark.parametrize('which,name,value', [
    ('plant', 'load_offset', 'three'),      # rclpy's type line named no parameter
    ('controller', 'phi_d', 'x'),           # TypeError text: "'<' not supported between ..."
    ('controller', 'current_gain', 'x'),
    ('adapter', 'enable', 3)])
def test_a_live_value_of_the_wrong_type_is_refused_naming_it(running, which, name, value):
    res = running[which].set_parameters([Parameter(name, value=value)])[0]
    assert not res.successful
    assert res.reason.startswith(f"invalid parameter '{name}' = {value!r}: must be "), res.reason


# End to end: the set_parameters service, as ros2 param set calls it ----------------------
@pytest.mark.slow
@given(data=st.data())
def test_fuzz_set_parameters_service_of_a_live_controller(running, declared, context, data):
    from rclpy.executors import SingleThreadedExecutor
    from rcl_interfaces.srv import SetParameters
    node = running['controller']
    names = data.draw(st.lists(st.one_of(st.sampled_from(list(LIVE_PARAMETERS)),
                                         st.sampled_from(declared['controller']),
                                         st.text(min_size=1, max_size=8).filter(str.isidentifier)),
                               min_size=1, max_size=3, unique=True))
    params = [Parameter(n, value=data.draw(VALUES)) for n in names]
    user = rclpy.create_node('operator', context=context)
    ex = SingleThreadedExecutor(context=context)
    ex.add_node(node)
    ex.add_node(user)
    try:
        cli = user.create_client(SetParameters,
                                 f'{node.get_fully_qualified_name()}/set_parameters')
        assert cli.wait_for_service(timeout_sec=20)
        fut = cli.call_async(SetParameters.Request(
            parameters=[p.to_parameter_msg() for p in params]))
        ex.spin_until_future_complete(fut, timeout_sec=20)
        results = fut.result().results
    finally:
        ex.remove_node(node)
        ex.remove_node(user)
        ex.shutdown()
        user.destroy_node()
    assert len(results) == len(params)
    for prm, res in zip(params, results):
        if prm.name not in declared['controller']:
            # rclpy's parameter service refuses an undeclared name itself, and its line names
            # none ('Invalid access to undeclared parameter(s): []', Jazzy's rclpy 7.1.6)
            assert not res.successful and '\n' not in res.reason
        elif not res.successful:
            one_line_naming(res.reason, [prm.name])
    assert _applied(node, 'controller')
