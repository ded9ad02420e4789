"""Compiled constraints of the estimators' Jacobians: a stacked Jacobian projected off the
unobservable directions (the OC-EKF's and the invariant EKF's), the invariant EKF's
directions N(x) on a set of state indices, and its whole constraint of a linearisation
(:meth:`bsslam.slam.invariant_ekf.InvariantEKF.constrain`).

The filter constrains four linearisations a scan (the beams' and the bends', at the prior
and at the first corrected estimate), each of ~90 × 30 entries. As whole-array numpy that
was about fifteen calls of a few microseconds each; these loops cost one call. The numpy
forms they replaced are the tests' oracles (``tests/slam/constraint_oracle.py``).
"""

from __future__ import annotations

import numpy as np

from bsslam.compiled import jit

#: The heading's state index.
HEADING = 2


@jit
def project_off(H, N):
    """H ← H − H N (Nᵀ N)⁻¹ Nᵀ in place, for H (m, c) and N (c, 3): each row of H projected
    onto the orthogonal complement of N's columns. False (H untouched) when NᵀN is not
    positive definite (N's columns dependent on these indices)."""
    m, c = H.shape
    G = np.zeros((3, 3))
    for j in range(c):
        for a in range(3):
            for b in range(3):
                G[a, b] += N[j, a] * N[j, b]
    L = np.zeros((3, 3))            # G = L Lᵀ
    for a in range(3):
        s = G[a, a]
        for k in range(a):
            s -= L[a, k] * L[a, k]
        if not s > 0.0:
            return False
        L[a, a] = np.sqrt(s)
        for b in range(a + 1, 3):
            t = G[b, a]
            for k in range(a):
                t -= L[b, k] * L[a, k]
            L[b, a] = t / L[a, a]
    y = np.empty(3)
    for i in range(m):
        for a in range(3):
            s = 0.0
            for j in range(c):
                s += H[i, j] * N[j, a]
            y[a] = s
        for a in range(3):          # G y = Nᵀ hᵢ: L z = Nᵀ hᵢ, then Lᵀ y = z
            s = y[a]
            for k in range(a):
                s -= L[a, k] * y[k]
            y[a] = s / L[a, a]
        for a in range(2, -1, -1):
            s = y[a]
            for k in range(a + 1, 3):
                s -= L[k, a] * y[k]
            y[a] = s / L[a, a]
        for j in range(c):
            H[i, j] -= N[j, 0] * y[0] + N[j, 1] * y[1] + N[j, 2] * y[2]
    return True


@jit
def invariant_null_space(cols, x, sign, mate):
    """(c, 3) N(x) on state indices ``cols``: global x and y translation (1 on each x, resp.
    y, entry) and the rotation about the origin (1 on the heading, J x on each position:
    −y on an x entry, x on a y entry). ``sign`` (n,) is −1 on x entries, +1 on y entries, 0
    on the heading; ``mate`` (n,) the other coordinate of each position entry."""
    c = cols.shape[0]
    N = np.zeros((c, 3))
    for j in range(c):
        k = cols[j]
        s = sign[k]
        if s < 0:
            N[j, 0] = 1.0
        elif s > 0:
            N[j, 1] = 1.0
        N[j, 2] = 1.0 if k == HEADING else s * x[mate[k]]
    return N


@jit
def invariant_jacobian(cols, H, x, x_hat, sign, mate):
    """The invariant EKF's Jacobian of H (m, c) on ``cols`` linearised at x:
    ``(cols' (c'), H' (m, c'), ok)``. With the heading among ``cols``, H projected off N(x)
    (ok False, H' unprojected, when that fails); without it (a bend's rows), the heading's
    column appended, zero. Then H' A(x̂ → x): the heading's column gains H' J (x − x̂)."""
    m, c = H.shape
    at = -1
    for j in range(c):
        if cols[j] == HEADING:
            at = j
            break
    ok = True
    if at < 0:
        out_cols = np.empty(c + 1, dtype=cols.dtype)
        out_cols[:c] = cols
        out_cols[c] = HEADING
        out = np.zeros((m, c + 1))
        out[:, :c] = H
        at = c
    else:
        out_cols = cols.copy()
        out = H.copy()
        ok = project_off(out, invariant_null_space(cols, x, sign, mate))
    w = out_cols.shape[0]
    turn = np.empty(w)              # J (x − x̂) on the columns
    for j in range(w):
        k = out_cols[j]
        turn[j] = sign[k] * (x[mate[k]] - x_hat[mate[k]])
    for i in range(m):
        s = 0.0
        for j in range(w):
            s += out[i, j] * turn[j]
        out[i, at] += s
    return out_cols, out, ok
