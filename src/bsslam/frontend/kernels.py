"""Compiled inner loops of the laser-odometry front end (:mod:`bsslam.frontend.scan_matcher`).

Each scan match reads the likelihood fields at ~0.7 million (pose, offset, point) triples
and runs ~7 nearest-neighbour searches of a few hundred points; as whole-array numpy these
were gathers into large temporaries and a KD-tree query per Gauss–Newton step. Compiled,
each loops once over its points and reads the field or the point grid in place.

Where a kernel replaces a numpy form it does the same floating-point operations in the same
order (no fused multiply-add, no reassociation: numba's default, strict IEEE), so the
results are bit-identical to it, and the grid search finds the points cKDTree found. The
one exception is stated where it occurs (:func:`window_scores` sums exactly instead of in
BLAS's float32 order). The front-end trajectories on the four real logs are bit-identical
to those of the numpy forms.
"""

from __future__ import annotations

import math

import numpy as np

from bsslam.compiled import jit


@jit
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
    # Each point's window corner (flat cell), unsigned: it is ≥ 0 (pad ≥ reach·step), and an
    # unsigned index spares numba's negative-index wraparound on every read (~1.7x faster).
    first = np.empty(n, dtype=np.uint64)
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
            first[i] = np.uint64((ix - reach * step) * ny + iy - reach * step)
        # Offset-major: one sum over the points per offset, in four partial sums (exact, so
        # the split does not change it; four independent additions keep the adder busy).
        # The offsets of one window row read the same cache lines, still in L1.
        for a in range(width):
            for b in range(width):
                off = np.uint64((a * ny + b) * step)
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


@jit
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


# -- nearest line point ---------------------------------------------------------------------
#
# The refinement asks, ~7 times per scan, for the nearest line-like reference point of each of
# a few hundred moved scan points within a gate of a few decimetres. A uniform grid of cells
# about the gate's size, its points stored cell by cell, answers that by scanning the few
# cells the gate's square touches; it replaces a KD-tree query (and rebuilds faster).


@jit
def grid_index(points, cell, max_cells):
    """Bucket ``points`` (m, 2) (m, m ≥ 1) into square cells of side ``cell`` (m) over their
    bounding box, the side doubled until there are at most ``max_cells`` cells.

    Returns:
        lo_x, lo_y: corner (m) of cell (0, 0); cell: the side used (m); nx, ny: cells;
        start: (nx·ny + 1,) the points of flat cell k = cx·ny + cy are ``order[start[k]:
        start[k+1]]``; order: (m,) point indices, cell by cell, increasing within a cell.
    """
    m = points.shape[0]
    lo_x, lo_y = points[0, 0], points[0, 1]
    hi_x, hi_y = lo_x, lo_y
    for i in range(1, m):
        lo_x, hi_x = min(lo_x, points[i, 0]), max(hi_x, points[i, 0])
        lo_y, hi_y = min(lo_y, points[i, 1]), max(hi_y, points[i, 1])
    while True:
        nx = int(math.floor((hi_x - lo_x) / cell)) + 1
        ny = int(math.floor((hi_y - lo_y) / cell)) + 1
        if nx * ny <= max_cells:
            break
        cell *= 2.0
    key = np.empty(m, dtype=np.intp)
    start = np.zeros(nx * ny + 1, dtype=np.intp)
    for i in range(m):
        cx = min(int(math.floor((points[i, 0] - lo_x) / cell)), nx - 1)
        cy = min(int(math.floor((points[i, 1] - lo_y) / cell)), ny - 1)
        key[i] = cx * ny + cy
        start[key[i] + 1] += 1
    for k in range(nx * ny):
        start[k + 1] += start[k]
    fill = start[:-1].copy()
    order = np.empty(m, dtype=np.intp)
    for i in range(m):                       # counting sort: stable
        order[fill[key[i]]] = i
        fill[key[i]] += 1
    return lo_x, lo_y, cell, nx, ny, start, order


