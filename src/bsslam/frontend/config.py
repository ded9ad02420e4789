"""Parameters of the laser-odometry front end (scan matcher and keyframe submap).

One frozen dataclass; every length is in metres, every angle in radians. The defaults are
used unchanged on all four real logs of ``shared/data`` and on the simulator (no per-log
tuning); the reasons are given next to each field.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from bsslam.errors import ConfigError


def _check(ok: bool, message: str) -> None:
    if not ok:
        raise ConfigError(message)


@dataclass(frozen=True)
class FrontendConfig:
    """Scan matching and laser odometry.

    Beams and points
        min_range_m: beams at or below this range are dropped (m).
        max_range_m: beams at or beyond this range are dropped (m). Far points move a lot
            for a small rotation error and are sparse; 30 m keeps the ends of long corridors
            (CSAIL, ACES), which are what fixes the motion along them.
        scan_voxel_m: the current scan is thinned to one point per cell of this size (m) so
            that dense near walls do not outweigh sparse far ones.
        max_scan_points: at most this many (evenly chosen) thinned points go into the
            Gauss–Newton refinement.
        search_points: at most this many of them go into the correlative search (its cost
            is linear in it).

    Submap
        submap_keyframes: the reference is the union of the last this-many keyframes.
        submap_voxel_m: the submap is thinned to one point per cell of this size (m).
        submap_rebuild_every: the submap's likelihood fields and KD-tree are rebuilt from
            the last ``submap_keyframes`` keyframes every this many keyframes; in between,
            a new keyframe is added to them in place (so the submap holds up to
            ``submap_keyframes + submap_rebuild_every − 1`` keyframes). 1 rebuilds always.
        keyframe_distance_m, keyframe_angle_rad: a scan becomes a keyframe when it is this
            far (m) or this much turned (rad) from the last keyframe.
        normal_neighbours: points used for each reference point's local line fit (normal).

    Correlative search (coarse to fine, around the odometry guess)
        search_window_m: half-width of the translation search (m) in x and y. The worst
            odometry errors between scans on the real logs are ~0.46 m (CSAIL).
        search_window_rad: half-width of the rotation search (rad); worst seen ~24° (CSAIL).
        coarse_step_m, coarse_step_rad: grid of the first level; its likelihood field has
            cells of half the step.
        coarse_sigma_m: blur of the first level's likelihood field (m); about the step so
            that a pose between grid nodes still scores.
        fine_step_m, fine_step_rad, fine_sigma_m: the same for the second level, searched
            ±1 coarse step around the best coarse candidates; its field's cells are one
            fine step.
        coarse_candidates: how many distinct coarse maxima are refined at the fine level.
        search_prior_weight: penalty on the correlative score (a mean likelihood in
            [0, 1]) at the corner of the search window, quadratic in the distance from the
            guess, so that equal scores (a corridor) prefer the odometry guess.

    Refinement (robust point-to-line Gauss–Newton)
        icp_iterations: Gauss–Newton iterations at most.
        icp_max_distance_m: correspondences farther than this are ignored (m) (first
            iteration; it shrinks to ``icp_min_distance_m`` as the match converges).
        icp_min_distance_m: the final correspondence gate (m).
        huber_m: Huber threshold of the residual weights (m).
        inlier_distance_m: a point is an inlier of the final match when its point-to-line
            residual is below this (m) and its nearest reference point within the gate.

    Covariance
        range_sigma_m: stated σ of one point-to-line residual (m): range noise plus wall
            roughness and the reference's own noise; the larger of it and the σ estimated
            from the residuals is used.
        covariance_inflation: the Gauss–Newton covariance assumes independent residuals;
            neighbouring points of one real wall are not, so it is multiplied by this
            factor. Without it the covariance is consistent on the simulator (independent
            range noise: mean NEES ≈ 3, tests/frontend); with ×10 the median NEES of the
            increments against the real logs' references is ≈ 4–5 (χ²₃ median 2.4), and
            those references carry cm/degree errors of their own
            (benchmarks/bench_frontend.py); on the simulator it is then ~×10 conservative.
        min_sigma_xy_m, min_sigma_rad: floors added to the match covariance (m, rad).

    Odometry model (prior of the refinement and covariance of a fallback)
        odom_sigma_xy_m, odom_sigma_xy_per_m: σ of Δx, Δy = a + b·|Δ| (m, m/m).
        odom_sigma_rad, odom_sigma_rad_per_rad, odom_sigma_rad_per_m: σ of Δφ =
            a + b·|Δφ| + c·|Δ| (rad, rad/rad, rad/m). Wide: the real wheel odometry of the
            1 Hz Intel log is off by up to ~20° in one step.

    Trust
        min_points: fewer valid points in the scan or in the reference → fall back.
        min_inlier_fraction: a match with fewer inliers (fraction of the refined points)
            is rejected → fall back.
        degenerate_ratio: when the smallest eigenvalue of the translation information is
            below this fraction of the largest, the match is flagged degenerate (a
            corridor); its weak direction then comes from the odometry prior.
    """

    # beams and points
    min_range_m: float = 0.05
    max_range_m: float = 30.0
    scan_voxel_m: float = 0.1
    max_scan_points: int = 400
    search_points: int = 150
    # submap
    submap_keyframes: int = 20
    submap_voxel_m: float = 0.05
    submap_rebuild_every: int = 5
    keyframe_distance_m: float = 0.3
    keyframe_angle_rad: float = math.radians(10.0)
    normal_neighbours: int = 7
    # correlative search
    search_window_m: float = 0.6
    search_window_rad: float = math.radians(30.0)
    coarse_step_m: float = 0.2
    coarse_step_rad: float = math.radians(2.0)
    coarse_sigma_m: float = 0.2
    fine_step_m: float = 0.05
    fine_step_rad: float = math.radians(0.5)
    fine_sigma_m: float = 0.07
    coarse_candidates: int = 4
    search_prior_weight: float = 0.05
    # refinement
    icp_iterations: int = 20
    icp_max_distance_m: float = 0.3
    icp_min_distance_m: float = 0.15
    huber_m: float = 0.03
    inlier_distance_m: float = 0.08
    # covariance
    range_sigma_m: float = 0.02
    covariance_inflation: float = 10.0
    min_sigma_xy_m: float = 0.005
    min_sigma_rad: float = math.radians(0.2)
    # odometry model
    odom_sigma_xy_m: float = 0.05
    odom_sigma_xy_per_m: float = 0.2
    odom_sigma_rad: float = math.radians(3.0)
    odom_sigma_rad_per_rad: float = 0.2
    odom_sigma_rad_per_m: float = math.radians(5.0)
    # trust
    min_points: int = 30
    min_inlier_fraction: float = 0.25
    degenerate_ratio: float = 0.02

    def __post_init__(self) -> None:
        positive = ("max_range_m", "scan_voxel_m", "submap_voxel_m", "search_window_m", "search_window_rad",
                    "coarse_step_m", "coarse_step_rad", "coarse_sigma_m", "fine_step_m", "fine_step_rad",
                    "fine_sigma_m", "icp_max_distance_m", "icp_min_distance_m", "huber_m",
                    "inlier_distance_m", "range_sigma_m", "covariance_inflation")
        for name in positive:
            _check(getattr(self, name) > 0, f"frontend.{name} must be > 0, got {getattr(self, name)!r}")
        nonneg = ("min_range_m", "keyframe_distance_m", "keyframe_angle_rad", "search_prior_weight",
                  "min_sigma_xy_m", "min_sigma_rad", "odom_sigma_xy_m", "odom_sigma_xy_per_m", "odom_sigma_rad",
                  "odom_sigma_rad_per_rad", "odom_sigma_rad_per_m", "degenerate_ratio")
        for name in nonneg:
            _check(getattr(self, name) >= 0, f"frontend.{name} must be ≥ 0, got {getattr(self, name)!r}")
        _check(self.max_range_m > self.min_range_m, "frontend.max_range_m must exceed min_range_m")
        _check(self.odom_sigma_xy_m > 0 and self.odom_sigma_rad > 0,
               "frontend.odom_sigma_xy_m and odom_sigma_rad must be > 0 (the fallback covariance)")
        for name in ("max_scan_points", "search_points", "submap_keyframes", "submap_rebuild_every", "coarse_candidates",
                     "icp_iterations", "min_points"):
            _check(getattr(self, name) >= 1, f"frontend.{name} must be ≥ 1, got {getattr(self, name)!r}")
        _check(self.normal_neighbours >= 3, "frontend.normal_neighbours must be ≥ 3")
        _check(self.icp_min_distance_m <= self.icp_max_distance_m,
               "frontend.icp_min_distance_m must be ≤ icp_max_distance_m")
        _check(0 <= self.min_inlier_fraction <= 1, "frontend.min_inlier_fraction must be in [0, 1]")
        _check(self.search_window_rad < math.pi, "frontend.search_window_rad must be < π")
        _check(self.fine_step_m <= self.coarse_step_m and self.fine_step_rad <= self.coarse_step_rad,
               "frontend fine steps must not exceed the coarse ones")
