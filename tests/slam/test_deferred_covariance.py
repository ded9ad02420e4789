"""The state defers P ← P − Z Zᵀ (P = base − D Dᵀ): whatever is read, transformed, appended
or removed in between, it equals the dense covariance, and folding keeps P exactly symmetric."""

import numpy as np

from bsslam.slam.motion import predict
from bsslam.slam.state import POSE, JointState


def random_spd(rng, n):
    A = rng.normal(size=(n, n))
    return A @ A.T / n + 0.1 * np.eye(n)


def test_pending_updates_read_and_fold_like_the_dense_covariance():
    rng = np.random.default_rng(7)
    n = 300   # more than one fold block of rows
    P = random_spd(rng, n)
    state = JointState(np.zeros(3), P[:3, :3], capacity=4, max_pending=10)
    state.append(np.zeros(n - 3), P[3:, :3], P[3:, 3:])
    dense = P.copy()
    cols = np.array([0, 1, 2, 17, 40, 299])
    for k in (4, 5, 3, 12, 2):   # fills the pending buffer, overflows it, exceeds its width
        Z = rng.normal(size=(n, k)) * 0.05
        state.subtract_low_rank(Z)
        dense -= Z @ Z.T
        np.testing.assert_allclose(state.columns(cols), dense[:, cols], atol=1e-12)
        np.testing.assert_allclose(state.block(cols[2:], cols), dense[np.ix_(cols[2:], cols)], atol=1e-12)
        np.testing.assert_allclose(state.diagonal(cols), np.diag(dense)[cols], atol=1e-12)
        np.testing.assert_allclose(state.pose_covariance, dense[:3, :3], atol=1e-12)
    assert state.pending.shape[1] > 0
    np.testing.assert_allclose(state.P, dense, atol=1e-12)
    assert state.pending.shape[1] == 0
    np.testing.assert_array_equal(state.P, state.P.T)


def test_prediction_transform_append_and_removal_carry_the_pending_term():
    rng = np.random.default_rng(8)
    n = 40
    P = random_spd(rng, n)
    state = JointState(rng.normal(size=3), P[:3, :3], capacity=4, max_pending=64)
    state.append(rng.normal(size=n - 3), P[3:, :3], P[3:, 3:])
    Z = rng.normal(size=(n, 6)) * 0.05
    state.subtract_low_rank(Z)
    dense = P - Z @ Z.T
    x = state.x.copy()
    # prediction on the base, F_x carried through the pending term
    delta, Q = np.array([0.3, 0.05, 0.1]), np.diag([1e-4, 1e-4, 1e-5])
    F_x = predict(state.x, state.base, delta, Q)
    state.transform_pending(POSE, F_x)
    predict(x, dense, delta, Q)
    np.testing.assert_allclose(state.x, x, atol=1e-15)
    np.testing.assert_allclose(state.columns(np.arange(n)), dense, atol=1e-12)
    # an extension's transform of a block
    idx = np.array([5, 9, 10, 30])
    T = rng.normal(size=(4, 4))
    state.transform(idx, T)
    A = np.eye(n)
    A[np.ix_(idx, idx)] = T
    dense = A @ dense @ A.T
    x[idx] = T @ x[idx]
    np.testing.assert_allclose(state.x, x, atol=1e-12)
    np.testing.assert_allclose(state.columns(np.arange(n)), dense, atol=1e-12)
    # new entries, then removal of some old and some new ones
    cross = rng.normal(size=(3, n)) * 0.01
    state.append(np.ones(3), cross, np.eye(3))
    dense = np.block([[dense, cross.T], [cross, np.eye(3)]])
    gone = np.array([4, 20, n + 1])
    state.remove(gone)
    keep = np.setdiff1d(np.arange(n + 3), gone)
    dense = dense[np.ix_(keep, keep)]
    np.testing.assert_allclose(state.columns(np.arange(keep.size)), dense, atol=1e-12)
    np.testing.assert_allclose(state.P, dense, atol=1e-12)
    np.testing.assert_array_equal(state.P, state.P.T)
