"""The seams' shared heading drift rate: the factor's Jacobians against finite
differences, the graph with it against a dense least-squares oracle (scipy), and what it
is for — a drift a loop closure reveals corrected on every seam."""

from __future__ import annotations

import pickle

import gtsam
import numpy as np
import pytest
from scipy.optimize import least_squares

from bsslam import se2
from bsslam.submaps.drift_factor import drift_corrected, drift_error
from bsslam.submaps.pose_graph import PoseGraph
from .test_pose_graph import se2_log, whitener


def _corrected(z: np.ndarray, rate: float, distance: float) -> np.ndarray:
    """:func:`drift_corrected` on (3,) coordinates (x m, y m, φ rad)."""
    c = drift_corrected(gtsam.Pose2(*z), rate, distance)
    return np.array([c.x(), c.y(), c.theta()])


def _pose(rng) -> gtsam.Pose2:
    return gtsam.Pose2(*rng.uniform(-5, 5, 2), rng.uniform(-np.pi, np.pi))


@pytest.mark.parametrize("seed", range(5))
def test_the_jacobians_match_central_differences(seed):
    rng = np.random.default_rng(seed)
    z, xi, xj = _pose(rng), _pose(rng), _pose(rng)
    distance, rate = rng.uniform(1, 30), rng.normal(0, 0.003)
    H = [None] * 3
    drift_error(z, distance, xi, xj, rate, H)
    h = 1e-6
    moves = [lambda step: (xi.retract(step), xj), lambda step: (xi, xj.retract(step))]
    for move, J in zip(moves, H[:2]):
        numeric = np.empty((3, 3))
        for c in range(3):
            step = np.zeros(3)
            step[c] = h
            plus, minus = drift_error(z, distance, *move(step), rate), drift_error(z, distance, *move(-step), rate)
            numeric[:, c] = (plus - minus) / (2 * h)
        np.testing.assert_allclose(J, numeric, atol=1e-7)
    numeric = (drift_error(z, distance, xi, xj, rate + h) - drift_error(z, distance, xi, xj, rate - h)) / (2 * h)
    np.testing.assert_allclose(H[2].ravel(), numeric, rtol=1e-6, atol=1e-6)


def test_the_corrected_seam_turns_back_the_drift_and_its_chord_by_half():
    z = gtsam.Pose2(3.0, 1.0, 0.4)
    assert drift_corrected(z, 0.0, 20.0).equals(z, 1e-15)
    c = drift_corrected(z, 0.01, 10.0)             # 0.1 rad over the submap
    assert c.theta() == pytest.approx(0.4 - 0.1)
    rot = np.array([[np.cos(-0.05), -np.sin(-0.05)], [np.sin(-0.05), np.cos(-0.05)]])
    np.testing.assert_allclose([c.x(), c.y()], rot @ [3.0, 1.0], atol=1e-14)


# A square driven twice round, 10 m a side, the heading of each seam off by a constant
# rate; one loop closure at the end of the first round.
SIDE = 10.0
TRUE_RATE = -0.002          # rad/m: 1.15° a side
SEAM_COV = np.diag([0.02 ** 2, 0.02 ** 2, 0.003 ** 2])
LOOP_COV = np.diag([0.01 ** 2, 0.01 ** 2, 0.001 ** 2])


def _square(rng=None):
    truth = [np.zeros(3)]
    seams = []
    for _ in range(8):
        u = np.array([SIDE, 0.0, np.pi / 2])
        truth.append(se2.compose(truth[-1], u))
        z = _corrected(u, -TRUE_RATE, SIDE)     # the drift put in
        if rng is not None:
            z = z + rng.multivariate_normal(np.zeros(3), SEAM_COV)
        seams.append(z)
    return np.array(truth), seams


def _graph(seams, truth, sigma, loops=((0, 4),)):
    g = PoseGraph(np.zeros(3), loop_outliers=None, drift_rate_sigma=sigma)
    for z in seams:
        g.add_node(z, SEAM_COV, SIDE)
    for i, j in loops:
        g.add_loop(i, j, se2.between(truth[i], truth[j]), LOOP_COV)
    g.optimize()
    return g


