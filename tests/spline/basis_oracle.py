"""The whole-array numpy form of Piegl & Tiller A2.3 (basis functions and derivatives),
vectorised over the parameters: the oracle of the compiled
:func:`bsslam.spline.kernels.basis_derivatives`, which must match it bit for bit."""

import numpy as np


def _basis_triangle(knots: np.ndarray, degree: int, t: np.ndarray, span: np.ndarray) -> np.ndarray:
    """The table ``ndu`` of Piegl & Tiller A2.3, shape (degree+1, degree+1, m).

    Upper triangle ``ndu[r, j]``: the non-zero degree-j basis functions on the span;
    lower triangle ``ndu[j, r]`` (j > r): the knot differences used as denominators.
    The differences are > 0 for any non-empty span, so no 0/0 occurs.
    """
    m = t.shape[0]
    ndu = np.empty((degree + 1, degree + 1, m))
    left = np.empty((degree + 1, m))
    right = np.empty((degree + 1, m))
    ndu[0, 0] = 1.0
    for j in range(1, degree + 1):
        left[j] = t - knots[span + 1 - j]
        right[j] = knots[span + j] - t
        saved = np.zeros(m)
        for r in range(j):
            ndu[j, r] = right[r + 1] + left[j - r]
            temp = ndu[r, j - 1] / ndu[j, r]
            ndu[r, j] = saved + right[r + 1] * temp
            saved = left[j - r] * temp
        ndu[j, j] = saved
    return ndu



def _derivatives_from_triangle(ndu: np.ndarray, degree: int, nder: int) -> np.ndarray:
    """Derivatives 0 … nder of the non-zero basis functions, shape (nder+1, degree+1, m).

    Piegl & Tiller A2.3, second part; every branch depends only on (r, k, degree), so the
    whole algorithm vectorises over the parameters.
    """
    p = degree
    m = ndu.shape[2]
    ders = np.zeros((nder + 1, p + 1, m))
    ders[0] = ndu[:, p]
    top = min(nder, p)  # derivatives of order > degree vanish
    for r in range(p + 1):
        a_prev = np.zeros((p + 1, m))
        a_next = np.zeros((p + 1, m))
        a_prev[0] = 1.0
        for k in range(1, top + 1):
            d = np.zeros(m)
            rk, pk = r - k, p - k
            if r >= k:
                a_next[0] = a_prev[0] / ndu[pk + 1, rk]
                d = a_next[0] * ndu[rk, pk]
            j1 = 1 if rk >= -1 else -rk
            j2 = k - 1 if r - 1 <= pk else p - r
            for j in range(j1, j2 + 1):
                a_next[j] = (a_prev[j] - a_prev[j - 1]) / ndu[pk + 1, rk + j]
                d = d + a_next[j] * ndu[rk + j, pk]
            if r <= pk:
                a_next[k] = -a_prev[k - 1] / ndu[pk + 1, r]
                d = d + a_next[k] * ndu[r, pk]
            ders[k, r] = d
            a_prev, a_next = a_next, a_prev
    factor = float(p)
    for k in range(1, top + 1):
        ders[k] *= factor
        factor *= p - k
    return ders
