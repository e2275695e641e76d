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
    from im_common.params import THESIS_MOTOR
    from im_common.saturation import saturated_model_from_text
    from im_common.validation import InvalidParameter
    import yaml
    with pytest.raises(InvalidParameter, match="'saturation_model'.*not a YAML mapping"):
        saturated_model_from_text('{law: [', THESIS_MOTOR, 'saturation_model', yaml.safe_load)
    with pytest.raises(InvalidParameter, match='saturation_model.beta'):
        saturated_model_from_text('{law: power, S: 7}', THESIS_MOTOR, 'saturation_model',
                                  yaml.safe_load)
    assert saturated_model_from_text('', THESIS_MOTOR, 'saturation_model', yaml.safe_load) is None