@jit
def _nearest(xy, start, lo_x, lo_y, cell, nx, ny, qx, qy, gate):
    """Row of ``xy`` (k, ≥ 2) (the grid's points in its columns 0, 1 (m), cell by cell) nearest
    to (qx, qy) at a distance
    below ``gate`` (m), or −1. The squared distance is ``dx² + dy²`` compared with
    ``gate²`` (strictly), as scipy's cKDTree compares them for ``distance_upper_bound``;
    of equally near points the first in the grid's order is taken."""
    best = gate * gate
    found = -1
    # The cells of the gate's square around q, a millionth of a cell wider for rounding.
    fx0, fx1 = (qx - gate - lo_x) / cell - 1e-6, (qx + gate - lo_x) / cell + 1e-6
    fy0, fy1 = (qy - gate - lo_y) / cell - 1e-6, (qy + gate - lo_y) / cell + 1e-6
    if fx1 < 0.0 or fy1 < 0.0 or fx0 >= nx or fy0 >= ny:
        return found
    cx0, cx1 = max(int(math.floor(fx0)), 0), min(int(math.floor(fx1)), nx - 1)
    cy0, cy1 = max(int(math.floor(fy0)), 0), min(int(math.floor(fy1)), ny - 1)
    for cx in range(cx0, cx1 + 1):
        for j in range(start[cx * ny + cy0], start[cx * ny + cy1 + 1]):   # cells cy0 … cy1
            dx = xy[j, 0] - qx
            dy = xy[j, 1] - qy
            d2 = dx * dx + dy * dy
            if d2 < best:
                best = d2
                found = j
    return found


@jit
def point_to_line(rotated, x0, x1, gate, qn, start, lo_x, lo_y, cell, nx, ny, huber):
    """Point-to-line residuals and Jacobian of :meth:`ReferenceMap._linearise`.

    Args:
        rotated: (n, 2) the scan points rotated by the pose (m) (``R p``, from numpy);
            x0, x1: the pose's translation (m).
        gate: correspondence gate (m).
        qn: (k, 4) line points (m) and their unit normals, cell by cell as in the grid
            ``start, lo_x, lo_y, cell, nx, ny`` (:func:`grid_index` of the points).
        huber: Huber threshold (m).

    Returns:
        Jr (m, 4): rows (n_x, n_y, n_y·(Rp)_x − n_x·(Rp)_y, r) of the points with a line point
        within the gate, r = nᵀ(R p + t − q) (m) to the nearest one q; w (m,) Huber weights
        huber / max(|r|, huber); found (n,) which points have one.

    The operations are numpy's in :meth:`_linearise` before it, in the same order.
    """
    n = rotated.shape[0]
    Jr = np.empty((n, 4))
    w = np.empty(n)
    found = np.zeros(n, dtype=np.bool_)
    m = 0
    for i in range(n):
        rx, ry = rotated[i, 0], rotated[i, 1]
        mx, my = rx + x0, ry + x1
        j = _nearest(qn, start, lo_x, lo_y, cell, nx, ny, mx, my, gate)
        if j < 0:
            continue
        found[i] = True
        nx_, ny_ = qn[j, 2], qn[j, 3]
        Jr[m, 0] = nx_
        Jr[m, 1] = ny_
        Jr[m, 2] = ny_ * rx - nx_ * ry
        r = nx_ * (mx - qn[j, 0]) + ny_ * (my - qn[j, 1])
        Jr[m, 3] = r
        w[m] = huber / max(abs(r), huber)
        m += 1
    return Jr[:m].copy(), w[:m].copy(), found


# -- thinning ---------------------------------------------------------------------------------


@jit
def first_per_cell(points, cell_m):
    """Indices (increasing) of the first point of ``points`` (m, 2) in each occupied square
    cell of side ``cell_m`` (m): the body of :func:`~bsslam.frontend.scan_matcher.voxel_thin`.

    A point's cell is ``floor(p / cell_m)`` per axis, keyed as numpy's form keyed it (cells
    from the lowest one, ``cx·(span_y + 1) + cy``); the first point of a key is found with a
    hash table of the keys seen (open addressing, twice the points' slots), one pass in
    point order instead of a sort of the keys."""
    m = points.shape[0]
    if m == 0:
        return np.empty(0, dtype=np.intp)
    cx = np.empty(m, dtype=np.int64)
    cy = np.empty(m, dtype=np.int64)
    for i in range(m):
        cx[i] = np.int64(math.floor(points[i, 0] / cell_m))
        cy[i] = np.int64(math.floor(points[i, 1] / cell_m))
    min_x, min_y, max_y = cx.min(), cy.min(), cy.max()
    width = max_y - min_y + 1
    bits = 4
    while (1 << bits) < 2 * m:
        bits += 1
    size = 1 << bits
    shift, mask = np.uint64(64 - bits), np.uint64(size - 1)
    table = np.full(size, -1, dtype=np.int64)
    keep = np.empty(m, dtype=np.intp)
    k = 0
    for i in range(m):
        key = (cx[i] - min_x) * width + (cy[i] - min_y)
        # Fibonacci hashing: the high bits of key × 2⁶⁴/φ spread neighbouring cells
        slot = (np.uint64(key) * np.uint64(11400714819323198485)) >> shift
        while True:
            held = table[slot]
            if held == -1:
                table[slot] = key
                keep[k] = i
                k += 1
                break
            if held == key:
                break
            slot = (slot + np.uint64(1)) & mask
    return keep[:k].copy()
