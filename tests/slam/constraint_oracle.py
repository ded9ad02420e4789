"""The numpy forms of :mod:`bsslam.slam.constraint_kernels`, kept as the tests' oracles: the
projection off the unobservable directions (solved with LAPACK's posv), the invariant EKF's
N(x) on a set of state indices and its constraint of a linearisation."""

import numpy as np
from scipy.linalg.lapack import dposv

HEADING = 2


def project_out(H_c, N_c):
    """(m, c) H − H N (Nᵀ N)⁻¹ Nᵀ; None when NᵀN is not positive definite."""
    _, coeffs, info = dposv(N_c.T @ N_c, (H_c @ N_c).T)
    if info != 0:
        return None
    return H_c - coeffs.T @ N_c.T


def turn(v, sign, mate, rows):
    """J v on ``rows``: (−v_y, v_x) on each position entry, 0 on the heading."""
    return sign[rows] * v[mate[rows]]


def null_space(x, cols, sign, mate):
    """(c, 3) global x, y translation and the rotation about the origin on ``cols``."""
    N = np.zeros((cols.shape[0], 3))
    N[sign[cols] < 0, 0] = 1.0
    N[sign[cols] > 0, 1] = 1.0
    N[:, 2] = np.where(cols == HEADING, 1.0, turn(x, sign, mate, cols))
    return N


def invariant_constrain(cols, H, x, x_hat, sign, mate):
    """(cols', H'): H projected off N(x) when it has the heading's column (else that column
    appended, zero), then its heading column plus H' J (x − x̂)."""
    H = np.array(H, dtype=float)
    at = np.flatnonzero(cols == HEADING)
    if at.size:
        H = project_out(H, null_space(x, cols, sign, mate))
    else:
        cols = np.concatenate([cols, [HEADING]])
        H = np.concatenate([H, np.zeros((H.shape[0], 1))], axis=1)
        at = np.array([cols.shape[0] - 1])
    H[:, at[0]] += H @ turn(x - x_hat, sign, mate, cols)
    return cols, H
