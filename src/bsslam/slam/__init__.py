"""The BS-SLAM filter, cut along three seams: the estimator (the joint Gaussian over pose
and control points, :class:`Estimator`), the map (:class:`SplineMap`: splines and their
batch table) and the measurement model (:class:`RangeModel`: beams to a stacked
linearisation); :class:`SplineSLAM` runs the paper's sequence over them. Imports
numpy/scipy and bsslam's spline/scan layers only."""

from bsslam.slam.estimator import CompressedEKF, Estimator
from bsslam.slam.features import MapSpline, SplineFeature
from bsslam.slam.filter import SplineSLAM, StepReport
from bsslam.slam.measurement import MeasurementModel, RangeModel
from bsslam.slam.oc_ekf import OCEKF
from bsslam.slam.spline_map import SplineMap
from bsslam.slam.state import JointState

__all__ = ["CompressedEKF", "Estimator", "JointState", "MapSpline", "MeasurementModel", "OCEKF", "RangeModel",
           "SplineFeature", "SplineMap", "SplineSLAM", "StepReport"]
