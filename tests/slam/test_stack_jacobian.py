"""The compiled assembly of a scan's stacked Jacobian against the plain numpy assembly it
replaced (its columns: the pose, then every state index the kept beams touch, sorted)."""

import numpy as np

from bsslam.slam.kernels import stack_jacobian


def _numpy_stack(rows, window, real, state_rows, H_cp_x, H_cp_y, H_pose):
    state = state_rows[window[rows]]                                      # (m, p+1, 2)
    cp_cols = np.where(real[rows][:, :, None], state, -1).transpose(0, 2, 1).reshape(rows.size, -1)
    cp_vals = np.hstack([H_cp_x[rows], H_cp_y[rows]])
    used = cp_cols >= 0
    cols = np.concatenate([np.arange(3), np.unique(cp_cols[used])])
    H_c = np.zeros((rows.size, cols.shape[0]))
    H_c[:, :3] = H_pose[rows]
    r_idx, _ = np.nonzero(used)
    H_c[r_idx, np.searchsorted(cols[3:], cp_cols[used]) + 3] = cp_vals[used]
    return cols, H_c


def test_stack_jacobian_equals_the_numpy_assembly():
    rng = np.random.default_rng(3)
    n_cp, n_state, k, p = 30, 80, 25, 3
    # control points in the state at scattered indices; some fixed (−1), as in localisation
    state_rows = rng.permutation(np.arange(3, n_state))[: 2 * n_cp].reshape(n_cp, 2)
    state_rows[rng.random(n_cp) < 0.2] = -1
    first = rng.integers(0, n_cp - p, k)
    window = first[:, None] + np.arange(p + 1)
    real = np.ones((k, p + 1), dtype=bool)
    real[:5, 2:] = False                     # padding of lower-degree splines
    window[:5, 2:] = window[:5, 1:2]
    H_cp_x, H_cp_y, H_pose = rng.normal(size=(k, p + 1)), rng.normal(size=(k, p + 1)), rng.normal(size=(k, 3))
    for rows in (np.arange(k), np.sort(rng.choice(k, 9, replace=False)), np.array([4])):
        cols, H_c = stack_jacobian(rows, window, real, state_rows, H_cp_x, H_cp_y, H_pose, n_state)
        ref_cols, ref_H = _numpy_stack(rows, window, real, state_rows, H_cp_x, H_cp_y, H_pose)
        np.testing.assert_array_equal(cols, ref_cols)
        np.testing.assert_array_equal(H_c, ref_H)
