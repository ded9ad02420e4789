"""What a spline may tell the filter along itself (:mod:`bsslam.slam.bends`): the tangent
angle's gradient against finite differences, the weight's limits, the scaled Jacobian's
invariants, and the filter down a straight simulated corridor, where the paper's update
grows overconfident along the walls and the limited one stays inside the χ² band."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from bsslam.config import SLAMConfig
from bsslam.eval.consistency import pose_errors
from bsslam.experiments.consistency import simulation_config
from bsslam.pipeline import run_dataset
from bsslam.sim import SimConfig, simulate
from bsslam.sim.worlds import large_corridor
from bsslam.slam.bends import bend_weight, scale_along_splines, tangent_angle_rows
from bsslam.spline.curve import BSplineCurve
from bsslam.spline.knots import clamped_knots_with_spans


def _curve(rng, n=7, degree=3):
    knots = clamped_knots_with_spans(float(n - degree), n - degree, degree)
    control = np.column_stack([np.arange(n, dtype=float), 0.3 * rng.normal(size=n)])
    return BSplineCurve(control, knots, degree)


def test_the_tangent_angle_and_its_gradient_match_the_curve_and_finite_differences():
    rng = np.random.default_rng(0)
    curve = _curve(rng)
    t = np.array([0.2, 1.7, 3.9])
    angle, rows = tangent_angle_rows(curve.knots, curve.degree, curve.control_points, t)
    d = curve.evaluate(t, 1)
    np.testing.assert_allclose(angle, np.arctan2(d[:, 1], d[:, 0]), atol=1e-12)
    n = curve.n_control
    eps = 1e-7
    for j in range(2 * n):
        moved = curve.control_points.copy()
        moved[j % n, j // n] += eps
        up, _ = tangent_angle_rows(curve.knots, curve.degree, moved, t)
        moved[j % n, j // n] -= 2 * eps
        down, _ = tangent_angle_rows(curve.knots, curve.degree, moved, t)
        np.testing.assert_allclose(rows[:, j], (up - down) / (2 * eps), atol=1e-6)


def test_the_weight_is_zero_within_the_noise_continuous_and_tends_to_one():
    assert bend_weight(0.0, 1e-6) == 0.0 and bend_weight(0.0, 0.0) == 0.0
    assert bend_weight(1e-3, 1e-6) == 0.0                     # exactly at σ
    assert bend_weight(1e-3 * (1 + 1e-12), 1e-6) == pytest.approx(0.0, abs=1e-11)
    assert bend_weight(-3e-3, 1e-6) == pytest.approx(1 - 1 / 9)
    assert bend_weight(1.0, 1e-6) == pytest.approx(1.0, abs=1e-5)


def _rows(rng, m=12):
    """Jacobian rows of m beams on one spline of 5 control points (state 3–12) plus another
    spline's columns: ∂z/∂(x, y) = g, ∂z/∂(x_j, y_j) = −β_j g, β a partition of unity."""
    normal = np.array([0.05, 1.0]) / np.hypot(0.05, 1.0)
    g = -(normal + 0.01 * rng.normal(size=(m, 2))) / rng.uniform(0.7, 1.0, (m, 1))
    beta = rng.dirichlet(np.ones(4), size=m)
    first = rng.integers(0, 2, m)
    cols = np.arange(16)                     # pose, x_0..x_4 (3–7), y_0..y_4 (8–12), another (13–15)
    H = np.zeros((m, cols.size))
    H[:, :2] = g
    H[:, 2] = rng.normal(size=m)
    for i in range(m):
        H[i, 3 + first[i]: 7 + first[i]] = -beta[i] * g[i, 0]
        H[i, 8 + first[i]: 12 + first[i]] = -beta[i] * g[i, 1]
    return H, cols, np.arange(3, 8), np.arange(8, 13)


def test_scaling_removes_the_along_spline_part_and_keeps_the_gauge():
    rng = np.random.default_rng(1)
    H, cols, idx_x, idx_y = _rows(rng)
    group = np.zeros(H.shape[0], dtype=np.intp)
    group[-3:] = 5                  # three rows of another spline, not weighted: left alone
    mine = group == 0
    spline = {0: (idx_x, idx_y)}

    def scaled(w):
        out = H.copy()
        scale_along_splines(out, cols, group, {0: w}, spline)
        return out

    out = scaled(0.0)
    g = H[mine, :2]
    normal = (g / np.linalg.norm(g, axis=1, keepdims=True)).sum(axis=0)
    tangent = np.array([-normal[1], normal[0]]) / np.hypot(*normal)
    # nothing is left along the spline's mean tangent: moving the robot along it changes no range
    np.testing.assert_allclose(out[mine, :2] @ tangent, 0.0, atol=1e-12)
    # across the spline nothing changes
    np.testing.assert_allclose(out[:, :2] @ normal, H[:, :2] @ normal, rtol=1e-12)
    # the heading, the other spline's columns and the other spline's rows are untouched
    np.testing.assert_array_equal(out[:, 2], H[:, 2])
    np.testing.assert_array_equal(out[:, 13:], H[:, 13:])
    np.testing.assert_array_equal(out[~mine], H[~mine])
    # moving the robot and the whole spline together changes no range, before and after
    for H_ in (H, out):
        np.testing.assert_allclose(H_[mine, 0] + H_[mine][:, idx_x].sum(axis=1), 0.0, atol=1e-12)
        np.testing.assert_allclose(H_[mine, 1] + H_[mine][:, idx_y].sum(axis=1), 0.0, atol=1e-12)
    # w = 1 changes nothing; w = ½ removes half
    np.testing.assert_allclose(scaled(1.0), H, atol=1e-15)
    np.testing.assert_allclose(scaled(0.5)[mine, :2] @ tangent, 0.5 * (H[mine, :2] @ tangent), atol=1e-12)


def _corridor_nees(bends: bool, seeds: int = 8, steps: int = 50) -> float:
    """Pose NEES (3 dof, exact ground truth) averaged over the first ``steps`` steps and
    ``seeds`` runs down the straight stretch of the 80 × 50 m corridor loop, the default
    spline and mapping settings (ρ = 1 m, extension on)."""
    sim = SimConfig()
    base = SLAMConfig()
    config = simulation_config(base, sim).replace(backend="ekf")
    config = config.replace(observation=dataclasses.replace(config.observation, significant_bends_only=bends))
    values = []
    for seed in range(seeds):
        data = simulate(large_corridor(80.0, 50.0), sim, seed=seed, steps=steps + 1)
        values.append(pose_errors(run_dataset(data, config, point_stride=0).estimate, data.ground_truth).nees[1:])
    return float(np.mean(values))


def test_down_a_straight_corridor_the_filter_stays_consistent_only_with_significant_bends():
    """The paper's update reads the fitted walls' wiggles as shape and grows overconfident
    along the corridor; limited to significant bends its pose NEES is χ²(3)-like (mean 3;
    the upper bound allows for the steps of a run being correlated)."""
    upper = 3.6
    assert 2.0 < _corridor_nees(True) < upper
    assert _corridor_nees(False) > upper       # 4.5 (5.1 before extensions were placed by their geometry)
