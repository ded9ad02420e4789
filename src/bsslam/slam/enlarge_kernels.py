"""Compiled assembly of the map-enlargement blocks (:mod:`bsslam.slam.enlarge`).

A new or extended spline's block is a few matrix products (BLAS, kept numpy) and a
dozen numpy calls that only stack, scale and scatter their results into the arrays the
state takes. These loops do that in one call each, with the operations of the numpy
forms in the same order (strict IEEE: see :mod:`bsslam.compiled`), so the blocks are bit
for bit theirs; the tests check them against those forms, kept as oracles in
``tests/slam/enlarge_oracle.py``. Cosines and sines stay numpy.
"""

from __future__ import annotations

import numpy as np

from bsslam.compiled import jit


@jit
def beam_arrays(lx, ly, cm, sm, ranges, a, b):
    """The arrays of a :class:`~bsslam.slam.enlarge.BeamPoints`.

    Args:
        lx, ly: the laser's world position (m); cm, sm: (k,) cos, sin of each beam's world
            bearing; ranges: (k,) ranges (m); a, b: the heading derivative's pose terms
            (−s·ox − c·oy and c·ox − s·oy, m).

    Returns:
        points (k, 2), d_dpose (2, k, 3), d_drange (2, k).
    """
    k = ranges.shape[0]
    points = np.empty((k, 2))
    d_dpose = np.zeros((2, k, 3))
    d_drange = np.empty((2, k))
    for j in range(k):
        points[j, 0] = lx + ranges[j] * cm[j]
        points[j, 1] = ly + ranges[j] * sm[j]
        d_dpose[0, j, 0] = 1.0
        d_dpose[1, j, 1] = 1.0
        d_dpose[0, j, 2] = a - ranges[j] * sm[j]
        d_dpose[1, j, 2] = b + ranges[j] * cm[j]
        d_drange[0, j] = cm[j]
        d_drange[1, j] = sm[j]
    return points, d_dpose, d_drange


@jit
def stacked_arrays(ax, ay, jx, jy, A, d_drange):
    """``stacked_map``'s stacking: ([ax; ay] (2q,), [jx; jy] (2q, 3), the (2q, k) range
    Jacobian [A · diag(d_drange[0]); A · diag(d_drange[1])]) from the products
    ax = A·D_x, ay = A·D_y (q,) and jx, jy (q, 3) and A (q, k)."""
    q, k = A.shape
    mean = np.empty(2 * q)
    J_pose = np.empty((2 * q, 3))
    G_z = np.empty((2 * q, k))
    for i in range(q):
        mean[i] = ax[i]
        mean[q + i] = ay[i]
        for c in range(3):
            J_pose[i, c] = jx[i, c]
            J_pose[q + i, c] = jy[i, c]
        for j in range(k):
            G_z[i, j] = A[i, j] * d_drange[0, j]
            G_z[q + i, j] = A[i, j] * d_drange[1, j]
    return mean, J_pose, G_z


@jit
def extension_arrays(data_mean, J_pose, old_x, old_y, psi_o, idx_x, idx_y):
    """``extension_block``'s assembly: the mean data_mean + [old_x; old_y] (2m,), the
    Jacobian (2m, 3 + 2 n_old) [J_pose, Ψ_o ⊕ Ψ_o] and its state columns
    [0, 1, 2, idx_x, idx_y], from data_mean (2m,), J_pose (2m, 3), the old control
    points' share old_x = Ψ_o·x_old, old_y (m,), Ψ_o (m, n_old)."""
    m, n_old = psi_o.shape
    mean = np.empty(2 * m)
    J = np.zeros((2 * m, 3 + 2 * n_old))
    for i in range(m):
        mean[i] = data_mean[i] + old_x[i]
        mean[m + i] = data_mean[m + i] + old_y[i]
    for i in range(2 * m):
        for c in range(3):
            J[i, c] = J_pose[i, c]
    for i in range(m):
        for c in range(n_old):
            J[i, 3 + c] = psi_o[i, c]
            J[m + i, 3 + n_old + c] = psi_o[i, c]
    cols = np.empty(3 + 2 * n_old, dtype=np.int64)
    for c in range(3):
        cols[c] = c
    for c in range(n_old):
        cols[3 + c] = idx_x[c]
        cols[3 + n_old + c] = idx_y[c]
    return mean, J, cols
