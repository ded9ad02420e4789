"""Compiled inner loops of the scan segmentation's shape tests (:mod:`bsslam.scan.segment`).

Each scan is segmented once per filter step, and as whole-array numpy the window searches,
run bounds, spacing test, window moments, principal axes and non-maximum suppression were
about a hundred numpy calls of a few microseconds each on a few hundred points. These
loops do the same per-element floating-point operations in the same order as the numpy
forms they replace (kept as oracles in ``tests/scan/segment_oracle.py``), so the cuts are
bit-identical; what numpy computes on whole arrays stays numpy and is passed in: the
transcendentals (``np.hypot`` of the chords, ``np.arctan2``, ``np.cos``, ``np.sin``) and
the mean of the points (a pairwise sum). Running sums (path length, prefix moments) are
sequential, as ``np.cumsum`` adds. A dot product of two 2-vectors is ``a₀b₀ + a₁b₁``, as
``np.einsum("ij,ij->i")`` gives it.
"""

from __future__ import annotations

import numpy as np

from bsslam.compiled import jit
from bsslam.spline.kernels import search_left, search_right


@jit
def _clip_windows(reach, cut, window):
    """Every point's windows clipped to its run between the ``cut`` edges (m-1,) bool:
    ``window[0] = max(reach[0], first point of the run)``, ``window[1] = min(reach[1],
    last point of the run)`` ((2, m) int, written)."""
    m = reach.shape[1]
    first = 0
    for i in range(m):
        if i > 0 and cut[i - 1]:
            first = i
        window[0, i] = max(reach[0, i], first)
    last = m - 1
    for i in range(m - 1, -1, -1):
        if i < m - 1 and cut[i]:
            last = i
        window[1, i] = min(reach[1, i], last)


@jit
def spacing_setup(points, edge_len, cut, window_m):
    """Path length, window reaches and the chords the spacing test compares.

    Args:
        points: (m, 2) points (m), m ≥ 3; edge_len: (m-1,) lengths of their edges (m).
        cut: (m-1,) bool, the gap cuts; window_m: window path length (m).

    Returns:
        path: (m,) path length from point 0 (m), the running sum of ``edge_len``.
        ends: (4, m) int, rows 0–1 ``reach``: the last point at least window_m behind each
            point and the first at least window_m ahead, ignoring cuts (at most i − 1, at
            least i + 1); rows 2–3 ``window``: reach clipped to each point's run between
            the cuts (one array, not two: each array returned costs a Python call).
        chord: (2, 2(m-1)) the x and y of the chords from ``window[0, k]`` to k (columns
            k) and from k + 1 to ``window[1, k+1]`` (columns m − 1 + k), for ``np.hypot``.
    """
    m = points.shape[0]
    path = np.empty(m)
    path[0] = 0.0
    acc = 0.0
    for k in range(m - 1):
        acc = acc + edge_len[k]
        path[k + 1] = acc
    ends = np.empty((4, m), dtype=np.intp)
    reach, window = ends[:2], ends[2:]
    for i in range(m):
        reach[0, i] = min(search_right(path, 0, m, path[i] - window_m) - 1, i - 1)
        reach[1, i] = max(search_left(path, 0, m, path[i] + window_m), i + 1)
    _clip_windows(reach, cut, window)
    chord = np.empty((2, 2 * (m - 1)))
    for k in range(m - 1):
        lo, hi = window[0, k], window[1, k + 1]
        chord[0, k] = points[k, 0] - points[lo, 0]
        chord[1, k] = points[k, 1] - points[lo, 1]
        chord[0, m - 1 + k] = points[hi, 0] - points[k + 1, 0]
        chord[1, m - 1 + k] = points[hi, 1] - points[k + 1, 1]
    return path, ends, chord


@jit
def spacing_cuts(edge_len, steps, window, chord_len, cut, eta, min_jump_m):
    """Add to ``cut`` (m-1,) the edges longer than ``min_jump_m`` whose length per beam step
    exceeds η times that of the window on either side (segment's spacing test).

    Args:
        edge_len: (m-1,) edge lengths (m); steps: (m,) beam number of each point (float).
        window: (2, m) the windows of :func:`spacing_setup`; chord_len: (2(m-1),) the
            lengths of its chords (m).
        cut: (m-1,) bool, updated; eta: η; min_jump_m: the shortest edge cut (m).
    """
    m = steps.shape[0]
    for k in range(m - 1):
        per_beam = edge_len[k] / (steps[k + 1] - steps[k])
        left_lo, right_hi = window[0, k], window[1, k + 1]
        ref = np.inf
        if left_lo < k:
            ref = chord_len[k] / (steps[k] - steps[left_lo])
        if right_hi > k + 1:
            right = chord_len[m - 1 + k] / (steps[right_hi] - steps[k + 1])
            if ref == ref and (right < ref or right != right):   # np.minimum: a NaN wins
                ref = right
        if per_beam > eta * ref and edge_len[k] >= min_jump_m:
            cut[k] = True


