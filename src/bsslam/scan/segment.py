"""Splitting a laser scan into runs of points that each belong to one wall (spec §3, paper §III-A).

Three steps (the third's loops compiled: :mod:`bsslam.scan.segment_kernels`):

1. :func:`valid_beams` drops NaN/inf, no-return and too-close beams.
2. :func:`beams_to_points` turns the remaining beams into points of the robot frame.
3. :func:`segment_points` cuts the point sequence where the paper's direction (14) and
   spacing (15) criteria fail, or where consecutive points are farther apart than
   ``max_gap_m``, and keeps the runs that are long enough.
"""

from __future__ import annotations

import numpy as np

from bsslam.config import SegmentationConfig
from bsslam.errors import InputError
from bsslam.scan.laser_scan import LaserScan
from bsslam.scan.segment_kernels import (
    beam_validity,
    direction_breaks,
    direction_windows,
    kept_runs,
    prefix_moments,
    spacing_cuts,
    spacing_setup,
    turn_args,
)

#: Default path length (m) of the windows on which the direction and spacing tests are made.
#: Range noise of ~1 cm on neighbours 1–4 cm apart swamps the direction of a single
#: point-to-point vector; the principal axis of 20 cm of wall tilts by ~3° for 1 cm of
#: noise, well under α_max, while a wall of radius R turns by only 0.2/R rad across it
#: (11° at R = 1 m). Chosen on simulated walls (σ = 1 cm at 0.5–2 m) and Intel scans.
DEFAULT_WINDOW_M = 0.2

#: Reasons a beam is invalid, in the order they are checked (each beam counts once).
INVALID_REASONS = ("nonfinite", "no_return", "too_close")


def valid_beams(scan: LaserScan, config: SegmentationConfig) -> tuple[np.ndarray, dict[str, int]]:
    """Mark the beams of ``scan`` that hit something usable.

    A beam is invalid when its range is NaN or ±inf (``nonfinite``), at or above the
    scan's ``max_range`` or ``config.no_return_m`` (``no_return``), or at or below
    ``config.min_range_m`` (``too_close``, which also catches negative ranges).

    Returns:
        mask: (n,) bool, True for valid beams.
        counts: beams per reason (keys of :data:`INVALID_REASONS`) plus ``beams`` (n) and
            ``valid``; each invalid beam is counted under its first reason only.
    """
    ranges = scan.ranges
    no_return_m = scan.max_range if config.no_return_m is None else min(scan.max_range, config.no_return_m)
    # one compiled loop: each beam counts under its first reason only
    mask, valid, nonfinite, no_return, too_close = beam_validity(ranges, no_return_m, config.min_range_m)
    counts = {
        "beams": int(ranges.shape[0]),
        "valid": valid,
        "nonfinite": nonfinite,
        "no_return": no_return,
        "too_close": too_close,
    }
    return mask, counts


def beams_to_points(angles: np.ndarray, ranges: np.ndarray) -> np.ndarray:
    """Beam end points in the sensor (robot) frame.

    Args:
        angles: (m,) bearings (rad).
        ranges: (m,) ranges (m), finite.

    Returns:
        (m, 2) points ``ranges·(cos angles, sin angles)`` (m).
    """
    angles = np.asarray(angles, dtype=float)
    ranges = np.asarray(ranges, dtype=float)
    if angles.shape != ranges.shape or angles.ndim != 1:
        raise InputError(f"angles {angles.shape} and ranges {ranges.shape} must be equal 1-D arrays")
    return beam_points(angles, ranges)


def beam_points(angles: np.ndarray, ranges: np.ndarray) -> np.ndarray:
    """:func:`beams_to_points` of float64 (m,) angles and ranges, unchecked: for beams of a
    :class:`~bsslam.scan.laser_scan.LaserScan`, whose arrays are checked when it is made."""
    points = np.empty((angles.shape[0], 2))
    np.multiply(ranges, np.cos(angles), out=points[:, 0])
    np.multiply(ranges, np.sin(angles), out=points[:, 1])
    return points


