"""The BS-SLAM filter: joint state, motion and observation models, association, update,
map enlargement. Imports numpy/scipy and bsslam's spline/scan layers only."""

from bsslam.slam.features import MapSpline, SplineFeature
from bsslam.slam.filter import SplineSLAM, StepReport
from bsslam.slam.state import JointState

__all__ = ["JointState", "MapSpline", "SplineFeature", "SplineSLAM", "StepReport"]