@jit
def prefix_moments(points, mean):
    """(m+1, 5) prefix sums of x, y, x², xy, y² of the points (m, 2) centred on ``mean``
    (2,) (their numpy mean): the moments of any window follow from two rows."""
    m = points.shape[0]
    prefix = np.empty((m + 1, 5))
    prefix[0, :] = 0.0
    for i in range(m):
        x = points[i, 0] - mean[0]
        y = points[i, 1] - mean[1]
        prefix[i + 1, 0] = prefix[i, 0] + x
        prefix[i + 1, 1] = prefix[i, 1] + y
        prefix[i + 1, 2] = prefix[i, 2] + x * x
        prefix[i + 1, 3] = prefix[i, 3] + x * y
        prefix[i + 1, 4] = prefix[i, 4] + y * y
    return prefix


@jit
def direction_windows(path, moments, reach, cut, half_window_m, window, tested, angle_args):
    """The points the direction test makes at the current cuts, and the arctan2 arguments of
    the principal axes of their two windows.

    Args:
        path: (m,) path length (m); moments: (m+1, 5) :func:`prefix_moments`;
        reach: (2, m) of :func:`spacing_setup`; cut: (m-1,) bool, the cuts so far;
        half_window_m: how far (m) each window must reach for the point to be tested.
        window: (2, m) int, written: reach clipped to the runs between the cuts.
        tested: (3, m) int, written: columns j < t hold a tested point i, its window's
            first point and its window's last point.
        angle_args: (2, 2m), written: columns j < 2t hold ``2 c_xy`` and ``c_xx − c_yy``
            of the window before tested point j (j < t) or after it (j − t), so the axis
            angle is ``0.5 · arctan2(angle_args[0], angle_args[1])``.

    Returns:
        t, the number of tested points.
    """
    m = path.shape[0]
    _clip_windows(reach, cut, window)
    t = 0
    for i in range(m):
        back, ahead = window[0, i], window[1, i]
        if (back < i and ahead > i and path[i] - path[back] >= half_window_m
                and path[ahead] - path[i] >= half_window_m):
            tested[0, t] = i
            tested[1, t] = back
            tested[2, t] = ahead
            t += 1
    for j in range(2 * t):
        first = tested[1, j] if j < t else tested[0, j - t]
        last = tested[0, j] if j < t else tested[2, j - t]
        n = float(last - first + 1)
        mx = (moments[last + 1, 0] - moments[first, 0]) / n
        my = (moments[last + 1, 1] - moments[first, 1]) / n
        cxx = (moments[last + 1, 2] - moments[first, 2]) / n - mx * mx
        cxy = (moments[last + 1, 3] - moments[first, 3]) / n - mx * my
        cyy = (moments[last + 1, 4] - moments[first, 4]) / n - my * my
        angle_args[0, j] = 2.0 * cxy
        angle_args[1, j] = cxx - cyy
    return t


@jit
def turn_args(points, tested, t, ax, ay):
    """Orient the principal axes along the scan and give the arctan2 arguments of the turn
    between each tested point's two windows.

    Args:
        points: (m, 2) points (m); tested: (3, m) of :func:`direction_windows`, t columns.
        ax, ay: (2t,) cos and sin of the axis angles (before: j < t, after: t + j); flipped
            in place where the axis points against the scan.

    Returns:
        (2, t): the cross and the dot product of the before and after axes.
    """
    for j in range(2 * t):
        if j < t:
            a, b = tested[1, j], tested[0, j]
        else:
            a, b = tested[0, j - t], tested[2, j - t]
        along = ax[j] * (points[b, 0] - points[a, 0]) + ay[j] * (points[b, 1] - points[a, 1])
        sign = -1.0 if along < 0 else 1.0
        ax[j] = ax[j] * sign
        ay[j] = ay[j] * sign
    out = np.empty((2, t))
    for j in range(t):
        out[0, j] = ax[j] * ay[t + j] - ay[j] * ax[t + j]
        out[1, j] = ax[j] * ax[t + j] + ay[j] * ay[t + j]
    return out


