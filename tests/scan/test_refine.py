"""Knot refinement of splines entering the map (scan/refine.py)."""

import numpy as np

from bsslam.scan.refine import fit_bias_scores, refine_for_map
from bsslam.spline import fit_curve

SIGMA = 0.005


def beams_on(points_true, rng):
    """Noisy laser points (sensor at the origin) of true points: noise along each beam."""
    r = np.hypot(points_true[:, 0], points_true[:, 1])
    u = points_true / r[:, None]
    return points_true + (SIGMA * rng.standard_normal(r.shape))[:, None] * u


def straight_wall(n=150):
    x = np.linspace(3.0, -3.0, n)
    return np.column_stack([x, np.full(n, 3.0)])


def line_then_arc(n=200):
    """A straight wall y = 3 for x ∈ [1, −1], then a quarter circle of radius 0.5 m turning
    towards the sensor: the curvature jumps from 0 to 2 m⁻¹ at the join."""
    line = np.column_stack([np.linspace(1.0, -1.0, n // 2), np.full(n // 2, 3.0)])
    a = np.linspace(np.pi / 2, np.pi, n // 2)
    arc = np.column_stack([-1.0 + 0.5 * np.cos(a), 2.5 + 0.5 * np.sin(a)])
    return np.vstack([line, arc[1:]])


def test_scores_are_standard_normal_under_pure_noise():
    """The variance formula is right: on an exactly representable wall the normalised
    differences between the coarse and the fine fit have about unit variance (measured
    0.89 RMS: the chord-length parameters, fixed in the formula, absorb a little noise)."""
    rng = np.random.default_rng(0)
    z = []
    for _ in range(40):
        pts = beams_on(straight_wall(), rng)
        coarse = fit_curve(pts, 3, 1.0)
        fine = fit_curve(pts, 3, 0.5, params=coarse.params)
        z.append(fit_bias_scores(coarse, fine, pts, SIGMA))
    z = np.concatenate(z)
    assert 0.8 < np.sqrt(np.mean(z ** 2)) < 1.1


def test_a_straight_wall_is_not_refined():
    rng = np.random.default_rng(1)
    pts = beams_on(straight_wall(), rng)
    fit = fit_curve(pts, 3, 1.0)
    assert refine_for_map(fit, pts, SIGMA, 0.25, 4.0).curve.n_control == fit.curve.n_control


def deviation_from(truth_dense, fit):
    """Largest distance (m) from the fitted curve to the true wall."""
    lo, hi = fit.curve.domain
    c = fit.curve.evaluate(np.linspace(lo, hi, 800))
    return np.sqrt(((c[:, None, :] - truth_dense[None]) ** 2).sum(-1)).min(axis=1).max()


def test_a_line_arc_join_is_refined_and_the_bias_goes():
    truth_dense = line_then_arc(4000)
    for seed in range(3):
        pts = beams_on(line_then_arc(), np.random.default_rng(seed))
        fit = fit_curve(pts, 3, 1.0)
        refined = refine_for_map(fit, pts, SIGMA, 0.25, 4.0)
        assert refined.curve.n_control > fit.curve.n_control
        before, after = deviation_from(truth_dense, fit), deviation_from(truth_dense, refined)
        assert before > 1.5 * SIGMA        # the 1 m spacing cannot follow the join (≈ 1 cm off)
        assert after < 0.6 * before and after < 1.5 * SIGMA