def test_the_graph_with_a_drift_rate_is_the_least_squares_solution():
    rng = np.random.default_rng(3)
    truth, seams = _square(rng)
    sigma = 0.001
    g = _graph(seams, truth, sigma)
    W0 = np.linalg.cholesky(np.linalg.inv(1e-9 * np.eye(3))).T

    def res(v):
        P, rate = v[:-1].reshape(-1, 3), v[-1]
        out = [W0 @ se2_log(P[0])]
        for k, z in enumerate(seams):
            zc = _corrected(z, rate, SIDE)
            out.append(whitener(SEAM_COV, z[2]) @ se2_log(se2.between(zc, se2.between(P[k], P[k + 1]))))
        z = se2.between(truth[0], truth[4])
        out.append(whitener(LOOP_COV, z[2]) @ se2_log(se2.between(z, se2.between(P[0], P[4]))))
        out.append([rate / sigma])
        return np.concatenate(out)

    oracle = least_squares(res, np.r_[g.poses().ravel(), 0.0], xtol=1e-15, ftol=1e-15, gtol=1e-15).x
    np.testing.assert_allclose(g.poses(), oracle[:-1].reshape(-1, 3), atol=1e-6)
    assert g.drift_rate()[0] == pytest.approx(oracle[-1], abs=1e-8)


def test_a_loop_closure_reveals_the_rate_and_it_corrects_the_seams_beyond_it():
    truth, seams = _square()
    with_rate = _graph(seams, truth, 0.001)
    without = _graph(seams, truth, 0.0)
    rate, sigma = with_rate.drift_rate()
    assert abs(rate - TRUE_RATE) < 3 * sigma < 0.001
    # the second round has no loop closure: only the rate corrects it
    err = lambda g: np.abs(se2.between(g.pose(8), truth[8]))[2]   # noqa: E731
    assert err(with_rate) < 0.1 * err(without)


def test_without_a_loop_closure_the_rate_moves_no_pose_but_widens_the_covariance():
    truth, seams = _square()
    with_rate = _graph(seams, truth, 0.001, loops=())
    without = _graph(seams, truth, 0.0, loops=())
    np.testing.assert_allclose(with_rate.poses(), without.poses(), atol=1e-9)
    assert with_rate.drift_rate()[0] == pytest.approx(0.0, abs=1e-12)
    # heading σ after 80 m: the shared rate adds 80 m × 0.001 rad/m in quadrature
    var_with, var_without = with_rate.covariance(8)[2, 2], without.covariance(8)[2, 2]
    assert var_with - var_without == pytest.approx(0.08 ** 2, rel=1e-3)


def test_a_graph_with_a_drift_rate_pickles_to_the_same_numbers():
    rng = np.random.default_rng(5)
    truth, seams = _square(rng)
    g = _graph(seams, truth, 0.001)
    g.covariance(3)
    g.drift_rate()
    back = pickle.loads(pickle.dumps(g))
    np.testing.assert_array_equal(back.poses(), g.poses())
    np.testing.assert_array_equal(back.covariance(6), g.covariance(6))
    assert back.drift_rate() == g.drift_rate()


@pytest.mark.parametrize("bad", [-1e-3, np.nan, np.inf])
def test_a_bad_drift_rate_sigma_or_distance_is_refused(bad):
    with pytest.raises(ValueError, match="drift_rate_sigma"):
        PoseGraph(np.zeros(3), drift_rate_sigma=bad)
    g = PoseGraph(np.zeros(3), drift_rate_sigma=0.001)
    with pytest.raises(ValueError, match="distance_m"):
        g.add_node(np.array([1.0, 0.0, 0.0]), np.eye(3), bad)


def test_gnc_classifies_loop_closures_in_a_graph_with_a_drift_rate():
    # GTSAM's GNC clones every factor, which a factor written in Python cannot do: the
    # classification takes the seams with the rate held at its estimate, and iSAM2 then
    # solves for it with the inliers. Seams that admit a drift of their own (as the
    # backend's do, ``seam_drift_rad_per_m``) keep the right loop closures inliers.
    truth, seams = _square()
    seam_cov = SEAM_COV + np.diag([0.0, 0.0, (0.001 * SIDE) ** 2])
    g = PoseGraph(np.zeros(3), loop_outliers="gnc", drift_rate_sigma=0.001)
    for z in seams:
        g.add_node(z, seam_cov, SIDE)
    g.add_loop(0, 4, se2.between(truth[0], truth[4]), LOOP_COV)
    g.add_loop(1, 5, se2.between(truth[1], truth[5]), LOOP_COV)
    wrong = se2.compose(se2.between(truth[2], truth[6]), np.array([3.0, -2.0, 0.5]))
    g.add_loop(2, 6, wrong, LOOP_COV)
    assert g.optimize() == []
    np.testing.assert_array_equal(g.loop_weights(), [1.0, 1.0, 0.0])
    rate, sigma = g.drift_rate()
    assert abs(rate - TRUE_RATE) < 3 * sigma and rate < -3 * sigma     # found, and its sign
    back = pickle.loads(pickle.dumps(g))
    np.testing.assert_array_equal(back.poses(), g.poses())
