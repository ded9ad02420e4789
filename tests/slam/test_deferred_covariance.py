"""The state defers P ← P − Z Zᵀ, Z = P[:, cols] W, and keeps it compressed (P = base − B G Bᵀ
on the lazy entries, the pose and the newest entries kept exactly): whatever is read,
predicted, transformed, appended or removed in between, it equals the dense covariance,
and folding keeps P exactly symmetric. The basis always holds the pose's three columns."""

import numpy as np

from bsslam.slam.motion import predict_state
from motion_oracle import predict
from bsslam.slam.state import POSE, JointState


def random_spd(rng, n):
    A = rng.normal(size=(n, n))
    return A @ A.T / n + 0.1 * np.eye(n)


def state_of(P, max_pending):
    """A JointState holding the covariance P (n, n): the pose, then n − 3 appended entries."""
    state = JointState(np.zeros(3), P[:3, :3], capacity=4, max_pending=max_pending)
    state.append(np.zeros(P.shape[0] - 3), P[3:, :3], P[3:, 3:])
    return state


def column_update(dense, cols, W):
    Z = dense[:, cols] @ W
    return dense - Z @ Z.T


def assert_reads_match(state, dense, cols):
    np.testing.assert_allclose(state.columns(cols), dense[:, cols], atol=1e-12)
    np.testing.assert_allclose(state.rows(cols), dense[cols], atol=1e-12)
    np.testing.assert_allclose(state.block(cols[2:], cols), dense[np.ix_(cols[2:], cols)], atol=1e-12)
    np.testing.assert_allclose(state.diagonal(cols), np.diag(dense)[cols], atol=1e-12)
    np.testing.assert_allclose(state.pose_covariance, dense[:3, :3], atol=1e-12)
    v = np.linspace(-1.0, 2.0, cols.shape[0])
    np.testing.assert_allclose(state.columns_times(cols, v), dense[:, cols] @ v, atol=1e-12)


def test_pending_updates_read_and_fold_like_the_dense_covariance():
    rng = np.random.default_rng(7)
    n = 300   # more than one fold block of rows
    P = random_spd(rng, n)
    state = state_of(P, max_pending=12)
    dense = P.copy()
    probe = np.array([0, 1, 2, 17, 40, 299])
    # overlapping column sets fill the basis slowly, then overflow it (a fold), then one
    # update is wider than the whole basis
    for cols in ([0, 1, 2, 17, 18], [0, 1, 2, 17, 18, 19], [0, 1, 2, 18, 19, 40], [0, 1, 2, 100, 101, 102, 299],
                 list(range(0, 30))):
        cols = np.array(cols)
        W = rng.normal(size=(cols.size, 3)) * 0.05
        state.subtract_column_update(cols, W)
        dense = column_update(dense, cols, W)
        assert_reads_match(state, dense, probe)
        assert_reads_match(state, dense, cols)
    assert state.pending_rank == 3   # the last update was wider than the basis: folded
    cols = np.array([0, 1, 2, 5])
    W = rng.normal(size=(4, 2)) * 0.05
    state.subtract_column_update(cols, W)
    dense = column_update(dense, cols, W)
    assert state.pending_rank == 4   # the pose's columns and the touched base column
    np.testing.assert_allclose(state.P, dense, atol=1e-12)
    np.testing.assert_array_equal(state.P, state.P.T)
    assert state.pending_rank == 3


def test_a_basis_shared_by_updates_stays_exact():
    rng = np.random.default_rng(9)
    n = 60
    P = random_spd(rng, n)
    state = state_of(P, max_pending=64)
    dense = P.copy()
    cols = np.array([0, 1, 2, 10, 11, 12, 13])
    for _ in range(6):   # the same columns: the basis does not grow
        W = rng.normal(size=(cols.size, cols.size)) * 0.1
        state.subtract_column_update(cols, W)
        dense = column_update(dense, cols, W)
    assert state.pending_rank == cols.size   # the pose's three and the four map columns
    assert_reads_match(state, dense, np.arange(n))
    np.testing.assert_allclose(state.P, dense, atol=1e-12)