@jit
def direction_breaks(moments, tested, t, ax, ay, turn, alpha_max_rad, cut):
    """Cut where the direction turns by more than α_max and by the most within the point's
    own windows (non-maximum suppression); the break point stays with the side whose line
    (that side's axis through the centroid of its other points) it lies closer to.

    Args:
        moments: (m+1, 5) :func:`prefix_moments`; tested, t: of :func:`direction_windows`;
        ax, ay: (2t,) the oriented axes of :func:`turn_args`; turn: (t,) the signed turns
            (rad); alpha_max_rad: α_max; cut: (m-1,) bool, updated.

    Returns:
        The number of breaks found (0: the search is over).
    """
    m = moments.shape[0] - 1
    full = np.zeros(m)
    size = np.empty(t)
    for j in range(t):
        size[j] = abs(turn[j])
        full[tested[0, j]] = size[j]
    breaks = 0
    for j in range(t):
        if not size[j] > alpha_max_rad:
            continue
        lo, i, hi = tested[1, j], tested[0, j], tested[2, j]
        top = full[lo]
        for k in range(lo + 1, hi + 1):   # np.maximum: a NaN wins
            if full[k] > top or full[k] != full[k]:
                top = full[k]
        if not size[j] >= top:
            continue
        own_x = moments[i + 1, 0] - moments[i, 0]
        own_y = moments[i + 1, 1] - moments[i, 1]
        before_x = (moments[i, 0] - moments[lo, 0]) / float(i - lo)
        before_y = (moments[i, 1] - moments[lo, 1]) / float(i - lo)
        after_x = (moments[hi + 1, 0] - moments[i + 1, 0]) / float(hi - i)
        after_y = (moments[hi + 1, 1] - moments[i + 1, 1]) / float(hi - i)
        off_before = abs(ax[j] * (own_y - before_y) - ay[j] * (own_x - before_x))
        off_after = abs(ax[t + j] * (own_y - after_y) - ay[t + j] * (own_x - after_x))
        cut[i if off_before <= off_after else i - 1] = True
        breaks += 1
    return breaks


@jit
def kept_runs(cut, gap_cut, path, min_points, min_length_m):
    """The runs between the cuts with at least ``min_points`` points and ``min_length_m``
    of path.

    Args:
        cut: (m-1,) bool, all cuts; gap_cut: (m-1,) bool, the gap cuts among them (each
            also in ``cut``); path: (m,) path length (m).

    Returns:
        bounds: (2, k) int, first and last point of each kept run; gap_cuts: the gap cuts
        (counted here rather than by np.count_nonzero, three Python calls a scan);
        shape_cuts: cuts that are not gap cuts; rejected: runs dropped.
    """
    m = path.shape[0]
    bounds = np.empty((2, m), dtype=np.intp)
    k = 0
    rejected = 0
    gap_cuts = 0
    shape_cuts = 0
    start = 0
    for e in range(m):
        if e < m - 1 and not cut[e]:
            continue
        if e < m - 1:
            if gap_cut[e]:
                gap_cuts += 1
            else:
                shape_cuts += 1
        if e - start + 1 >= min_points and path[e] - path[start] >= min_length_m:
            bounds[0, k] = start
            bounds[1, k] = e
            k += 1
        else:
            rejected += 1
        start = e + 1
    return bounds[:, :k], gap_cuts, shape_cuts, rejected


@jit
def beam_validity(ranges, no_return_m, min_range_m):
    """Each beam's first reason to be invalid (segment's ``valid_beams``).

    Args:
        ranges: (n,) ranges (m); no_return_m: ranges at or above it are no return;
        min_range_m: ranges at or below it are too close.

    Returns:
        valid: (n,) bool; then the numbers of valid, non-finite, no-return and too-close
        beams.
    """
    n = ranges.shape[0]
    valid = np.zeros(n, dtype=np.bool_)
    n_valid = n_nonfinite = n_no_return = n_too_close = 0
    for k in range(n):
        r = ranges[k]
        if not np.isfinite(r):
            n_nonfinite += 1
        elif r >= no_return_m:
            n_no_return += 1
        elif r <= min_range_m:
            n_too_close += 1
        else:
            valid[k] = True
            n_valid += 1
    return valid, n_valid, n_nonfinite, n_no_return, n_too_close
