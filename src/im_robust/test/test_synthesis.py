"""Synthesis, certificate and cutting plane on small problems with known answers."""
from im_robust.certificate import certify
from im_robust.examples import (AIRCRAFT_A23_TYPO_READING, check_printed_solution, example1,
                                example3)
from im_robust.polytope import augmented, UncertainSystem
from im_robust.synthesis import synthesize
import numpy as np
import pytest


def scalar_continuous(a_values, b=1.0):
    return UncertainSystem([(np.array([[a]]), np.array([[b]])) for a in a_values], None, False)


def test_augmented_matches_eq_2_7():
    A = np.array([[1.0, 2.0], [3.0, 4.0]])
    B = np.array([[5.0], [6.0]])
    F, E = augmented(A, B)
    np.testing.assert_array_equal(F, [[1, 2, -5], [3, 4, -6], [0, 0, 0]])
    np.testing.assert_array_equal(E, [[0], [0], [1]])


def test_scalar_continuous_closed_form():
    # ẋ = a x − u, a ∈ [1, 2]: Θ = 2(a w1 − w2) ≤ −1, w1 ≥ 1, W ⪰ 0, min w3 ≥ w2²/w1.
    # Optimum: w1 = 1, w2 = a_max + 1/2 = 2.5, w3 = 6.25, G = 2.5.
    res = synthesize(scalar_continuous([1.0, 2.0]))
    assert res.status == 'certified'
    np.testing.assert_allclose(res.G, [[2.5]], atol=1e-5)
    np.testing.assert_allclose(res.objective, 6.25, atol=1e-5)
    # The certified decay rate of A − G = a − 2.5 is 0.5 at the worst vertex (a = 2).
    np.testing.assert_allclose(res.certificate.rate, 0.5, atol=1e-6)


def test_scalar_discrete_known_answers():
    # x⁺ = a x − u: one gain must satisfy |a − G| < 1 at every vertex.
    ok = UncertainSystem([(np.array([[a]]), np.array([[1.0]])) for a in (0.5, 2.0)], None, True)
    res = synthesize(ok)
    assert res.status == 'certified'
    G = res.G[0, 0]
    assert 1.0 < G < 1.5
    np.testing.assert_allclose(res.certificate.rate, max(abs(0.5 - G), abs(2.0 - G)), atol=1e-9)
    # a ∈ [−0.5, 2] spans more than 2: no common gain exists (the intervals (a − 1, a + 1) miss).
    bad = UncertainSystem([(np.array([[a]]), np.array([[1.0]])) for a in (-0.5, 2.0)], None, True)
    res = synthesize(bad)
    assert res.status == 'infeasible' and res.G is None


def test_certificate_rejects_a_wrong_gain():
    sysm = scalar_continuous([1.0, 2.0])
    assert certify(sysm, [[2.5]]).certified
    bad = certify(sysm, [[1.5]])                    # a − 1.5 = +0.5 at a = 2: unstable vertex
    assert not bad.certified
    assert bad.margin < 0 or bad.P is None
    sign_flipped = certify(sysm, [[-2.5]])          # wrong sign convention: u = +G y
    assert not sign_flipped.certified


def test_certificate_catches_a_solver_point_that_violates_the_constraints():
    # A P that does not satisfy the Lyapunov inequality must not certify, whatever its origin.
    sysm = scalar_continuous([1.0, 2.0])
    cert = certify(sysm, [[1.9]], P=np.array([[1.0]]))
    assert not cert.certified


def test_dense_grid_failure_withdraws_the_certificate():
    # A 'grid' model outside the hull of the vertices (a = 50 vs a ∈ [−1, 1]): the vertex
    # certificate holds, the grid check must withdraw it.
    sysm = scalar_continuous([-1.0, 1.0])
    res = synthesize(sysm, grid_models=[(np.array([[50.0]]), np.array([[1.0]]))])
    assert res.status == 'uncertified'
    assert res.G is None and res.rejected_G is not None


