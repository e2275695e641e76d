"""
The drive's flux on the magnetizing curve (docs/controller.md §10, docs/plant.md §2).

min_loss's steady optimum and the optimal plan take the curve's copper term A φ²(1 + b φ^S)²;
the loss floor of a run on a saturating plant is the program with that term, and the drive on the
curve reaches it.
"""
import math

from im_common.params import THESIS_MOTOR as M
from im_common.saturation import saturation_from_dict
from im_controller.flux import flux_min_loss
from im_controller.flux_plan import loss_rates, plan_flux, saturation_terms
from im_controller.reference import ModelCoefficients
import numpy as np
import pytest

CURVE = {'law': 'power', 'beta': 1.439, 'S': 7.0}


def _sat():
    c = ModelCoefficients.from_params(M)
    return c, saturation_terms(c, saturation_from_dict(CURVE, M.L_M))


def test_the_curve_adds_the_magnetizing_current_the_plant_draws():
    """
    loss_rates on the curve: R_s i_ds² + ... with i_ds = i_M(ψ_R)/... from the curve itself.

    At a steady point (ẏ = 0) the stator copper of the d-axis is R_s (i_M(θφ))², i_M from the
    curve's own current(ψ): the (b, S) form in y is the same curve.
    """
    c, sat = _sat()
    curve = saturation_from_dict(CURVE, M.L_M)
    for phi in (0.2, 0.45, 0.6):
        y = np.array([phi * phi])
        cu, _ = loss_rates(c, y, np.zeros(1), np.zeros(1), np.zeros(1), sat=sat)
        i_d = curve.current(c.theta * phi)          # inverse-Γ: i_M(ψ_R) is the stator i_d
        assert cu[0] == pytest.approx(M.R_s * i_d * i_d, rel=1e-9)


def test_min_loss_on_the_curve_is_the_steady_minimum():
    """Newton on the convex steady loss: the brute-force minimum over φ to 1e-5 Wb."""
    c, sat = _sat()
    for tau, w in ((5.0, 100.0), (12.0, 50.0), (2.0, 150.0)):
        phi = flux_min_loss(c, tau, w, 0.01, 5.0, M.k_e, M.k_h, 2.0, sat)
        grid = np.linspace(0.05, 1.0, 200001)
        f_e = abs(c.v * w + c.R_r * tau / (c.v * phi * phi)) / (2 * math.pi)   # at the solution
        cu, _ = loss_rates(c, grid * grid, 0 * grid, tau + 0 * grid, w + 0 * grid, sat=sat)
        K = (M.k_h + M.k_e * f_e) * f_e * c.theta ** 2
        best = grid[np.argmin(cu + K * grid * grid)]
        assert phi == pytest.approx(best, abs=1e-5), (tau, w)
        linear = flux_min_loss(c, tau, w, 0.01, 5.0, M.k_e, M.k_h)
        assert phi < linear           # the curve makes flux dearer: its optimum lies lower


def test_the_floor_on_the_curve_is_above_the_linear_one_and_meets_it_without_saturation():
    c, sat = _sat()
    t = np.linspace(0.0, 0.5, 251)
    tau = 6.0 + 2.0 * np.sin(8.0 * t[:-1])
    w = 80.0 + 0 * tau
    linear = plan_flux(c, t, tau, w, 0.4, k_e=M.k_e, k_h=M.k_h)
    curved = plan_flux(c, t, tau, w, 0.4, k_e=M.k_e, k_h=M.k_h, sat=sat)
    assert curved.loss_J > linear.loss_J * 1.001
    flat = plan_flux(c, t, tau, w, 0.4, k_e=M.k_e, k_h=M.k_h, sat=(0.0, 7.0))
    assert flat.loss_J == pytest.approx(linear.loss_J, rel=1e-6)


@pytest.mark.slow
def test_on_a_saturating_real_plant_optimal_sits_on_the_floor(tmp_path):
    """
    A ±100 rad/s reversal on a saturating real plant, the drive on the curve.

    Every block but the thermal (switched inverter compensated, iron loss acting, the thesis
    curve): optimal within 1 % of the floor on the curve, min_loss within 2 %, none below it
    (measured 1.0009 and 1.0114).
    """
    import json
    from im_studies.loss_bound import main
    path = tmp_path / 'run.yaml'
    path.write_text(f"""task: speed
start: steady
omega0: 100.0
duration: 2.0
profile: {{setpoints: [{{t: 0.0, velocity: 100.0}}, {{t: 0.3, velocity: -100.0, duration: 1.0}}]}}
load: {{kind: constant, tau: 2.0}}
inverter: {{V_dc: 600.0, pwm_frequency: 10000.0, deadtime: 2.0e-6, v_on: 1.0, r_on: 0.02}}
saturation: {json.dumps(CURVE)}
iron_loss: true
compensation: inverter
saturation_model: true
""")
    out = tmp_path / 'f.json'
    assert main([str(path), '--run', 'min_loss', '--run', 'optimal', '--json', str(out)]) == 0
    runs = json.loads(out.read_text())['runs']
    assert runs['optimal']['ratio_loss'] < 1.01
    assert runs['min_loss']['ratio_loss'] < 1.02
    for st, r in runs.items():
        assert r['ratio_loss'] > 1.0 - 1e-4, st
