"""Laser-odometry front end: a correlative + point-to-line scan matcher and a stateful
per-scan odometry that turns raw odometry increments into scan-matched ones with a
covariance."""

from bsslam.config import FrontendConfig
from bsslam.frontend.laser_odometry import FrontendStats, FrontendStep, LaserOdometry
from bsslam.frontend.update_schedule import UpdateSchedule
from bsslam.frontend.scan_matcher import MatchResult, ReferenceMap, match_scan, scan_points

__all__ = ["FrontendConfig", "FrontendStats", "FrontendStep", "LaserOdometry", "MatchResult", "ReferenceMap", "match_scan", "scan_points",
           "UpdateSchedule"]