def test_unstabilizable_vertex_is_infeasible_and_gives_no_gain():
    # Second state is unstable (a22 = 1) and not reachable from u: no gain can help.
    A = np.array([[0.0, 0.0], [0.0, 1.0]])
    B = np.array([[1.0], [0.0]])
    sysm = UncertainSystem([(A, B), (A - 0.1 * np.eye(2), B)], None, False)
    for solver in ('clarabel', 'cutting-plane'):
        res = synthesize(sysm, solver=solver, bound=1e3)
        assert res.status == 'infeasible', (solver, res.status, res.message)
        assert res.G is None


def test_output_feedback_structure_gives_G_C():
    ex = example3()
    res = synthesize(ex.system, D=ex.D)
    assert res.status == 'certified'
    st_W = res.W
    n, r = ex.system.n, ex.system.r
    # W₂' W₁⁻¹ = [G 0] in transformed coordinates (eq. 3.35)
    K_t = np.linalg.solve(st_W[:n, :n], st_W[:n, n:]).T
    np.testing.assert_allclose(K_t[:, r:], 0.0, atol=1e-8)
    np.testing.assert_allclose(K_t[:, :r], res.G, atol=1e-8)
    assert res.norm_G ** 2 <= res.objective + 1e-6          # eq. 2.33 / 3.19


def test_cutting_plane_agrees_with_sdp_on_example3():
    ex = example3()
    sdp = synthesize(ex.system, D=ex.D, solver='clarabel')
    cut = synthesize(ex.system, D=ex.D, solver='cutting-plane')
    assert sdp.status == cut.status == 'certified'
    assert abs(cut.objective - sdp.objective) <= 1e-3 * sdp.objective
    np.testing.assert_allclose(cut.G, sdp.G, atol=1e-3)
    assert cut.iterations > 1


def test_cutting_plane_box_too_small_is_reported_as_infeasible():
    # Example 3's optimum has entries near 24; a box of 10 excludes it.
    ex = example3()
    res = synthesize(ex.system, D=ex.D, solver='cutting-plane', bound=10.0)
    assert res.status == 'infeasible' and res.G is None
    assert 'box' in res.message


def test_thesis_example1_is_certified_and_its_printed_W_is_not_feasible():
    ex = example1()
    grid = ex.system.grid_models(101)
    res = synthesize(ex.system, D=ex.D, grid_models=grid)
    assert res.status == 'certified'
    assert res.certificate.grid_points == 101 and res.certificate.grid_margin > 0
    closed = [A - B @ res.G @ ex.system.C for A, B in grid]
    assert max(np.linalg.eigvals(M).real.max() for M in closed) < 0
    chk = check_printed_solution(ex)
    assert max(chk['theta_max_eig']) > 0          # the printed W_o violates Θ_l ⪯ −I
    assert chk['objective'] < res.objective        # ... and undercuts the true optimum
    assert certify(ex.system, ex.G_printed).certified   # its G is nevertheless stabilizing


def test_example1_printed_W_is_feasible_only_with_a23_read_as_0_035():
    """
    Seed 001 example 1 both ways.

    With a23 = 0.35 as printed, the printed W_o violates (3.33) at both vertices by far; with
    a23 = 0.035 both vertex constraints hold and are active to print precision (λ_max(Θ_l) ≈ −ε
    = −1), which is what a solution of the LP looks like. W_o itself does not depend on A: its
    λ_min(W) is the same small negative number (4-digit rounding).
    """
    printed = check_printed_solution(example1())
    typo = check_printed_solution(example1(AIRCRAFT_A23_TYPO_READING))
    assert min(printed['theta_max_eig']) > 100.0 and not printed['theta_ok']
    assert typo['theta_ok'] and max(abs(v + 1.0) for v in typo['theta_max_eig']) < 0.01
    assert typo['lambda_min_W'] == printed['lambda_min_W'] and abs(typo['lambda_min_W']) < 0.05
    # the printed G is the one the printed W gives
    assert typo['G_mismatch'] < 1e-4
    ex = example1(AIRCRAFT_A23_TYPO_READING)
    assert ex.key == '1-a23' and certify(ex.system, ex.G_printed).certified


@pytest.mark.parametrize('bad', [np.nan, np.inf])
def test_bad_input_is_rejected(bad):
    with pytest.raises(ValueError, match='NaN or inf'):
        UncertainSystem([(np.array([[bad]]), np.array([[1.0]]))])
