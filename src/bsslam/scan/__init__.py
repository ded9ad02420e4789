"""Scans and their segmentation into observed splines (spec §3, paper §III-A).

Imports numpy, bsslam.spline, the pose algebra (bsslam.se2) and the configuration only.
"""

from bsslam.scan.deskew import deskew
from bsslam.scan.laser_scan import LaserScan
from bsslam.scan.observed import ObservedSpline, ScanFeatures, extract_splines
from bsslam.scan.segment import (
    DEFAULT_WINDOW_M,
    INVALID_REASONS,
    beams_to_points,
    segment_points,
    segment_points_counted,
    valid_beams,
)

__all__ = [
    "DEFAULT_WINDOW_M",
    "INVALID_REASONS",
    "LaserScan",
    "ObservedSpline",
    "ScanFeatures",
    "beams_to_points",
    "deskew",
    "extract_splines",
    "segment_points",
    "segment_points_counted",
    "valid_beams",
]
