"""The numpy form of the scan segmentation's shape tests (bsslam.scan.segment) as it was
before its loops were compiled (bsslam.scan.segment_kernels): the oracle the compiled
segmentation must match bit for bit (cuts, counts and runs)."""

from __future__ import annotations

import numpy as np

from bsslam.config import SegmentationConfig
from bsslam.errors import InputError
from bsslam.scan.segment import DEFAULT_WINDOW_M


def numpy_segment_bounds_counted(points: np.ndarray, config: SegmentationConfig, *,
                           beam_index: np.ndarray | None = None,
                           window_m: float = DEFAULT_WINDOW_M) -> tuple[np.ndarray, np.ndarray, dict[str, int]]:
    """:func:`segment_points_counted` with each segment as its first and last row: (k,),
    (k,) int arrays (segment j is ``points[starts[j] : ends[j] + 1]``), and the counts."""
    points = np.asarray(points, dtype=float)
    if points.ndim != 2 or points.shape[1] != 2:
        raise InputError(f"points must be (m, 2), got {points.shape}")
    if not (window_m >= 0):
        raise InputError(f"window_m must be ≥ 0, got {window_m!r}")
    m = points.shape[0]
    counts = {"gap_cuts": 0, "shape_cuts": 0, "segments": 0, "rejected_segments": 0}
    if m == 0:
        return np.zeros(0, dtype=np.intp), np.zeros(0, dtype=np.intp), counts
    if beam_index is None:
        steps = np.arange(m, dtype=float)
    else:
        steps = np.asarray(beam_index, dtype=float)
        if steps.shape != (m,) or np.any(steps[1:] <= steps[:-1]):
            raise InputError(f"beam_index must be (m,) = ({m},) and strictly increasing")

    edges = points[1:] - points[:-1]                     # (m-1, 2): edge k joins points k, k+1
    edge_len = np.hypot(edges[:, 0], edges[:, 1])         # (m-1,)
    path = np.zeros(m)                                    # (m,) path length from point 0 (m)
    np.cumsum(edge_len, out=path[1:])

    gap_cut = edge_len > config.max_gap_m                 # (m-1,)
    shape_cut = _shape_cuts(points, edge_len, path, steps, gap_cut, config, window_m)
    cut = gap_cut | shape_cut
    counts["gap_cuts"] = int(np.count_nonzero(gap_cut))
    counts["shape_cuts"] = int(np.count_nonzero(shape_cut & ~gap_cut))

    # Runs between cuts: [starts[j], ends[j]] inclusive.
    cut_at = np.flatnonzero(cut)
    starts = np.concatenate(([0], cut_at + 1))
    ends = np.concatenate((cut_at, [m - 1]))
    keep = (ends - starts + 1 >= config.min_points) & (path[ends] - path[starts] >= config.min_length_m)
    counts["segments"] = int(np.count_nonzero(keep))
    counts["rejected_segments"] = int(keep.shape[0] - counts["segments"])
    return starts[keep], ends[keep], counts


def _shape_cuts(points: np.ndarray, edge_len: np.ndarray, path: np.ndarray, steps: np.ndarray,
                gap_cut: np.ndarray, config: SegmentationConfig, window_m: float) -> np.ndarray:
    """Edges (m-1,) bool to cut by the spacing and direction tests (see segment_points)."""
    m = points.shape[0]
    cut = gap_cut.copy()
    if m < 3:
        return cut
    # Window ends ignoring cuts: the last point at least window_m of path behind, the first
    # at least window_m ahead (the neighbours when window_m = 0). Each pass clips them to
    # the runs between the current cuts.
    i = np.arange(m)
    reach_back = np.minimum(np.searchsorted(path, path - window_m, side="right") - 1, i - 1)
    reach_ahead = np.maximum(np.searchsorted(path, path + window_m, side="left"), i + 1)
    run_first, run_last = _run_bounds(cut)
    back, ahead = np.maximum(reach_back, run_first), np.minimum(reach_ahead, run_last)
    cut |= _spacing_cuts(points, edge_len, steps, back, ahead, config.eta, 0.5 * window_m)

    moments = _prefix_moments(points)
    while True:  # each pass adds at least one cut, so at most m-1 passes; usually 1–3
        run_first, run_last = _run_bounds(cut)
        back, ahead = np.maximum(reach_back, run_first), np.minimum(reach_ahead, run_last)
        tested = ((back < i) & (ahead > i)
                  & (path - path[back] >= 0.5 * window_m) & (path[ahead] - path >= 0.5 * window_m))
        breaks = _direction_breaks(points, moments, edge_len, np.flatnonzero(tested), back, ahead,
                                   config.alpha_max_rad)
        if breaks.shape[0] == 0:
            return cut
        cut[breaks] = True