def segment_points(points: np.ndarray, config: SegmentationConfig, *, beam_index: np.ndarray | None = None,
                   window_m: float = DEFAULT_WINDOW_M) -> list[np.ndarray]:
    """Split consecutive scan points into runs that each lie on one smooth wall.

    The paper (14)–(15) tests, at every point ``i``, the angle between the vectors to its
    neighbours, ``p_i = d_i − d_{i−1}`` and ``p_{i+1}``, against ``α_max``, and the ratio of
    their lengths against ``η``. On dense real scans (1° beams at 1 m are 1.7 cm apart,
    range noise ~1 cm) single-step vectors are mostly noise, so both tests are made over
    *windows* of about ``window_m`` of path length instead (with ``window_m`` = 0 they reduce
    to the paper's single steps):

    - direction (14): the principal axis of the points in the window ending at ``i`` and
      that of the window starting at ``i`` turn by at most ``α_max``. Two straight walls
      meeting at ``i`` give exactly the corner angle; a wall of radius R turns by about
      ``window_m / R`` (11° at R = 1 m for the default 0.2 m), and 1 cm of noise moves it
      by ~3°. Failures cluster within a window of a corner, so only a point whose turn is
      the largest in its own windows is a break (non-maximum suppression); it stays with
      the side whose line it lies closer to, so no point is lost at a corner. Breaks
      closer together than a window are found by repeating the test within the pieces
      until no new break appears (a few passes, each one sweep over the points).
    - spacing (15): an edge is cut when its length per beam step exceeds ``η`` times the
      mean spacing per beam step of the window on either side (beam steps, so a dropped
      beam is not a jump) and it is at least ``window_m / 2`` long (shorter steps are
      within the noise of dense scans, and left to the direction test).

    Every edge longer than ``max_gap_m`` is cut, and no window reaches across a cut.
    Points whose windows reach less than ``window_m / 2`` on either side (run ends) are not
    tested. Of the resulting runs, those with fewer than ``min_points`` points or a path
    length under ``min_length_m`` are dropped.

    Args:
        points: (m, 2) consecutive valid scan points in beam order (m).
        config: the thresholds α_max, η, max gap, minimum points and length.
        beam_index: (m,) increasing beam number of each point, used to count the beam steps
            a window spans; None means consecutive beams.
        window_m: path length (m) of the windows the tests use.

    Returns:
        Segments in beam order, each an increasing (k,) int array of row indices into
        ``points``; segments never overlap.
    """
    segments, _ = segment_points_counted(points, config, beam_index=beam_index, window_m=window_m)
    return segments


def segment_points_counted(points: np.ndarray, config: SegmentationConfig, *,
                           beam_index: np.ndarray | None = None,
                           window_m: float = DEFAULT_WINDOW_M) -> tuple[list[np.ndarray], dict[str, int]]:
    """:func:`segment_points`, also returning counts: ``gap_cuts``, ``shape_cuts`` (direction
    or spacing), ``segments`` kept and ``rejected_segments`` (too few points or too short)."""
    starts, ends, counts = segment_bounds_counted(points, config, beam_index=beam_index, window_m=window_m)
    return [np.arange(s, e + 1) for s, e in zip(starts.tolist(), ends.tolist())], counts


def segment_bounds_counted(points: np.ndarray, config: SegmentationConfig, *,
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
        if steps.shape != (m,) or np.logical_or.reduce(steps[1:] <= steps[:-1]):
            raise InputError(f"beam_index must be (m,) = ({m},) and strictly increasing")

    edges = points[1:] - points[:-1]                     # (m-1, 2): edge k joins points k, k+1
    edge_len = np.hypot(edges[:, 0], edges[:, 1])         # (m-1,)
    gap_cut = edge_len > config.max_gap_m                 # (m-1,)
    path, cut = _shape_cuts(points, edge_len, steps, gap_cut, config, window_m)
    bounds, gap_cuts, shape_cuts, rejected = kept_runs(cut, gap_cut, path, config.min_points, config.min_length_m)
    counts["gap_cuts"] = gap_cuts
    counts["shape_cuts"] = shape_cuts
    counts["segments"] = bounds.shape[1]
    counts["rejected_segments"] = rejected
    return bounds[0], bounds[1], counts


def _shape_cuts(points: np.ndarray, edge_len: np.ndarray, steps: np.ndarray, gap_cut: np.ndarray,
                config: SegmentationConfig, window_m: float) -> tuple[np.ndarray, np.ndarray]:
    """(m,) path length from point 0 (m) and the edges (m-1,) bool to cut: the gap cuts
    plus those of the spacing and direction tests (see segment_points).

    Compiled loops (:mod:`bsslam.scan.segment_kernels`) do the window searches and
    arithmetic; numpy does the chord lengths, the mean and the angles, on whole arrays."""
    m = points.shape[0]
    cut = gap_cut.copy()
    # Window ends ignoring cuts (reach): the last point at least window_m of path behind,
    # the first at least window_m ahead (the neighbours when window_m = 0); the windows
    # are them clipped to the runs between the current cuts.
    path, ends, chord = spacing_setup(points, edge_len, cut, window_m)
    reach, window = ends[:2], ends[2:]
    if m < 3:
        return path, cut
    half = 0.5 * window_m
    spacing_cuts(edge_len, steps, window, np.hypot(chord[0], chord[1]), cut, config.eta, half)

    # points.mean(axis=0) without its six Python calls: the same sum, divided by the count
    moments = prefix_moments(points, np.add.reduce(points, axis=0) / m)
    tested = np.empty((3, m), dtype=np.intp)
    angle_args = np.empty((2, 2 * m))
    # each pass adds at least one cut, so at most m-1 passes; usually 1–3
    while t := direction_windows(path, moments, reach, cut, half, window, tested, angle_args):
        theta = np.arctan2(angle_args[0, : 2 * t], angle_args[1, : 2 * t])
        theta *= 0.5
        ax, ay = np.cos(theta), np.sin(theta)
        turn = turn_args(points, tested, t, ax, ay)
        if not direction_breaks(moments, tested, t, ax, ay, np.arctan2(turn[0], turn[1]), config.alpha_max_rad, cut):
            break
    return path, cut
