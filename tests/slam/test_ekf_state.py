"""The stacked low-rank update against the textbook dense EKF, and state bookkeeping."""

import numpy as np
import pytest

from bsslam.slam.ekf import StackedGain, innovation_variances
from bsslam.se2 import compose_jacobians
from bsslam.slam.motion import predict_state
from motion_oracle import predict
from bsslam.slam.state import JointState


def random_spd(rng, n):
    A = rng.normal(size=(n, n))
    return A @ A.T / n + 0.1 * np.eye(n)


def make_state(rng, n):
    P = random_spd(rng, n)
    s = JointState(rng.normal(size=3), P[:3, :3], capacity=4)
    s.append(rng.normal(size=n - 3), P[3:, :3], P[3:, 3:])
    return s, P


def dense_problem(rng, n, m, cols):
    state, P0 = make_state(rng, n)
    H_c = rng.normal(size=(m, cols.size))
    H = np.zeros((m, n))
    H[:, cols] = H_c
    return state, P0, H_c, H


COLS = np.array([0, 1, 2, 5, 6, 7, 20, 21])


@pytest.mark.parametrize("m", [3, 12, 40])  # fewer beams than touched columns, more, and ≥ 2× more (compressed)
def test_stacked_gain_equals_dense_ekf(m):
    rng = np.random.default_rng(1)
    n, R = 30, 0.01 ** 2
    state, P0, H_c, H = dense_problem(rng, n, m, COLS)
    x0 = state.x.copy()
    nu = rng.normal(size=m) * 0.01
    gain = StackedGain(state.P, COLS, H_c, R)
    dx, nis = gain.correction(nu)
    state.x[:] += dx
    gain.update_covariance(state)
    S = H @ P0 @ H.T + R * np.eye(m)
    K = P0 @ H.T @ np.linalg.inv(S)
    np.testing.assert_allclose(state.x, x0 + K @ nu, atol=1e-10)
    np.testing.assert_allclose(state.P, (np.eye(n) - K @ H) @ P0, atol=1e-10)
    np.testing.assert_allclose(state.P, state.P.T, atol=0)
    assert np.all(np.linalg.eigvalsh(state.P) > 0)
    np.testing.assert_allclose(nis, nu @ np.linalg.solve(S, nu), rtol=1e-9)
    np.testing.assert_allclose(gain.S_diag, np.diag(S), rtol=1e-12)


def test_a_gain_on_working_rows_corrects_them_and_the_whole_state_like_the_dense_ekf():
    """The iterations read P only on working rows (the pose and the observed splines);
    the whole state is corrected once, from the same gain, with a deferred update pending."""
    from bsslam.errors import FilterError
    from bsslam.slam.ekf import CovarianceColumns

    rng = np.random.default_rng(5)
    n, m, R = 40, 12, 1e-4
    state, P0, H_c, H = dense_problem(rng, n, m, COLS)
    W = rng.normal(size=(COLS.size, 4)) * 0.05   # a pending update: P = base − B G Bᵀ
    state.subtract_column_update(COLS, W)
    Z = P0[:, COLS] @ W
    P = P0 - Z @ Z.T
    assert state.pending_rank > 0
    work = np.array([0, 1, 2, 4, 5, 6, 7, 8, 20, 21, 22, 30])
    columns = CovarianceColumns(state, work)
    np.testing.assert_allclose(columns.get(COLS), P[np.ix_(work, COLS)], atol=1e-12)
    np.testing.assert_allclose(columns.block(COLS), P[np.ix_(COLS, COLS)], atol=1e-12)
    # the first request read every working row; the rest are served from it
    np.testing.assert_allclose(columns.get(work), P[np.ix_(work, work)], atol=1e-12)
    nu = rng.normal(size=m) * 0.01
    gain = StackedGain(columns, COLS, H_c, R)
    K = P @ H.T @ np.linalg.inv(H @ P @ H.T + R * np.eye(m))
    dx_work, nis = gain.correction(nu)
    np.testing.assert_allclose(dx_work, (K @ nu)[work], atol=1e-12)
    dx, nis_whole = gain.state_correction(nu)
    np.testing.assert_allclose(dx, K @ nu, atol=1e-12)
    assert nis_whole == nis
    assert state.pending_rank > 0   # read without folding
    with pytest.raises(FilterError, match="outside the working rows"):
        columns.get(np.array([0, 1, 2, 9]))
    with pytest.raises(FilterError, match="start with the pose"):
        CovarianceColumns(state, np.array([1, 2, 3]))


