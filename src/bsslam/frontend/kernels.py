"""Compiled inner loops of the laser-odometry front end (:mod:`bsslam.frontend.scan_matcher`).

Each scan match scores a few ten thousand poses × points on the likelihood fields and runs
a handful of nearest-neighbour searches of a few hundred points; as whole-array numpy these
were gathers into large temporaries and a KD-tree query per Gauss–Newton step. Compiled,
each loops once over its points and reads the field or the point grid in place.

Where a kernel replaces a numpy form it does the same floating-point operations in the same
order (no fused multiply-add, no reassociation: numba's default, strict IEEE), so the
results are bit-identical to it; the one exception is stated where it occurs
(:func:`window_scores` sums exactly instead of in BLAS's float32 order).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

# cache=True: compiled once per machine into __pycache__, not at every start (~1 s each).
_jit = njit(cache=True, nogil=True)


@_jit
def window_scores(values, nx, ny, origin_x, origin_y, resolution, pad, points, cos, sin, tx, ty, reach, step):
    """Mean field value of ``points`` under every pose and every whole-cell offset of a
    square window: the body of :meth:`LikelihoodField.score_grid`.

    Args:
        values: (nx·ny,) float32 field, row = x cell, column = y cell.
        origin_x, origin_y: world position (m) of the corner of cell (0, 0); ``resolution``
            the cell size (m); ``pad`` the clipping margin (cells), at least reach·step.
        points: (n, 2) robot-frame points (m).
        cos, sin, tx, ty: (p,) each pose's cos φ, sin φ (from numpy, so the moved points are
            numpy's to the bit) and translation (m).
        reach, step: offsets a·step, b·step (cells) for a, b in −reach … reach.

    Returns:
        (p, t) float32, t = (2·reach + 1)², x offset major: the mean over the points of the
        field at the point's clipped cell plus the offset.

    The point's cell is computed as numpy computed it (``c·x − s·y + tx``, then
    ``floor((w − origin)/resolution)``, clipped ``pad`` inside). The sum over the points is
    accumulated in float64, where it is *exact*: a field value is 0 or a float32 of at least
    exp(−4.5) > 2⁻⁷ (the kernel is cut at 3σ), so a multiple of 2⁻³⁰, and a sum of fewer
    than 2²³ such values ≤ 1 needs fewer than 53 bits. It is rounded once to float32 and
    divided by n in float32. The numpy form summed in float32 in BLAS's order, rounding at
    each step, so a score may differ from it in the last float32 bits (the front-end
    trajectories on the four logs did not change).
    """
    n_pose, n = cos.shape[0], points.shape[0]
    width = 2 * reach + 1
    out = np.empty((n_pose, width * width), dtype=np.float32)
    first = np.empty(n, dtype=np.intp)        # each point's window corner (flat cell)
    x_hi, y_hi = nx - 1 - pad, ny - 1 - pad
    n32 = np.float32(n)
    for p in range(n_pose):
        c, s, px, py = cos[p], sin[p], tx[p], ty[p]
        for i in range(n):
            x, y = points[i, 0], points[i, 1]
            wx = c * x - s * y + px
            wy = s * x + c * y + py
            ix = min(max(int(math.floor((wx - origin_x) / resolution)), pad), x_hi)
            iy = min(max(int(math.floor((wy - origin_y) / resolution)), pad), y_hi)
            first[i] = (ix - reach * step) * ny + iy - reach * step
        # Offset-major: one sum over the points per offset, in four partial sums (exact, so
        # the split does not change it; four independent additions keep the adder busy).
        # The offsets of one window row read the same cache lines, still in L1.
        for a in range(width):
            for b in range(width):
                off = (a * ny + b) * step
                s0, s1, s2, s3 = 0.0, 0.0, 0.0, 0.0
                i = 0
                while i + 4 <= n:
                    s0 += values[first[i] + off]
                    s1 += values[first[i + 1] + off]
                    s2 += values[first[i + 2] + off]
                    s3 += values[first[i + 3] + off]
                    i += 4
                while i < n:
                    s0 += values[first[i] + off]
                    i += 1
                out[p, a * width + b] = np.float32((s0 + s1) + (s2 + s3)) / n32
    return out


@_jit
def splat_max(values, cells, kernel_offset, kernel_value):
    """``values[cell + kernel_offset[k]] = max(…, kernel_value[k])`` for every cell of
    ``cells`` (q,) and kernel entry k, in place on the float32 field ``values``: what
    ``np.maximum.at`` did, without its per-element dispatch. A maximum is exact, so the
    order does not matter."""
    for i in range(cells.shape[0]):
        base = cells[i]
        for k in range(kernel_offset.shape[0]):
            j = base + kernel_offset[k]
            v = kernel_value[k]
            if values[j] < v:
                values[j] = v