def test_prediction_transform_appends_and_removal_carry_the_pending_term():
    rng = np.random.default_rng(8)
    n = 40
    P = random_spd(rng, n)
    state = JointState(rng.normal(size=3), P[:3, :3], capacity=4, max_pending=64)
    state.append(rng.normal(size=n - 3), P[3:, :3], P[3:, 3:])
    cols = np.array([0, 1, 2, 5, 9, 30])
    W = rng.normal(size=(6, 4)) * 0.05
    state.subtract_column_update(cols, W)
    dense = column_update(P, cols, W)
    x = state.x.copy()
    # prediction: the pose's rows, kept apart from the deferred term
    delta, Q = np.array([0.3, 0.05, 0.1]), np.diag([1e-4, 1e-4, 1e-5])
    predict_state(state, delta, Q)
    predict(x, dense, delta, Q)
    np.testing.assert_allclose(state.x, x, atol=1e-15)
    np.testing.assert_allclose(state.columns(np.arange(n)), dense, atol=1e-12)
    # the same columns updated again after the prediction
    W = rng.normal(size=(6, 4)) * 0.05
    state.subtract_column_update(cols, W)
    dense = column_update(dense, cols, W)
    np.testing.assert_allclose(state.columns(np.arange(n)), dense, atol=1e-12)
    # an extension's transform of a block, partly in the basis
    idx = np.array([5, 9, 10, 31])
    T = rng.normal(size=(4, 4))
    state.transform(idx, T)
    A = np.eye(n)
    A[np.ix_(idx, idx)] = T
    dense = A @ dense @ A.T
    x[idx] = T @ x[idx]
    np.testing.assert_allclose(state.x, x, atol=1e-12)
    state.subtract_column_update(cols, W)
    dense = column_update(dense, cols, W)
    np.testing.assert_allclose(state.columns(np.arange(n)), dense, atol=1e-12)
    # entries that depend linearly on old ones keep the basis valid
    src = np.array([0, 1, 2, 9, 30])
    J = rng.normal(size=(4, 5))
    noise = 0.01 * np.eye(4)
    state.append_dependent(np.ones(4), src, J, noise)
    cross = J @ dense[src]
    dense = np.block([[dense, cross.T], [cross, cross[:, src] @ J.T + noise]])
    n += 4
    np.testing.assert_allclose(state.columns(np.arange(n)), dense, atol=1e-12)
    cols = np.array([0, 1, 2, 9, n - 1])
    W = rng.normal(size=(5, 2)) * 0.05
    state.subtract_column_update(cols, W)
    dense = column_update(dense, cols, W)
    np.testing.assert_allclose(state.columns(np.arange(n)), dense, atol=1e-12)
    # entries with a given cross covariance, then removal of some old and some new ones
    cross = rng.normal(size=(3, n)) * 0.01
    state.append(np.ones(3), cross, np.eye(3))
    dense = np.block([[dense, cross.T], [cross, np.eye(3)]])
    n += 3
    state.subtract_column_update(cols, W)
    dense = column_update(dense, cols, W)
    gone = np.array([4, 20, n - 2])
    state.remove(gone)
    keep = np.setdiff1d(np.arange(n), gone)
    dense = dense[np.ix_(keep, keep)]
    np.testing.assert_allclose(state.columns(np.arange(keep.size)), dense, atol=1e-12)
    state.subtract_column_update(np.array([0, 1, 2, 8]), W[:4])
    dense = column_update(dense, np.array([0, 1, 2, 8]), W[:4])
    np.testing.assert_allclose(state.P, dense, atol=1e-12)
    np.testing.assert_array_equal(state.P, state.P.T)


def test_compiled_block_read_equals_numpy_indexing():
    """take_block serves every block read: unsorted and repeated indices, on a view of a
    padded buffer (the state's layout), give exactly numpy's P[np.ix_(rows, cols)]."""
    from bsslam.slam.kernels import take_block

    rng = np.random.default_rng(11)
    P = rng.normal(size=(70, 78))[:60, :60]
    rows = np.array([5, 0, 59, 5, 31], dtype=np.intp)
    cols = rng.permutation(60)[:17].astype(np.intp)
    np.testing.assert_array_equal(take_block(P, rows, cols), P[np.ix_(rows, cols)])
    assert take_block(P, rows[:0], cols).shape == (0, 17)


