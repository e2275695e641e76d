"""
The drive on the magnetizing curve in the graph (docs/plant.md §2, "The drive on the curve").

The observer and controller nodes take the curve (``saturation_model``) and run the same numbers
as the ROS-free loop.
"""
from dataclasses import replace

import pytest


@pytest.mark.slow
def test_the_graph_on_the_curve_computes_what_the_ros_free_loop_computes():
    from im_bringup.offline import simulate
    from im_bringup.testing import run_graph
    from test_real_plant import _reversal_on_the_curve
    sc = replace(_reversal_on_the_curve(saturation_model=True), duration=0.3)
    offline = simulate(sc).summary
    graph = run_graph(scenario=sc)
    for key in ('E_in_J', 'E_loss_J', 'V_max_V'):      # the step-exact books
        assert graph.summary[key] == pytest.approx(offline[key], rel=1e-9), key
    linear = simulate(replace(sc, saturation_model=False)).summary
    assert abs(linear['E_in_J'] / offline['E_in_J'] - 1.0) > 1e-4     # the curve did act


def test_a_bad_curve_parameter_is_one_line():
    from im_common.node_params import block_from_parameters
    from im_common.saturation import SaturationBlock
    from im_common.validation import InvalidParameter
    on = {'saturation_model.enabled': True}
    with pytest.raises(InvalidParameter, match="'saturation_model.law' = 'table'"):
        block_from_parameters(SaturationBlock, dict(on, **{'saturation_model.law': 'table'}),
                              'saturation_model')
    with pytest.raises(InvalidParameter, match="'saturation_model.beta' = None: is missing"):
        block_from_parameters(SaturationBlock, dict(on, **{'saturation_model.S': 7.0}),
                              'saturation_model')
    assert block_from_parameters(SaturationBlock, {}, 'saturation_model') is None
