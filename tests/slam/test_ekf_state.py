"""The stacked low-rank update against the textbook dense EKF, and state bookkeeping."""

import numpy as np
import pytest

from bsslam.slam.ekf import stacked_update
from bsslam.slam.motion import motion_jacobians, predict
from bsslam.slam.state import JointState


def random_spd(rng, n):
    A = rng.normal(size=(n, n))
    return A @ A.T / n + 0.1 * np.eye(n)


def make_state(rng, n):
    P = random_spd(rng, n)
    s = JointState(rng.normal(size=3), P[:3, :3], capacity=4)
    s.append(rng.normal(size=n - 3), P[3:, :3], P[3:, 3:])
    return s, P


@pytest.mark.parametrize("m", [3, 40])  # fewer and more beams than touched columns
def test_stacked_update_equals_dense_ekf(m):
    rng = np.random.default_rng(1)
    n = 30
    state, P0 = make_state(rng, n)
    x0 = state.x.copy()
    cols = np.array([0, 1, 2, 5, 6, 7, 20, 21])
    H_c = rng.normal(size=(m, cols.size))
    nu = rng.normal(size=m) * 0.01
    R = 0.01 ** 2
    res = stacked_update(state, cols, H_c, nu, R, gate=None)
    H = np.zeros((m, n))
    H[:, cols] = H_c
    S = H @ P0 @ H.T + R * np.eye(m)
    K = P0 @ H.T @ np.linalg.inv(S)
    np.testing.assert_allclose(state.x, x0 + K @ nu, atol=1e-10)
    np.testing.assert_allclose(state.P, (np.eye(n) - K @ H) @ P0, atol=1e-10)
    np.testing.assert_allclose(state.P, state.P.T, atol=0)
    assert np.all(np.linalg.eigvalsh(state.P) > 0)
    np.testing.assert_allclose(res.nis, nu @ np.linalg.solve(S, nu), rtol=1e-9)


def test_gate_drops_outliers_only():
    rng = np.random.default_rng(2)
    state, _ = make_state(rng, 10)
    cols = np.arange(3)
    H_c = rng.normal(size=(5, 3))
    nu = np.zeros(5)
    nu[3] = 100.0  # far outside any plausible S
    res = stacked_update(state, cols, H_c, nu, 1e-4, gate=6.63)
    assert res.accepted.tolist() == [True, True, True, False, True]


def test_predict_touches_only_pose_rows_and_columns():
    rng = np.random.default_rng(3)
    state, P0 = make_state(rng, 12)
    delta = np.array([0.4, 0.1, 0.2])
    Q = np.diag([1e-4, 2e-4, 3e-4])
    pose0 = state.x[:3].copy()
    predict(state.x, state.P, delta, Q)
    F_x, F_u = motion_jacobians(pose0, delta)
    F = np.eye(12)
    F[:3, :3] = F_x
    expected = F @ P0 @ F.T
    expected[:3, :3] += F_u @ Q @ F_u.T
    np.testing.assert_allclose(state.P, expected, atol=1e-12)


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