def _run_bounds(cut: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """First and last point (m,), (m,) of every point's run between the ``cut`` edges (m-1,)."""
    cut_at = np.flatnonzero(cut)
    run_id = np.concatenate(([0], np.cumsum(cut)))
    run_first = np.concatenate(([0], cut_at + 1))[run_id]
    run_last = np.concatenate((cut_at, [cut.shape[0]]))[run_id]
    return run_first, run_last


def _spacing_cuts(points: np.ndarray, edge_len: np.ndarray, steps: np.ndarray, back: np.ndarray,
                  ahead: np.ndarray, eta: float, min_jump_m: float) -> np.ndarray:
    """Edges (m-1,) longer than ``min_jump_m`` whose spacing per beam exceeds η times that
    of the window on either side.

    The paper's (15) compares neighbouring single edges; one long edge between two dense
    stretches is where a scan jumps from one object to another. The references here are
    the windows (``back``/``ahead``, clipped to the gap-free run) that exclude the edge,
    so a noisy neighbour cannot mask a jump. Range noise of 1–2 cm on points 1–2 cm apart
    still makes single edges twice their neighbours, so only edges of at least
    ``min_jump_m`` (half a window: geometry below the window scale is treated as noise) are
    cut; smaller steps are left to the direction test. An edge with no neighbour in its
    run is not tested.
    """
    k = np.arange(points.shape[0] - 1)
    per_beam = edge_len / (steps[1:] - steps[:-1])
    left_lo, right_hi = back[k], ahead[k + 1]
    ref = np.full(k.shape[0], np.inf)
    has_left = left_lo < k
    has_right = right_hi > k + 1
    with np.errstate(divide="ignore", invalid="ignore"):
        left = _chord_length(points, left_lo, k) / (steps[k] - steps[left_lo])
        right = _chord_length(points, k + 1, right_hi) / (steps[right_hi] - steps[k + 1])
    ref = np.where(has_left, left, ref)
    ref = np.where(has_right, np.minimum(ref, right), ref)
    return (per_beam > eta * ref) & (edge_len >= min_jump_m)


def _direction_breaks(points: np.ndarray, moments: np.ndarray, edge_len: np.ndarray, idx: np.ndarray,
                      back: np.ndarray, ahead: np.ndarray, alpha_max_rad: float) -> np.ndarray:
    """Edges (as indices) to cut where the wall direction turns by more than α_max (14).

    The direction on each side of a tested point ``i`` (``idx``) is the principal axis of
    the points in ``[back[i], i]`` and in ``[i, ahead[i]]``, oriented along the scan. It
    averages the range noise of every point in the window instead of resting on the two
    end points of a chord (about 1.5× less angular noise for ~10 points), and on two
    straight walls meeting at ``i`` it is exactly each wall's direction.

    The direction turns at every point within one window of a corner, so only a point
    whose turn is the largest in its own windows is a break (non-maximum suppression); it
    stays with the wall whose line it lies closer to.
    """
    if idx.shape[0] == 0:
        return idx
    t = idx.shape[0]
    lo, hi = back[idx], ahead[idx]
    # Both windows of every tested point in one call: rows [0, t) before, [t, 2t) after.
    axes = _principal_axes(moments, np.concatenate((lo, idx)), np.concatenate((idx, hi)),
                           np.concatenate((points[idx] - points[lo], points[hi] - points[idx])))
    before, after = axes[:t], axes[t:]
    turn = np.abs(np.arctan2(_cross(before, after), np.einsum("ij,ij->i", before, after)))
    over = np.flatnonzero(turn > alpha_max_rad)
    if over.shape[0] == 0:  # the usual last pass: nothing turns enough
        return idx[:0]
    full = np.zeros(points.shape[0])
    full[idx] = turn
    # non-maximum suppression, needed only where the turn is large enough to matter
    worst = over[turn[over] >= _window_max(full, lo[over], hi[over])]
    # The break point stays with the side whose line it lies closer to: each side's line
    # has that side's axis through the centroid of its other points. Tested points are
    # never run ends, so both windows hold other points and both edges exist.
    i = idx[worst]
    own = moments[i + 1, :2] - moments[i, :2]                                  # the point, centred
    before_c = (moments[i, :2] - moments[lo[worst], :2]) / (i - lo[worst])[:, None]
    after_c = (moments[hi[worst] + 1, :2] - moments[i + 1, :2]) / (hi[worst] - i)[:, None]
    off_before = np.abs(_cross(before[worst], own - before_c))
    off_after = np.abs(_cross(after[worst], own - after_c))
    return np.where(off_before <= off_after, i, i - 1)


def _prefix_moments(points: np.ndarray) -> np.ndarray:
    """(m+1, 5) prefix sums of x, y, x², xy, y² of the centred points: the moments of any
    window follow from two rows. Centring keeps the window variances well conditioned."""
    centred = points - points.mean(axis=0)
    x, y = centred[:, 0], centred[:, 1]
    prefix = np.zeros((points.shape[0] + 1, 5))
    terms = np.empty((points.shape[0], 5))
    terms[:, 0], terms[:, 1] = x, y
    np.multiply(x, x, out=terms[:, 2])
    np.multiply(x, y, out=terms[:, 3])
    np.multiply(y, y, out=terms[:, 4])
    np.cumsum(terms, axis=0, out=prefix[1:])
    return prefix


def _principal_axes(moments: np.ndarray, first: np.ndarray, last: np.ndarray, along: np.ndarray) -> np.ndarray:
    """Unit principal axes (t, 2) of the windows ``[first[j], last[j]]`` (inclusive point
    indices), each signed to point along ``along[j]`` (t, 2)."""
    sums = moments[last + 1] - moments[first]                     # (t, 5)
    n = (last - first + 1).astype(float)
    mx, my = sums[:, 0] / n, sums[:, 1] / n
    cxx = sums[:, 2] / n - mx * mx
    cxy = sums[:, 3] / n - mx * my
    cyy = sums[:, 4] / n - my * my
    theta = 0.5 * np.arctan2(2.0 * cxy, cxx - cyy)
    axis = np.empty((theta.shape[0], 2))
    np.cos(theta, out=axis[:, 0])
    np.sin(theta, out=axis[:, 1])
    sign = np.where(np.einsum("ij,ij->i", axis, along) < 0, -1.0, 1.0)
    return axis * sign[:, None]


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(t,) z components of the cross products of rows of a and b (t, 2)."""
    return a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]


def _chord_length(points: np.ndarray, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """(t,) distances between points i and j (m)."""
    d = points[j] - points[i]
    return np.hypot(d[:, 0], d[:, 1])


def _window_max(values: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Maximum of ``values[lo[j]:hi[j]+1]`` for every j (one ``np.maximum.reduceat``).

    Args:
        values: (m,) values.
        lo, hi: (t,) inclusive window bounds, 0 ≤ lo ≤ hi < m.

    Returns:
        (t,) window maxima.
    """
    if lo.shape[0] == 0:
        return np.zeros(0)
    # one reduceat over the slices [lo_j, hi_j + 1) (each non-empty); the slices that
    # reduceat makes between consecutive windows are discarded. The appended 0 makes
    # hi + 1 = m a valid index; it lies in no window.
    bounds = np.empty(2 * lo.shape[0], dtype=np.intp)
    bounds[0::2] = lo
    bounds[1::2] = hi + 1
    return np.maximum.reduceat(np.append(values, 0.0), bounds)[0::2]


def numpy_valid_beams(ranges: np.ndarray, no_return_m: float, min_range_m: float) -> tuple[np.ndarray, dict[str, int]]:
    """valid_beams' mask and counts as numpy computed them (bsslam.scan.segment_kernels.beam_validity)."""
    finite = np.isfinite(ranges)
    no_return = finite & (ranges >= no_return_m)
    too_close = finite & ~no_return & (ranges <= min_range_m)
    mask = finite & ~no_return & ~too_close
    counts = {
        "beams": int(ranges.shape[0]),
        "valid": int(np.count_nonzero(mask)),
        "nonfinite": int(ranges.shape[0] - np.count_nonzero(finite)),
        "no_return": int(np.count_nonzero(no_return)),
        "too_close": int(np.count_nonzero(too_close)),
    }
    return mask, counts