def test_reads_after_a_removal_are_the_dense_covariance_of_the_kept_entries():
    """The rows of the deferred term the state keeps between reads are keyed by state
    index; a removal renumbers the entries, so rows read before it must not serve after."""
    rng = np.random.default_rng(13)
    n = 40
    P = random_spd(rng, n)
    state = state_of(P, max_pending=32)
    cols = np.array([0, 1, 2, 10, 11, 25, 30])
    W = rng.normal(size=(cols.size, 4)) * 0.05
    state.subtract_column_update(cols, W)
    dense = column_update(P, cols, W)
    assert_reads_match(state, dense, np.arange(n))    # every row of the deferred term read
    removed = np.array([5, 6, 20])
    state.remove(removed)
    kept = np.setdiff1d(np.arange(n), removed)
    assert state.pending_rank > 0
    assert_reads_match(state, dense[np.ix_(kept, kept)], np.arange(kept.size))



def test_predictions_and_new_entries_do_not_grow_the_basis():
    """The pose and the entries appended since the last fold are kept exactly (eager): a
    prediction and a new feature that depends on the pose leave the basis as it was, so
    only map columns touched again after a fold join it."""
    rng = np.random.default_rng(21)
    n = 50
    P = random_spd(rng, n)
    state = JointState(rng.normal(size=3), P[:3, :3], capacity=4, max_pending=64, max_eager=64)
    state.append(rng.normal(size=n - 3), P[3:, :3], P[3:, 3:])
    dense, x = P.copy(), state.x.copy()
    cols = np.array([0, 1, 2, 10, 11])
    for _ in range(5):
        delta, Q = rng.normal(size=3) * 0.2, np.diag(rng.uniform(1e-5, 1e-3, 3))
        predict_state(state, delta, Q)
        predict(x, dense, delta, Q)
        W = rng.normal(size=(cols.size, 3)) * 0.05
        state.subtract_column_update(cols, W)
        dense = column_update(dense, cols, W)
    assert state.pending_rank == 5   # the pose's three columns, and entries 10 and 11 once each
    J = rng.normal(size=(4, 3))      # a new feature seen from the pose
    noise = 0.01 * np.eye(4)
    state.append_dependent(np.zeros(4), POSE, J, noise)
    cross = J @ dense[:3]
    dense = np.block([[dense, cross.T], [cross, cross[:, :3] @ J.T + noise]])
    new = np.array([0, 1, 2, n, n + 1])
    W = rng.normal(size=(5, 3)) * 0.05
    state.subtract_column_update(new, W)
    dense = column_update(dense, new, W)
    assert state.pending_rank == 5 and state.eager_count == 3 + 4
    np.testing.assert_allclose(state.x[:n], x, atol=1e-15)
    assert_reads_match(state, dense, np.array([0, 1, 2, 10, 30, n, n + 3]))
    np.testing.assert_allclose(state.P, dense, atol=1e-12)


