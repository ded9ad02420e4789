"""Unclamping and extension: the old curve is untouched, new data are fitted, Ψ and T hold."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.interpolate import BSpline
from spline_cases import curves

from bsslam.errors import FitError, SplineError
from bsslam.spline import BSplineCurve, chord_length_parameters, clamped_knots, fit_curve
from bsslam.spline.extend import continuation_parameters, extend_curve, runs_outward, unclamp

SETTINGS = settings(max_examples=50, deadline=None)
SIDES = ("left", "right")


def _new_knots(curve: BSplineCurve, side: str, gaps: list[float]) -> np.ndarray:
    lo, hi = curve.domain
    steps = np.cumsum(gaps)
    return hi + steps if side == "right" else (lo - steps)[::-1]


def _assert_same_on(domain, before: BSplineCurve, knots, control, degree, atol=1e-9):
    """scipy, as an independent evaluator, sees the same curve on ``domain``."""
    t = np.linspace(*domain, 1001)
    np.testing.assert_allclose(BSpline(knots, control, degree)(t), before.evaluate(t), rtol=0, atol=atol)


@SETTINGS
@given(
    curve=curves(clamped=True),
    side=st.sampled_from(SIDES),
    gaps=st.lists(st.one_of(st.just(0.0), st.floats(0.05, 3.0)), min_size=4, max_size=4),
    first_gap=st.floats(0.05, 3.0),
)
def test_unclamping_keeps_the_curve_and_t_maps_control_points(curve, side, gaps, first_gap):
    p = curve.degree
    new = _new_knots(curve, side, [first_gap] + gaps[: p - 1])
    knots, control, transform = unclamp(curve.knots, curve.control_points, p, side, new)
    _assert_same_on(curve.domain, curve, knots, control, p)
    np.testing.assert_allclose(transform @ curve.control_points, control, rtol=0, atol=1e-12)
    if side == "right":
        np.testing.assert_array_equal(knots[: curve.n_control + 1], curve.knots[: curve.n_control + 1])
        np.testing.assert_array_equal(knots[curve.n_control + 1 :], new)
    else:
        np.testing.assert_array_equal(knots[:p], new)
        np.testing.assert_array_equal(knots[p:], curve.knots[p:])
    # Only the degree − 1 control points next to the unclamped end move.
    moved = np.flatnonzero(np.any(transform != np.eye(curve.n_control), axis=1))
    assert moved.size <= p - 1
    if moved.size:
        assert (moved.min() >= curve.n_control - (p - 1)) if side == "right" else (moved.max() <= p - 2)


@pytest.mark.parametrize("side", SIDES)
def test_degree_one_unclamping_is_the_identity(side):
    curve = BSplineCurve(np.array([[0.0, 0.0], [1.0, 1.0], [2.0, 0.0]]), clamped_knots(2.0, 1.0, 1), 1)
    knots, control, transform = unclamp(curve.knots, curve.control_points, 1, side, _new_knots(curve, side, [0.7]))
    np.testing.assert_array_equal(transform, np.eye(3))
    np.testing.assert_array_equal(control, curve.control_points)


@pytest.mark.parametrize(
    ("knots", "side", "new", "match"),
    [
        (np.array([0, 0, 0, 0, 1, 2, 2, 2, 3.0]), "right", [4, 5, 6], "not clamped"),
        (clamped_knots(2.0, 1.0, 3), "right", [2.0, 3, 4], "beyond"),
        (clamped_knots(2.0, 1.0, 3), "left", [-3, -2, 0.0], "before"),
        (clamped_knots(2.0, 1.0, 3), "right", [3, 4], "3 finite"),
        (clamped_knots(2.0, 1.0, 3), "right", [5, 4, 6], "non-decreasing"),
        (clamped_knots(2.0, 1.0, 3), "up", [3, 4, 5], "side"),
    ],
)
def test_bad_unclamping_requests_raise(knots, side, new, match):
    with pytest.raises(SplineError, match=match):
        unclamp(knots, np.zeros((len(knots) - 4, 2)), 3, side, new)


def _arc(phi: np.ndarray, radius: float = 6.0) -> np.ndarray:
    return np.column_stack([radius * np.cos(phi), radius * np.sin(phi)])


def _old_and_new(side: str, degree: int, n_new: int = 120, sigma: float = 0.0, seed: int = 0):
    """An old curve fitted to one part of a 6 m-radius arc and data of the next part."""
    rng = np.random.default_rng(seed)
    phi = np.linspace(0.0, 2.0, 400)
    clean = _arc(phi)
    params = chord_length_parameters(clean)
    old = slice(0, 200) if side == "right" else slice(200, 400)
    new = slice(200, 200 + n_new) if side == "right" else slice(200 - n_new, 200)
    curve = fit_curve(clean[old], degree, 1.0, params=params[old]).curve
    noisy = clean[new] + rng.normal(0.0, sigma, clean[new].shape)
    return curve, noisy, params[new], phi[new]


@pytest.mark.parametrize("degree", [1, 2, 3, 4])
@pytest.mark.parametrize("side", SIDES)
def test_extension_keeps_the_old_part_and_psi_reproduces_control_points(degree, side):
    curve, data, params, _ = _old_and_new(side, degree, sigma=0.005)
    ext = extend_curve(curve, side, data, params, 1.0)
    _assert_same_on(curve.domain, curve, ext.curve.knots, ext.curve.control_points, degree)
    stacked = np.concatenate([curve.control_points, data])
    np.testing.assert_allclose(ext.psi @ stacked, ext.curve.control_points, rtol=0, atol=1e-12)
    assert ext.psi.shape == (curve.n_control + ext.n_added, curve.n_control + len(data))
    assert ext.curve.n_control == curve.n_control + ext.n_added and ext.side == side
    old_rows = slice(0, curve.n_control) if side == "right" else slice(ext.n_added, None)
    np.testing.assert_allclose(ext.curve.control_points[old_rows], ext.T @ curve.control_points, atol=1e-12)
    # The new end is clamped at the outermost parameter; the new spans follow ρ = 1 m.
    lo, hi = ext.curve.domain
    assert (hi == params.max() and lo == curve.domain[0]) if side == "right" else (lo == params.min())
    np.testing.assert_allclose(ext.curve.evaluate([hi if side == "right" else lo]),
                               ext.curve.control_points[[-1 if side == "right" else 0]], atol=1e-12)
    extent = params.max() - curve.domain[1] if side == "right" else curve.domain[0] - params.min()
    assert ext.n_added == int(np.ceil(extent / 1.0))


@pytest.mark.parametrize("degree", [1, 2, 3, 4])
@pytest.mark.parametrize("side", SIDES)
def test_new_control_points_solve_the_constrained_least_squares(degree, side):
    """Residuals are orthogonal to every new basis function (normal equations)."""
    curve, data, params, _ = _old_and_new(side, degree, sigma=0.01, seed=3)
    ext = extend_curve(curve, side, data, params, 1.0)
    residual = data - ext.curve.evaluate(params)
    basis = BSpline(ext.curve.knots, np.eye(ext.curve.n_control), degree)(params)
    new_cols = slice(curve.n_control, None) if side == "right" else slice(0, ext.n_added)
    np.testing.assert_allclose(basis[:, new_cols].T @ residual, 0.0, atol=1e-10)


@pytest.mark.parametrize("side", SIDES)
def test_extension_fits_noisy_points_to_noise_level(side):
    sigma = 0.005
    curve, data, params, phi = _old_and_new(side, 3, sigma=sigma, seed=11)
    ext = extend_curve(curve, side, data, params, 1.0)
    residual = np.linalg.norm(data - ext.curve.evaluate(params), axis=1)
    rms = np.sqrt(np.mean(residual**2))
    # Two noisy coordinates, a few parameters absorbed by the fit: RMS ≈ σ√2.
    assert 0.8 * sigma * np.sqrt(2) < rms < 1.2 * sigma * np.sqrt(2)
    # And the curve follows the true arc far more closely than the noise.
    truth_error = np.abs(np.linalg.norm(ext.curve.evaluate(params), axis=1) - 6.0)
    assert truth_error.max() < 2.0 * sigma


@pytest.mark.parametrize("degree", [2, 3, 4])
@pytest.mark.parametrize("side", SIDES)
def test_short_extension_with_fewer_new_spans_than_the_degree(degree, side):
    curve, data, params, _ = _old_and_new(side, degree, n_new=8)
    ext = extend_curve(curve, side, data, params, 1.0)
    assert ext.n_added == 1 < degree
    _assert_same_on(curve.domain, curve, ext.curve.knots, ext.curve.control_points, degree)
    # One new control point cannot bend freely, but it follows the arc within a millimetre.
    np.testing.assert_allclose(ext.curve.evaluate(params), data, rtol=0, atol=1e-3)


@pytest.mark.parametrize("side", SIDES)
def test_data_only_at_the_far_end_reduce_the_new_spans(side):
    curve, data, params, _ = _old_and_new(side, 3)
    far = slice(-10, None) if side == "right" else slice(0, 10)
    ext = extend_curve(curve, side, data[far], params[far], 0.5)
    extent = params.max() - curve.domain[1] if side == "right" else curve.domain[0] - params.min()
    assert ext.n_added < np.ceil(extent / 0.5)
    _assert_same_on(curve.domain, curve, ext.curve.knots, ext.curve.control_points, 3)
    np.testing.assert_allclose(ext.psi @ np.concatenate([curve.control_points, data[far]]),
                               ext.curve.control_points, atol=1e-12)


def test_extension_errors():
    curve, data, params, _ = _old_and_new("right", 3)
    with pytest.raises(SplineError, match="> the domain end"):
        extend_curve(curve, "right", data, params - 5.0, 1.0)
    with pytest.raises(SplineError, match="< the domain start"):
        extend_curve(curve, "left", data, params, 1.0)
    with pytest.raises(FitError, match="no data"):
        extend_curve(curve, "right", np.zeros((0, 2)), np.zeros(0), 1.0)
    with pytest.raises(SplineError, match="side"):
        extend_curve(curve, "middle", data, params, 1.0)
    with pytest.raises(SplineError, match="params"):
        extend_curve(curve, "right", data, params[:-1], 1.0)


@pytest.mark.parametrize("side", SIDES)
def test_continuation_parameters_continue_the_chord_length_of_the_wall(side):
    """New points of the same arc, in scan order, get the arc's own chord-length parameters
    (those the old curve was fitted on) to well below a millimetre; points not yet past the
    end (the old curve's last stretch, seen again) are left out."""
    curve, data, params, _ = _old_and_new(side, 3)
    phi = np.linspace(0.0, 2.0, 400)          # _old_and_new's: the old curve ends at phi[199] / starts at phi[200]
    overlap = _arc(phi[[196, 197, 198]] if side == "right" else phi[[201, 202, 203]])
    points = np.vstack([overlap, data]) if side == "right" else np.vstack([data, overlap])
    beyond, got = continuation_parameters(curve, side, points)
    np.testing.assert_array_equal(beyond, np.r_[np.zeros(3, bool), np.ones(len(data), bool)] if side == "right"
                                  else np.r_[np.ones(len(data), bool), np.zeros(3, bool)])
    np.testing.assert_allclose(got, params, rtol=0, atol=1e-4)
    assert np.all(np.diff(got) > 0)
    assert (got[0] > curve.domain[1]) if side == "right" else (got[-1] < curve.domain[0])


@pytest.mark.parametrize("side", SIDES)
def test_data_shifted_along_the_curve_bend_the_extension_away_from_the_wall(side):
    """Why the parameters come from the points' geometry: the same arc data with their
    parameters 5 cm off (an association interval ended 5 cm early or late) give an
    extension 3.6 mm off the 6 m arc — far more than a map spline's σ, and the same in every
    run that matched the same way — where the continued chord length follows it to 0.05 mm."""
    curve, data, _, _ = _old_and_new(side, 3)
    _, params = continuation_parameters(curve, side, data)
    shift = 0.05 if side == "right" else -0.05
    radius_error = {}
    for name, p in (("geometric", params), ("shifted", params + shift)):
        ext = extend_curve(curve, side, data, p, 1.0)
        radius_error[name] = np.abs(np.linalg.norm(ext.curve.evaluate(p), axis=1) - 6.0).max()
    assert radius_error["geometric"] < 2e-4
    assert radius_error["shifted"] > 2e-3


def test_no_point_past_the_end_gives_no_parameters():
    curve, _, _, _ = _old_and_new("right", 3)
    beyond, params = continuation_parameters(curve, "right", _arc(np.linspace(0.5, 0.9, 5)))
    assert not beyond.any() and params.shape == (0,)


def _curve(xs, ys, length):
    n = len(xs)
    knots = np.r_[[0.0] * 3, np.linspace(0.0, length, n - 2), [length] * 3]
    return BSplineCurve(np.column_stack([xs, ys]), knots, 3)


def test_an_extension_that_folds_back_is_refused():
    """An extension must run outward all along its new stretch: a wall continued straight
    passes, on either side; one whose fit overshoots its data's end and comes back along
    the wall (every point on the wall, so the distance check passes) does not."""
    old = _curve(np.linspace(0.0, 5.0, 6), np.zeros(6), 5.0)
    straight = _curve(np.linspace(0.0, 6.0, 8), np.zeros(8), 6.0)
    folded = _curve(np.r_[np.linspace(0.0, 5.0, 6), 6.4, 5.6], np.zeros(8), 6.0)
    assert runs_outward(old, straight, "right")
    assert not runs_outward(old, folded, "right")
    # the left side: the old curve's domain [1, 6] extended down to [0, 6]
    old_left = _shifted(_curve(np.linspace(1.0, 6.0, 6), np.zeros(6), 5.0), 1.0)
    straight_left = _curve(np.linspace(0.0, 6.0, 8), np.zeros(8), 6.0)
    folded_left = _curve(np.r_[0.4, -0.4, np.linspace(1.0, 6.0, 6)], np.zeros(8), 6.0)
    assert runs_outward(old_left, straight_left, "left")
    assert not runs_outward(old_left, folded_left, "left")


def _shifted(curve, dt):
    """``curve`` with its parameter moved by dt (m): the same points at t + dt."""
    return BSplineCurve(curve.control_points, curve.knots + dt, curve.degree)
