"""Every Jacobian of the filter against central finite differences."""

import numpy as np
import pytest

from bsslam.slam.enlarge import beam_points, extension_block, new_feature_block
from bsslam.se2 import compose
from bsslam.se2 import compose_jacobians
from observation_oracle import predict_beams
from bsslam.spline import BSplineCurve, clamped_knots, extend_curve, fit_curve


def central_diff(f, x0, eps=1e-6):
    x0 = np.asarray(x0, dtype=float)
    cols = []
    for i in range(x0.size):
        d = np.zeros_like(x0)
        d.flat[i] = eps
        cols.append((np.asarray(f(x0 + d)) - np.asarray(f(x0 - d))) / (2 * eps))
    return np.stack(cols, axis=-1)


def wavy_wall(degree=3, n=9):
    """A wavy wall 3 m in front of the origin, running along x."""
    knots = clamped_knots(8.0, 8.0 / (n - degree), degree, start=0.0)
    xs = np.linspace(-4, 4, n)
    cps = np.column_stack([xs, 3.0 + 0.3 * np.sin(1.3 * xs)])
    return BSplineCurve(cps, knots, degree)


@pytest.mark.parametrize("delta", [(0.3, -0.1, 0.2), (0.0, 0.0, 0.0), (-0.5, 0.4, -1.0)])
def test_motion_jacobians(delta):
    pose = np.array([1.0, -2.0, 0.7])
    delta = np.array(delta)
    F_x, F_u = compose_jacobians(pose, delta)
    np.testing.assert_allclose(F_x, central_diff(lambda p: compose(p, delta), pose), atol=1e-8)
    np.testing.assert_allclose(F_u, central_diff(lambda u: compose(pose, u), delta), atol=1e-8)


@pytest.mark.parametrize("degree", [1, 2, 3, 4])
@pytest.mark.parametrize("offset", [(0.0, 0.0, 0.0), (0.2, -0.05, 0.1)])
def test_beam_jacobians_pose_and_control_points(degree, offset):
    curve = wavy_wall(degree)
    offset = np.array(offset)
    pose = np.array([0.3, 0.2, np.pi / 2 - 0.1])
    bearings = np.linspace(-0.6, 0.6, 7)
    pred = predict_beams(curve, pose, offset, bearings)
    assert pred.hit.all()

    def ranges_at_pose(p):
        return predict_beams(curve, p, offset, bearings).z

    np.testing.assert_allclose(pred.H_pose, central_diff(ranges_at_pose, pose), rtol=1e-5, atol=1e-6)

    cps = curve.control_points

    def ranges_at_cps(flat):
        return predict_beams(curve.with_control_points(flat.reshape(-1, 2)), pose, offset, bearings).z

    J = central_diff(ranges_at_cps, cps.ravel())  # (m, 2n) interleaved x0,y0,x1,y1…
    n = cps.shape[0]
    dense_x = np.zeros((bearings.size, n))
    dense_y = np.zeros((bearings.size, n))
    for row in range(bearings.size):
        cols = pred.first_cp[row] + np.arange(degree + 1)
        dense_x[row, cols] = pred.H_cp_x[row]
        dense_y[row, cols] = pred.H_cp_y[row]
    np.testing.assert_allclose(dense_x, J[:, 0::2], rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(dense_y, J[:, 1::2], rtol=1e-5, atol=1e-6)


def scan_of_wall(curve, pose, bearings):
    return predict_beams(curve, pose, np.zeros(3), bearings).z


@pytest.mark.parametrize("offset", [(0.0, 0.0, 0.0), (0.15, 0.05, -0.2)])
def test_new_feature_jacobians(offset):
    offset = np.array(offset)
    pose = np.array([0.5, -0.2, np.pi / 2 + 0.05])
    bearings = np.linspace(-0.5, 0.5, 40)
    ranges = 3.0 + 0.1 * np.sin(5 * bearings)
    pts_robot = np.column_stack([ranges * np.cos(bearings), ranges * np.sin(bearings)])
    phi = fit_curve(pts_robot, 3, 0.8).phi

    def mean(pose_, ranges_):
        return new_feature_block(phi, beam_points(pose_, offset, bearings, ranges_)).mean

    block = new_feature_block(phi, beam_points(pose, offset, bearings, ranges))
    np.testing.assert_allclose(block.J, central_diff(lambda p: mean(p, ranges), pose), atol=1e-7)
    np.testing.assert_allclose(block.G_z, central_diff(lambda z: mean(pose, z), ranges), atol=1e-7)
    # Φ·1 = 1 on a clamped fit: ∂X/∂x = 1, ∂X/∂y = 0
    n = phi.shape[0]
    np.testing.assert_allclose(block.J[:n, 0], 1.0, atol=1e-9)
    np.testing.assert_allclose(block.J[:n, 1], 0.0, atol=1e-12)


@pytest.mark.parametrize("side", ["left", "right"])
def test_extension_jacobians(side):
    curve = wavy_wall(3, 8)
    lo, hi = curve.domain
    pose = np.array([0.0, 0.0, np.pi / 2])
    # new data beyond the chosen end: the wall continued as a straight line
    k = 25
    if side == "right":
        end, tangent = curve.evaluate(np.array([hi]))[0], curve.evaluate(np.array([hi]), der=1)[0]
        s = np.linspace(0.05, 1.5, k)
        params = hi + s
    else:
        end, tangent = curve.evaluate(np.array([lo]))[0], -curve.evaluate(np.array([lo]), der=1)[0]
        s = np.linspace(1.5, 0.05, k)
        params = lo - s
    tangent /= np.linalg.norm(tangent)
    points = end + s[:, None] * tangent
    bearings = np.arctan2(points[:, 1], points[:, 0]) - pose[2]
    ranges = np.hypot(points[:, 0], points[:, 1])
    ext = extend_curve(curve, side, points, params, 0.8)
    n_old, m = curve.n_control, ext.n_added
    new_rows = ext.psi[n_old:] if side == "right" else ext.psi[:m]
    idx_x, idx_y = np.arange(3, 3 + n_old), np.arange(3 + n_old, 3 + 2 * n_old)

    def mean(pose_, cps_, ranges_):
        bp = beam_points(pose_, np.zeros(3), bearings, ranges_)
        return extension_block(new_rows, n_old, idx_x, idx_y, cps_, bp).mean

    cps = curve.control_points
    block = extension_block(new_rows, n_old, idx_x, idx_y, cps, beam_points(pose, np.zeros(3), bearings, ranges))
    np.testing.assert_allclose(block.J[:, :3], central_diff(lambda p: mean(p, cps, ranges), pose), atol=1e-7)
    J_cp = central_diff(lambda c: mean(pose, np.column_stack([c[:n_old], c[n_old:]]), ranges),
                        np.concatenate([cps[:, 0], cps[:, 1]]))
    np.testing.assert_allclose(block.J[:, 3:], J_cp, atol=1e-7)
    np.testing.assert_allclose(block.G_z, central_diff(lambda z: mean(pose, cps, z), ranges), atol=1e-7)
    # and the block's mean is the extension's new control points
    new_cps = ext.curve.control_points[n_old:] if side == "right" else ext.curve.control_points[:m]
    np.testing.assert_allclose(block.mean, np.concatenate([new_cps[:, 0], new_cps[:, 1]]), atol=1e-9)