def test_random_sequences_of_operations_equal_the_dense_covariance():
    """Every operation in random order, with small bases and eager blocks so that folds,
    promotions (an extension of entries partly eager) and the fallbacks for lack of room
    all happen: the reads equal a dense P updated the textbook way."""
    for seed in range(60):
        rng = np.random.default_rng(seed)
        n = 20
        P = random_spd(rng, n)
        state = JointState(rng.normal(size=3), P[:3, :3], capacity=4, max_pending=int(rng.integers(6, 40)),
                           max_eager=int(rng.integers(3, 30)))
        state.append(rng.normal(size=n - 3), P[3:, :3], P[3:, 3:])
        dense, x = P.copy(), state.x.copy()
        for _ in range(40):
            op = rng.choice(["predict", "update", "update", "append", "dependent", "dependent", "transform",
                             "remove", "fold"])
            n = state.size
            if op == "predict":
                delta, Q = rng.normal(size=3) * 0.2, np.diag(rng.uniform(1e-5, 1e-3, 3))
                predict_state(state, delta, Q)
                predict(x, dense, delta, Q)
            elif op == "update":
                picked = rng.choice(np.arange(3, n), size=min(int(rng.integers(1, 8)), n - 3), replace=False)
                cols = np.unique(np.concatenate([POSE, picked]))
                W = rng.normal(size=(cols.size, 3)) * 0.05
                state.subtract_column_update(cols, W)
                dense = column_update(dense, cols, W)
            elif op == "append":
                cross, block = rng.normal(size=(2, n)) * 0.01, 5.0 * np.eye(2)
                state.append(np.zeros(2), cross, block)
                dense = np.block([[dense, cross.T], [cross, block]])
                x = np.concatenate([x, np.zeros(2)])
            elif op == "dependent":
                k = int(rng.integers(1, 6))
                src = np.unique(np.concatenate([POSE[: rng.integers(0, 4)], rng.choice(np.arange(3, n), 2, replace=False)]))
                J, noise = rng.normal(size=(k, src.size)) * 0.5, 0.01 * np.eye(k)
                state.append_dependent(np.zeros(k), src, J, noise)
                cross = J @ dense[src]
                dense = np.block([[dense, cross.T], [cross, cross[:, src] @ J.T + noise]])
                x = np.concatenate([x, np.zeros(k)])
            elif op == "transform":
                idx = rng.choice(np.arange(3, n), min(int(rng.integers(1, 5)), n - 3), replace=False)
                T = np.eye(idx.size) + 0.3 * rng.normal(size=(idx.size, idx.size))
                state.transform(idx, T)
                A = np.eye(n)
                A[np.ix_(idx, idx)] = T
                dense = A @ dense @ A.T
                x[idx] = T @ x[idx]
            elif op == "remove" and n > 10:
                gone = rng.choice(np.arange(3, n), 2, replace=False)
                state.remove(gone)
                kept = np.setdiff1d(np.arange(n), gone)
                dense, x = dense[np.ix_(kept, kept)], x[kept]
            elif op == "fold":
                state.fold()
            np.testing.assert_allclose(state.x, x, atol=1e-12)
            probe = rng.choice(np.arange(state.size), 6, replace=False)
            assert_reads_match(state, dense, np.unique(np.concatenate([POSE, probe])))
        np.testing.assert_allclose(state.P, dense, atol=1e-10)
        np.testing.assert_array_equal(state.P, state.P.T)


def test_a_shear_by_a_pose_entry_is_deferred_exactly():
    """P ← A P Aᵀ, A = I + w e_kᵀ (the invariant EKF's carried covariance) between updates,
    with eager entries present, until the basis overflows (a fold), and on a state of the
    pose alone (no lazy room): every read and the folded P equal the dense covariance."""
    rng = np.random.default_rng(11)
    n = 80
    P = random_spd(rng, n)
    state = state_of(P, max_pending=12)
    dense = P.copy()
    probe = np.array([0, 1, 2, 7, 33, n - 1])
    J = rng.normal(size=(4, 3)) * 0.3       # four eager entries from the pose
    new = state.append_dependent(np.zeros(4), POSE, J, 0.01 * np.eye(4))
    cross = J @ dense[:3]
    dense = np.block([[dense, cross.T], [cross, J @ dense[:3, :3] @ J.T + 0.01 * np.eye(4)]])
    probe = np.concatenate([probe, new])
    folds = 0
    for step in range(12):
        cols = np.array([0, 1, 2, 10 + step, 40 + step])
        W = rng.normal(size=(cols.size, 2)) * 0.05
        before = state.pending_rank
        state.subtract_column_update(cols, W)
        dense = column_update(dense, cols, W)
        w = rng.normal(size=state.size) * 0.1
        k = step % 3
        state.shear(w, k)
        folds += state.pending_rank < before + 1
        A = np.eye(state.size)
        A[:, k] += w
        dense = A @ dense @ A.T
        assert_reads_match(state, dense, probe)
    assert folds >= 1, folds                    # the basis overflowed on the way
    np.testing.assert_allclose(state.P, dense, atol=1e-12)
    np.testing.assert_array_equal(state.P, state.P.T)
    pose_only = JointState(np.zeros(3), random_spd(rng, 3))
    w = rng.normal(size=3)
    A = np.eye(3)
    A[:, 2] += w
    expected = A @ pose_only.P @ A.T
    pose_only.shear(w, 2)
    np.testing.assert_allclose(pose_only.pose_covariance, expected, atol=1e-14)
    np.testing.assert_allclose(pose_only.P, expected, atol=1e-14)
