"""Ray intersection against brute-force dense sampling, and r against finite differences."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from spline_cases import corner_between, dense_samples, wall_curves

from bsslam.spline import BSplineCurve, clamped_knots, fit_curve
from bsslam.spline.intersect import intersect_rays

SETTINGS = settings(max_examples=40, deadline=None)
# Beams closer than this to the tangent are grazing (the filter drops them); there two
# roots can lie within one coarse sample and the search may miss the pair.
GRAZING_SIN = np.sin(np.radians(3.0))


def _brute_force(curve: BSplineCurve, origin: np.ndarray, angles: np.ndarray):
    """Nearest sign change of ỹ with x̃ > 0 on 50 001 samples, linearly interpolated.

    Returns (range (m,), sin of the incidence angle (m,)), NaN where no hit.
    """
    t, pts = dense_samples(curve, 50_001)
    tangent = curve.evaluate(t, der=1)
    c, s = np.cos(angles)[:, None], np.sin(angles)[:, None]
    dx, dy = pts[:, 0] - origin[0], pts[:, 1] - origin[1]
    xt, yt = c * dx + s * dy, c * dy - s * dx  # (m, n)
    change = (yt[:, :-1] > 0) != (yt[:, 1:] > 0)
    w = yt[:, :-1] / np.where(change, yt[:, :-1] - yt[:, 1:], 1.0)
    rng = np.where(change, xt[:, :-1] + w * (xt[:, 1:] - xt[:, :-1]), np.nan)
    rng[rng <= 0] = np.nan
    nearest = np.where(np.all(np.isnan(rng), axis=1), 0, np.nanargmin(np.where(np.isnan(rng), np.inf, rng), axis=1))
    best = rng[np.arange(len(angles)), nearest]
    tan = tangent[nearest] / np.linalg.norm(tangent[nearest], axis=1)[:, None]
    incidence = np.abs(np.cos(angles) * tan[:, 1] - np.sin(angles) * tan[:, 0])
    return best, np.where(np.isnan(best), np.nan, incidence)


def _check_hits_lie_on_rays(curve, origin, angles, hits):
    pts = curve.evaluate(hits.t[hits.hit])
    expected = origin + hits.range[hits.hit, None] * np.column_stack([np.cos(angles), np.sin(angles)])[hits.hit]
    np.testing.assert_allclose(pts, expected, rtol=0, atol=1e-8)
    assert np.all(hits.range[hits.hit] > 0)
    assert np.all(np.isnan(hits.t[~hits.hit]) & np.isnan(hits.range[~hits.hit]) & np.isnan(hits.r[~hits.hit]))


@settings(max_examples=25, deadline=None)
@given(curve=wall_curves(), seed=st.integers(0, 2**32 - 1))
def test_global_search_matches_brute_force(curve, seed):
    rng = np.random.default_rng(seed)
    box = curve.bbox()
    origin = rng.uniform(box[:2] - 2.0, box[2:] + 2.0)
    angles = rng.uniform(-np.pi, np.pi, 40)
    hits = intersect_rays(curve, origin, angles)
    _check_hits_lie_on_rays(curve, origin, angles, hits)
    brute, incidence = _brute_force(curve, origin, angles)
    clear = ~(incidence < GRAZING_SIN)  # NaN (no brute-force hit) counts as clear
    np.testing.assert_array_equal(hits.hit[clear], ~np.isnan(brute[clear]))
    np.testing.assert_allclose(hits.range[clear], brute[clear], rtol=0, atol=1e-5)


@SETTINGS
@given(curve=wall_curves(), seed=st.integers(0, 2**32 - 1), shift=st.floats(-0.05, 0.05))
def test_newton_from_guesses_agrees_with_global_search(curve, seed, shift):
    rng = np.random.default_rng(seed)
    box = curve.bbox()
    origin = rng.uniform(box[:2] - 2.0, box[2:] + 2.0)
    angles = rng.uniform(-np.pi, np.pi, 60)
    reference = intersect_rays(curve, origin, angles)
    # Guesses near the true hit (as data association gives them), junk guesses for the
    # rays that miss (Newton fails there and the global search confirms the miss), and NaN.
    guess = np.where(reference.hit, reference.t + shift, rng.uniform(*curve.domain, 60))
    guess[::7] = np.nan
    hits = intersect_rays(curve, origin, angles, t0=guess)
    _check_hits_lie_on_rays(curve, origin, angles, hits)
    np.testing.assert_array_equal(hits.hit, reference.hit)
    # Away from grazing incidence Newton converges to the root next to its guess — unless a
    # corner (a knot where the curve is only C0, every knot of a polyline) lies between the
    # guess and that root: a ray through a corner's neighbourhood can cross both of its
    # sides, and the guess may sit on the far one (seed 529, degree 1: roots 0.031 apart).
    incidence_sin = 1.0 / np.hypot(1.0, reference.r)
    clear = reference.hit & (incidence_sin > GRAZING_SIN)
    clear &= ~corner_between(curve, reference.t, guess, tol=0.0)
    np.testing.assert_allclose(hits.t[clear], reference.t[clear], rtol=0, atol=1e-9)
    np.testing.assert_allclose(hits.range[clear], reference.range[clear], rtol=0, atol=1e-9)
    np.testing.assert_allclose(hits.r[clear], reference.r[clear], rtol=1e-6, atol=1e-9)


def _u_shape(degree: int) -> BSplineCurve:
    """A U opening to +y: left arm x = 0, bottom y = 0, right arm x = 4 (fitted)."""
    side = np.linspace(4.0, 0.0, 40)
    pts = np.concatenate([
        np.column_stack([np.zeros(40), side]),
        np.column_stack([np.linspace(0.1, 3.9, 39), np.zeros(39)]),
        np.column_stack([np.full(40, 4.0), side[::-1]]),
    ])
    return fit_curve(pts, degree, 0.5).curve


@pytest.mark.parametrize("degree", [1, 2, 3, 4])
def test_ray_crossing_twice_returns_the_nearest_positive_hit(degree):
    curve = _u_shape(degree)
    origin = np.array([-2.0, 2.0])
    hits = intersect_rays(curve, origin, np.array([0.0, np.pi, np.pi / 2, -np.pi / 8]))
    # East: both arms are ahead, the left arm (x ≈ 0) is nearer. West: both behind.
    # North: parallel to the arms, misses. East-south-east: the left arm, then the bottom.
    np.testing.assert_array_equal(hits.hit, [True, False, False, True])
    assert hits.range[0] == pytest.approx(2.0, abs=0.02)
    assert hits.range[3] == pytest.approx(2.0 / np.cos(np.pi / 8), abs=0.02)
    # From inside the U looking east, the left arm is behind: the right arm wins.
    inside = intersect_rays(curve, np.array([2.0, 2.0]), np.array([0.0]))
    assert inside.range[0] == pytest.approx(2.0, abs=0.02)


def test_max_range_turns_far_hits_into_misses():
    curve = _u_shape(3)
    hits = intersect_rays(curve, np.array([-2.0, 2.0]), np.array([0.0, 0.0]), max_range=1.5)
    assert not hits.hit.any()
    hits = intersect_rays(curve, np.array([-2.0, 2.0]), np.array([0.0]), t0=[3.0], max_range=1.5)
    assert not hits.hit.any()


def _smooth_wall() -> BSplineCurve:
    x = np.linspace(-4.0, 4.0, 200)
    return fit_curve(np.column_stack([x, 5.0 + 0.5 * np.sin(1.3 * x)]), 3, 1.0).curve


def test_r_gives_the_range_derivatives_of_spec_section_6():
    curve = _smooth_wall()
    origin = np.array([0.3, -0.2])
    mu = np.linspace(np.radians(60), np.radians(120), 25)
    hits = intersect_rays(curve, origin, mu)
    assert hits.hit.all()
    z, r = hits.range, hits.r
    h = 1e-6
    dz_dmu = (intersect_rays(curve, origin, mu + h).range - intersect_rays(curve, origin, mu - h).range) / (2 * h)
    np.testing.assert_allclose(dz_dmu, z * r, rtol=1e-6, atol=1e-7)
    for axis, expected in ((0, -np.cos(mu) - r * np.sin(mu)), (1, -np.sin(mu) + r * np.cos(mu))):
        step = np.zeros(2)
        step[axis] = h
        fd = (intersect_rays(curve, origin + step, mu).range - intersect_rays(curve, origin - step, mu).range) / (2 * h)
        np.testing.assert_allclose(fd, expected, rtol=1e-6, atol=1e-7)


def test_r_is_the_tangent_ratio_in_the_beam_frame():
    curve = _smooth_wall()
    origin = np.array([0.0, 0.0])
    mu = np.linspace(np.radians(50), np.radians(130), 9)
    hits = intersect_rays(curve, origin, mu)
    ds = curve.evaluate(hits.t, der=1)
    dx = np.cos(mu) * ds[:, 0] + np.sin(mu) * ds[:, 1]
    dy = np.cos(mu) * ds[:, 1] - np.sin(mu) * ds[:, 0]
    np.testing.assert_allclose(hits.r, dx / dy, rtol=1e-10)


def test_per_ray_origins_and_bad_shapes():
    curve = _smooth_wall()
    origins = np.array([[0.0, 0.0], [1.0, 0.0]])
    hits = intersect_rays(curve, origins, np.array([np.pi / 2, np.pi / 2]))
    expected = curve.evaluate(hits.t)
    np.testing.assert_allclose(expected[:, 0], [0.0, 1.0], atol=1e-9)
    with pytest.raises(ValueError, match="origins"):
        intersect_rays(curve, np.zeros((3, 2)), np.zeros(2))
    with pytest.raises(ValueError, match="t0"):
        intersect_rays(curve, np.zeros(2), np.zeros(2), t0=np.zeros(3))


def test_line_segment_exact_degree_one():
    curve = BSplineCurve(np.array([[1.0, -1.0], [1.0, 1.0]]), clamped_knots(2.0, 2.0, 1), 1)
    angles = np.array([0.0, np.pi / 4, -np.pi / 4, np.pi / 3, np.pi])
    hits = intersect_rays(curve, np.zeros(2), angles)
    np.testing.assert_array_equal(hits.hit, [True, True, True, False, False])
    np.testing.assert_allclose(hits.range[:3], [1.0, np.sqrt(2), np.sqrt(2)], rtol=1e-14)
