"""
im_adapt.parameters.declare_law: the adaptation gains as declared node parameters.

Every gain is a declared parameter with a description and a range, overrides reach the adapter, and
bad values are refused naming the parameter (ROS-free stand-in and the real node).
"""

from im_adapt.adaptation import AdaptationGains, ParameterAdapter
from im_adapt.parameters import declare_law
from im_common.host import private_domain
from im_common.params import InvalidParameter, THESIS_MOTOR
import pytest

CH4 = THESIS_MOTOR.with_values(L_s=0.084, L_sr=0.081, L_r=0.081 / 0.952941)


class FakeNode:
    """Records ``param`` calls like LockstepNode.param; returns overrides or defaults."""

    def __init__(self, **overrides):
        self.overrides = overrides
        self.declared = {}

    def param(self, name, default, description, lo=None, hi=None, read_only=True, choices=None):
        assert description, name
        value = self.overrides.get(name, default)
        self.declared[name] = (default, description, lo, hi, choices)
        if choices is not None and value not in choices:
            raise ValueError(f"invalid parameter '{name}' = {value!r}")
        return value


def test_declares_every_gain_with_a_range():
    node = FakeNode()
    law = declare_law(node, CH4, 0.842, 0.952941)
    assert isinstance(law, ParameterAdapter)
    for name in ('law', 'freeze', 'decimation', 'gamma_t', 'gamma_r', 'epsilon', 'flux_corner',
                 'filter_corner', 'memory', 'leakage_memory', 'didt_floor', 'estimate_leakage',
                 'i_floor', 'phi_floor', 'L_sigma', 'L_sigma_min', 'L_sigma_max', 'R_r_min',
                 'R_r_max', 'theta_min', 'theta_max', 'sigma_min', 'L_M_min', 'L_M_max'):
        assert name in node.declared, name
    for name, (default, doc, lo, hi, choices) in node.declared.items():
        if isinstance(default, float):
            assert lo is not None and hi is not None and lo <= default <= hi, name
    # Defaults are the dataclass defaults, bounds derived from the motor.
    g = law.gains
    assert g.law == AdaptationGains().law and g.gamma_r == AdaptationGains().gamma_r
    assert g.R_r_min == pytest.approx(0.25 * CH4.R_r)
    assert g.L_sigma == pytest.approx(CH4.L_s - CH4.L_sr * 0.952941)
    e = law.estimates()
    assert {'R_r', 'theta', 'L_M', 'R_R'} <= set(e)
    assert e['R_R'] == pytest.approx(e['R_r'] * e['theta'] ** 2)
    assert e['L_M'] == pytest.approx(CH4.L_sr * e['theta'])


def test_overrides_reach_the_adapter():
    law = declare_law(FakeNode(law='thesis', gamma_t=0.5, decimation=3, L_sigma=0.006),
                      CH4, 0.9, 0.95)
    assert law.gains.law == 'thesis' and law.gains.gamma_t == 0.5 and law.N == 3
    assert law.gains.L_sigma == 0.006
    assert law.estimates()['R_r'] == 0.9


@pytest.mark.parametrize('name, value', [('sigma_min', 0.9), ('R_r_min', 50.0)])
def test_inconsistent_values_name_the_parameter(name, value):
    with pytest.raises(InvalidParameter, match=name):
        declare_law(FakeNode(**{name: value}), CH4, 0.842, 0.952941)


def test_adapter_node_declares_the_law():
    import rclpy
    from rclpy.context import Context
    from rclpy.parameter import Parameter

    from im_adapt.adapter_node import AdapterNode
    ctx = Context()
    rclpy.init(context=ctx, domain_id=private_domain())
    try:
        node = AdapterNode(context=ctx, parameter_overrides=[
            Parameter('law', Parameter.Type.STRING, 'thesis'),
            Parameter('gamma_r', Parameter.Type.DOUBLE, 5.0)])
        try:
            assert isinstance(node.law, ParameterAdapter)
            assert node.law.gains.law == 'thesis' and node.law.gains.gamma_r == 5.0
            d = node.describe_parameters(['gamma_r'])[0]
            assert 'eq. 4.9' in d.description and d.floating_point_range
        finally:
            node.destroy_node()
        with pytest.raises(Exception, match='law'):
            AdapterNode(context=ctx, parameter_overrides=[
                Parameter('law', Parameter.Type.STRING, 'lms')])
    finally:
        rclpy.try_shutdown(context=ctx)
