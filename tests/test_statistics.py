"""The shared statistics helpers against values worked out by hand, and the promise that the
package holds one definition of each."""

from __future__ import annotations

import math

import numpy as np
import pytest

from features import statistics as st

# ----------------------------------------------------------------------------- B-spline basis

def test_bspline_linear_hat_functions():
    # degree 1, three control points: knots 0 0 0.5 1 1, hat functions peaking at 0, 0.5, 1
    basis = st.bspline_basis([0.0, 0.25, 0.5, 1.0], 3, degree=1)
    np.testing.assert_allclose(basis, [[1, 0, 0], [0.5, 0.5, 0], [0, 1, 0], [0, 0, 1]])


def test_bspline_quadratic_known_values():
    # three control points of degree 2: the Bernstein polynomials (1-t)^2, 2t(1-t), t^2
    np.testing.assert_allclose(st.bspline_basis([0.5], 3, 2), [[0.25, 0.5, 0.25]])
    # four control points, knots 0 0 0 0.5 1 1 1: on the first span with u = 2t,
    # N0 = (1-u)^2, N1 = u (2 - 1.5 u), N2 = u^2 / 2
    np.testing.assert_allclose(st.bspline_basis([0.25, 0.5], 4, 2),
                               [[0.25, 0.625, 0.125, 0.0], [0.0, 0.5, 0.5, 0.0]])


@pytest.mark.parametrize("n_control, degree", [(1, 2), (2, 3), (5, 2), (8, 3), (15, 2)])
def test_bspline_partition_of_unity_and_shape(n_control, degree):
    t = np.linspace(0, 1, 101)
    basis = st.bspline_basis(t, n_control, degree)
    assert basis.shape == (101, n_control)
    np.testing.assert_allclose(basis.sum(axis=1), 1.0)
    assert (basis >= -1e-15).all()
    # clamped: the curve starts at the first control point and ends at the last
    assert basis[0, 0] == pytest.approx(1.0) and basis[-1, -1] == pytest.approx(1.0)


def test_bspline_degree_is_capped_by_the_control_points():
    # two control points of "degree 3" are the straight line between them
    np.testing.assert_allclose(st.bspline_basis([0.25], 2, 3), [[0.75, 0.25]])
    assert st.bspline_basis([], 4, 2).shape == (0, 4)


# ----------------------------------------------------------------------------- BIC

def test_bic_formula():
    # n ln(sse / n) + k ln(n) = 4 ln(1/2) + ln 4 = -2 ln 2
    assert st.bic(2.0, 4, 1) == pytest.approx(-2 * math.log(2))
    assert st.bic(0.0, 10, 2) == pytest.approx(10 * math.log(1e-301) + 2 * math.log(10))
    # a fractional parameter count (a search penalty) is allowed
    assert st.bic(2.0, 4, 1.5) - st.bic(2.0, 4, 1) == pytest.approx(0.5 * math.log(4))


# ----------------------------------------------------------------------------- grouped CV

def test_grouped_cv_least_squares_small_exact_example():
    # the mean model, two groups: leaving out a predicts it by 4.5, leaving out b by 1.5
    X, y = np.ones((4, 1)), np.array([1.0, 2.0, 3.0, 6.0])
    groups = np.array(["a", "a", "b", "b"])
    sse = (1 - 4.5) ** 2 + (2 - 4.5) ** 2 + (3 - 1.5) ** 2 + (6 - 1.5) ** 2
    assert st.grouped_cv_sse(X, y, groups) == pytest.approx(sse) == pytest.approx(41.0)
    assert st.grouped_cv_rmse(X, y, groups) == pytest.approx(math.sqrt(41.0 / 4))


def test_grouped_cv_uses_the_given_solver_and_fits_lines_exactly():
    X, y = np.ones((4, 1)), np.array([1.0, 2.0, 3.0, 6.0])
    zero = st.grouped_cv_sse(X, y, [0, 0, 1, 1], solve=lambda A, b: np.zeros(A.shape[1]))
    assert zero == pytest.approx(float(y @ y))
    x = np.arange(6.0)
    line = np.column_stack([np.ones(6), x])
    assert st.grouped_cv_sse(line, 2 + 3 * x, x % 3) == pytest.approx(0.0, abs=1e-20)