@pytest.mark.parametrize("m", [3, 40])
def test_the_update_checks_the_pose_variances_it_leaves(m):
    """The update's check of the pose's variances uses the gain's numbers: they are the
    posterior's; a gain that takes off more than the prior holds is refused."""
    from bsslam.errors import FilterError

    rng = np.random.default_rng(6)
    n, R = 30, 0.01 ** 2
    state, P0, H_c, H = dense_problem(rng, n, m, COLS)
    gain = StackedGain(state.P, COLS, H_c, R)
    expected = np.diag(P0)[:3] - gain._pose_variance_drop()
    gain.update_covariance(state)
    np.testing.assert_allclose(np.diag(state.pose_covariance), expected, atol=1e-12)
    state, P0, H_c, H = dense_problem(rng, n, m, COLS)
    broken = StackedGain(state.P, COLS, H_c, R)
    broken.Y = broken.Y * 10.0          # a hundred times the information the beams carry
    with pytest.raises(FilterError, match="lost positive definiteness"):
        broken.update_covariance(state)


@pytest.mark.parametrize("m", [12, 40])   # the gain in measurement space, and compressed
def test_gate_variances_prior_and_posterior_equal_dense_formulas(m):
    """The filter gates at the prior with diag(H P Hᵀ) + R and at the corrected estimate with
    diag(H' P⁺ H'ᵀ) + R, for a relinearised H' on other columns."""
    rng = np.random.default_rng(2)
    n, R = 30, 1e-4
    state, P0, H_c, H = dense_problem(rng, n, m, COLS)
    np.testing.assert_allclose(innovation_variances(P0, COLS, H_c, R), np.diag(H @ P0 @ H.T) + R, rtol=1e-12)
    gain = StackedGain(P0, COLS, H_c, R)
    K = P0 @ H.T @ np.linalg.inv(H @ P0 @ H.T + R * np.eye(m))
    P_post = (np.eye(n) - K @ H) @ P0
    cols2 = np.array([0, 1, 2, 6, 7, 8, 25])
    H2_c = rng.normal(size=(9, cols2.size))
    H2 = np.zeros((9, n))
    H2[:, cols2] = H2_c
    np.testing.assert_allclose(gain.posterior_variances(cols2, H2_c, R), np.diag(H2 @ P_post @ H2.T) + R,
                               rtol=1e-9)


def test_predict_touches_only_pose_rows_and_columns():
    rng = np.random.default_rng(3)
    state, P0 = make_state(rng, 12)
    delta = np.array([0.4, 0.1, 0.2])
    Q = np.diag([1e-4, 2e-4, 3e-4])
    pose0 = state.x[:3].copy()
    x, dense = state.x.copy(), P0.copy()
    predict_state(state, delta, Q)
    predict(x, dense, delta, Q)      # the dense oracle the other tests mirror the state with
    F_x, F_u = compose_jacobians(pose0, delta)
    F = np.eye(12)
    F[:3, :3] = F_x
    expected = F @ P0 @ F.T
    expected[:3, :3] += F_u @ Q @ F_u.T
    np.testing.assert_allclose(state.P, expected, atol=1e-12)
    np.testing.assert_allclose(dense, expected, atol=1e-12)
    np.testing.assert_array_equal(state.x, x)


def test_growth_and_removal_keep_values():
    rng = np.random.default_rng(4)
    state, P0 = make_state(rng, 9)
    x0 = state.x.copy()
    cap0 = state.capacity
    idx = state.append(np.arange(40.0), np.zeros((40, 9)), np.eye(40))  # forces growth
    assert state.capacity > cap0 and state.size == 49
    np.testing.assert_array_equal(state.x[:9], x0)
    np.testing.assert_array_equal(state.P[:9, :9], P0)
    mapping = state.remove(idx)
    assert state.size == 9
    np.testing.assert_array_equal(state.x, x0)
    np.testing.assert_array_equal(state.P, P0)
    assert (mapping[idx] == -1).all() and (mapping[:9] == np.arange(9)).all()


def _no_return_scan():
    from bsslam.scan import LaserScan
    angles = np.linspace(-np.pi / 2, np.pi / 2, 181)
    return LaserScan(0.0, angles, np.full(181, 100.0), max_range=80.0)


def test_step_with_given_odometry_covariance_propagates_it():
    """Without features the step is a pure prediction: P = F_u Q F_uᵀ from a known start."""
    from bsslam.slam import SplineSLAM
    from bsslam.se2 import compose_jacobians
    slam = SplineSLAM(initial_pose=(1.0, 2.0, 0.7))
    delta = np.array([0.4, -0.1, 0.2])
    A = np.array([[0.02, 0.0, 0.0], [0.005, 0.01, 0.0], [0.001, 0.002, 0.03]])
    Q = A @ A.T
    slam.step(delta, _no_return_scan(), odometry_covariance=Q)
    _, F_u = compose_jacobians(np.array([1.0, 2.0, 0.7]), delta)
    np.testing.assert_allclose(slam.pose_covariance, F_u @ Q @ F_u.T, atol=1e-15)


def test_step_rejects_an_indefinite_odometry_covariance():
    from bsslam.errors import InputError
    from bsslam.slam import SplineSLAM
    slam = SplineSLAM()
    with pytest.raises(InputError, match="covariance"):
        slam.step(np.array([0.1, 0.0, 0.0]), _no_return_scan(), odometry_covariance=np.diag([1.0, -1.0, 1.0]))
