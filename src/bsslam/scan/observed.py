"""Observed splines: the B-splines fitted to one scan's segments, with the map from each
beam to its spline parameter that the filter's observation model needs (spec §3, §6)."""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from bsslam.config import SLAMConfig
from bsslam.scan.laser_scan import LaserScan
from bsslam.scan.segment import beam_points, segment_bounds_counted, valid_beams
from bsslam.spline import BSplineCurve
from bsslam.spline.batch import CurveTable, curve_table
from bsslam.spline.fit import fit_runs


@dataclass(frozen=True, eq=False)
class ObservedSpline:
    """A spline fitted to one segment of a scan, in the robot (sensor) frame.

    Attributes:
        curve: the fitted clamped curve, of degree ``config.spline.degree`` (order = degree + 1).
        phi: (n_control, k) least-squares map Φ: ``curve.control_points == phi @ points``.
        beam_indices: (k,) int indices of the segment's beams into the scan's arrays, increasing.
        params: (k,) chord-length parameter of each beam's point on ``curve`` (m).
        points: (k, 2) the beams' end points (m).
        ranges: (k,) the beams' ranges (m).
        angles: (k,) the beams' bearings (rad).
    """

    curve: BSplineCurve
    phi: np.ndarray
    beam_indices: np.ndarray
    params: np.ndarray
    points: np.ndarray
    ranges: np.ndarray
    angles: np.ndarray


@dataclass(frozen=True)
class ScanFeatures:
    """What :func:`extract_splines` found in a scan.

    Attributes:
        splines: observed splines in beam order.
        counts: ``beams``, ``valid``, invalid beams by reason (``nonfinite``, ``no_return``,
            ``too_close``), ``gap_cuts``, ``shape_cuts``, ``segments`` (kept by the
            segmenter), ``rejected_segments`` (too few points or too short),
            ``fit_failed`` (segments no spline could be fitted to) and ``splines``.
    """

    splines: list[ObservedSpline] = field(default_factory=list)
    counts: dict[str, int] = field(default_factory=dict)

    # Built on first use and kept: the filter asks for them at every pass over the scan.
    @cached_property
    def curve_table(self) -> CurveTable:
        """The splines' knot structure as one batch table (needs at least one spline)."""
        return curve_table([o.curve.knots for o in self.splines], [o.curve.degree for o in self.splines])

    @cached_property
    def control_points(self) -> np.ndarray:
        """(N, 2) the splines' control points stacked in table order (robot frame, m)."""
        # np.vstack of (n_i, 2) arrays, without its wrappers' Python calls
        return np.concatenate([o.curve.control_points for o in self.splines])


def extract_splines(scan: LaserScan, config: SLAMConfig) -> ScanFeatures:
    """Valid beams → points → segments → one least-squares spline per segment.

    Each segment is fitted with ``fit_curve(points, config.spline.degree,
    config.spline.knot_spacing_m)`` on its own chord-length parameterisation starting at
    0. A segment that cannot be fitted (``FitError``) is counted, not raised.
    """
    mask, counts = valid_beams(scan, config.segmentation)
    beam_indices = mask.nonzero()[0]          # np.flatnonzero of the 1-D mask, in one call
    angles = scan.angles[beam_indices]
    ranges = scan.ranges[beam_indices]
    points = beam_points(angles, ranges)
    starts, ends, segment_counts = segment_bounds_counted(points, config.segmentation, beam_index=beam_indices)
    counts.update(segment_counts)
    # all segments' fits at once (they share degree and spacing): the same fits as
    # fit_curve on each segment's points
    fits = fit_runs(points, starts, ends, config.spline.degree, config.spline.knot_spacing_m,
                    max_noise_gain=config.spline.max_noise_gain)
    splines = []
    fit_failed = 0
    for start, end, fit in zip(starts.tolist(), ends.tolist(), fits):
        if fit is None:  # fit_curve raised FitError
            fit_failed += 1
            continue
        rows = slice(start, end + 1)
        splines.append(ObservedSpline(curve=fit.curve, phi=fit.phi, beam_indices=beam_indices[rows],
                                      params=fit.params, points=points[rows], ranges=ranges[rows],
                                      angles=angles[rows]))
    counts["fit_failed"] = fit_failed
    counts["splines"] = len(splines)
    return ScanFeatures(splines=splines, counts=counts)