# ----------------------------------------------------------------------------- between visits

def test_within_share_known_values():
    # group means 1.5 and 3.5: within SS 4 x 0.25 = 1, total SS 5
    assert st.within_share([1.0, 2.0, 3.0, 4.0], [0, 0, 1, 1]) == pytest.approx(0.2)
    shares = st.within_share(np.array([[1, 5], [2, 5], [3, 5], [4, 6]]), ["a", "a", "b", "b"])
    np.testing.assert_allclose(shares, [0.2, 2 / 3])
    assert math.isnan(st.within_share([1.0, 2.0], [0, 0]))      # one group
    assert math.isnan(st.within_share([1.0, 1.0], [0, 1]))      # does not vary


def test_varies_only_between_uses_the_one_threshold():
    visits = ["a", "a", "b", "b"]
    assert st.varies_only_between([1.0, 1.1, 3.0, 3.1], visits)      # share 0.0025
    assert not st.varies_only_between([1.0, 2.0, 3.0, 4.0], visits)  # share 0.2
    assert not st.varies_only_between([1.0, 1.0, 1.0, 1.0], visits)
    assert st.MIN_LEVEL_SHARE == 0.1


def test_one_definition_per_idea():
    from features import ranking
    from models import discovery, influence
    from models.physics import effects
    from models.wear import wear_map

    assert effects.bspline_basis is st.bspline_basis
    assert ranking.PROXY_WITHIN_SHARE == influence.MIN_SHARE == st.MIN_LEVEL_SHARE
    assert discovery.bic is st.bic
    np.testing.assert_allclose(wear_map.spline_basis([0.0, 50.0, 100.0], 0.0, 100.0, 5),
                               st.bspline_basis([0.0, 0.5, 1.0], 5, 3))


# ----------------------------------------------------------------------------- typed nuisances

def test_every_effect_record_has_typed_nuisance_parameters():
    from models.discovery import terms

    kinds = {n.kind for name in terms.EFFECTS for n in terms.nuisances(name)}
    assert kinds <= {"data", "targets", "ends", "period", "values", "quadrature", "profile"}
    pitch, phase = terms.nuisances("lead_error_periodic")
    assert (pitch.kind, pitch.values, pitch.searched) == ("period", (4.0, 20.0), True)
    assert (phase.kind, phase.amplitude, phase.searched) == ("quadrature", "amplitude_um", False)
    assert terms.quadrature_pairs("lead_error_periodic") == [("phase_rad", "amplitude_um")]
    assert "lead_error_profile" in terms.PROFILES
    with pytest.raises(ValueError, match="unknown grid"):
        terms.parse_nuisance("k", "everywhere", "a_um")


def test_nuisance_grids_on_the_measured_targets():
    from models.discovery import terms

    x = np.array([0.0, 100.0, 100.0, 250.0])
    key, grid = terms.nuisance_grid("backlash_position", x)
    assert key == "center_mm" and grid.tolist() == [0.0, 100.0, 250.0]
    assert terms.nuisance_grid("thermal_expansion", x)[1].tolist() == [0.0, 250.0]
    key, pitches = terms.nuisance_grid("lead_error_periodic", x)
    # uniform in frequency from 1/20 to 1/4 per mm, step 1 / (4 x travel)
    np.testing.assert_allclose(np.diff(1 / pitches), 1 / 1000)
    assert pitches[0] == pytest.approx(20.0) and pitches[-1] == pytest.approx(4.0)
    assert terms.nuisance_grid("backlash", x) == (None, None)


@pytest.mark.parametrize("baseline, words", [("backlash,gremlins", "unknown effect 'gremlins'"),
                                             (" , ", "empty"),
                                             ("backlash,backlash", "listed twice")])
def test_discovery_baseline_errors_name_the_parameter(baseline, words):
    from features.readings.errors import InputError
    from models.discovery import check_baseline

    with pytest.raises(InputError, match=words) as caught:
        check_baseline(baseline)
    assert caught.value.parameter == "baseline" and "--" not in str(caught.value)
