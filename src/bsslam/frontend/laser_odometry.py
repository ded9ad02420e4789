"""Stateful laser odometry: each frame's scan is matched against a submap of the last few
keyframes, turning the raw odometry increment into a scan-matched one with a covariance.

The front end keeps its own pose (the composition of the increments it returned, starting
at the first frame's odometry pose). For every frame after the first:

1. the raw increment ``between(previous odometry, odometry)`` predicts the pose,
2. the scan is matched around that guess against the submap (:class:`ReferenceMap`),
3. the increment is ``between(previous pose, matched pose)`` and its covariance the match
   covariance turned into the previous robot frame; when the match is not trusted — the
   matcher failed, or its increment disagrees with the odometry's beyond the
   ``odometry_gate`` probability region of both covariances, alone and summed with the
   matched increments just before it (``odometry_gate_steps``) — the raw increment is
   returned with the wheels' covariance (:meth:`LaserOdometry.fallback_covariance`; a
   *fallback*, counted). The first match after fallbacks is gated with their error
   (under the covariance each fallback was given) added: it undoes that error, which
   its own step's odometry does not hold,
4. the scan becomes a keyframe when the robot is far enough from the last one; the
   submap is the union of the last ``submap_keyframes`` keyframes, thinned. Keyframes
   farther from the newest than ``2·max_range_m + search_window_m`` cannot overlap its
   scan and are dropped, which also bounds the submap's extent (and its grids) after a
   long jump of the odometry.

Input is checked once on entry (:mod:`bsslam.input_limits`): a non-finite or huge
odometry pose or laser offset raises :class:`~bsslam.errors.InputError` instead of
reaching the numba kernels.

The covariance is that of the new pose *given* the submap, i.e. of the increment given
the previous pose. Increments matched against a shared submap are slightly correlated;
a consumer that treats them as independent odometry (the EKF) ignores that.
"""

from __future__ import annotations

import dataclasses
import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from bsslam.chi2 import chi2_quantile
from bsslam.config import FrontendConfig
from bsslam.dataset import Frame
from bsslam.errors import InputError
from bsslam.input_limits import InputLimits, offset_problem, pose_problem
from bsslam.frontend.scan_matcher import (MatchResult, ReferenceMap, _wrap, estimate_normals, scan_disagreement,
                                          scan_points, voxel_thin, weak_prior_share)
from bsslam.se2 import compose_with_covariance, inverse_with_covariance, squared_mahalanobis


# Limits of the poses the front end accepts (the defaults of the readers').
_LIMITS = InputLimits()

# The region a match rejected on its own step must fall in once composed over the last
# steps (:meth:`LaserOdometry._agrees_over_steps`): the χ²₃ median, where a typical
# consistent match lies.
_WINDOW_PROBABILITY = 0.5

# The odometry's translation σ learned from the matches (FrontendConfig.odometry_learned_window):
# matches needed before it is used, the bounds of its factor on the model's σ, and the
# median of χ²₁ (a component's squared disagreement in its σ).
_LEARN_MIN_MATCHES = 20
_LEARN_SCALE_BOUNDS = (0.1, 10.0)
_CHI2_1_MEDIAN = 0.454936423119572

# One pose at a time, :mod:`bsslam.se2`'s compose/between cost ~20 µs of numpy calls each
# (several per scan); these do the same float arithmetic, in the same order, on Python
# floats (math.cos/sin and numpy's agree bit for bit, and Python's float ``%`` is numpy's
# ``mod``; tests/frontend check them against se2).

def _compose(a: tuple[float, float, float], b: tuple[float, float, float]) -> tuple[float, float, float]:
    """:func:`bsslam.se2.compose` of two poses given as float triples."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return (a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], _wrap(a[2] + b[2]))


def _between(a: tuple[float, float, float], b: tuple[float, float, float]) -> tuple[float, float, float]:
    """:func:`bsslam.se2.between` (``compose(inverse(a), b)``) of float triples."""
    c, s = math.cos(a[2]), math.sin(a[2])
    inv = (-c * a[0] - s * a[1], s * a[0] - c * a[1], _wrap(-a[2]))
    return _compose(inv, b)


def _triple(pose) -> tuple[float, float, float]:
    x, y, phi = np.asarray(pose, dtype=float).reshape(3).tolist()
    return x, y, phi


@dataclass(frozen=True)
class FrontendStep:
    """What :meth:`LaserOdometry.step` returns for one frame.

    Attributes:
        increment: (3,) robot-frame motion since the previous frame (Δx m, Δy m, Δφ rad);
            None for the first frame (no motion to report, as the filter's ``step`` expects).
        covariance: (3, 3) covariance of ``increment``; None for the first frame.
        pose: (3,) the front end's pose after this frame (x m, y m, φ rad).
        odometry_increment: (3,) the raw increment from the frame's odometry; None first.
        match: the scan match, None when none was attempted (first frame, empty submap).
        fallback: True when ``increment`` is the raw odometry increment.
        keyframe: True when the scan was added to the submap.
        carried: (3, 3) on the first trusted match after fallbacks: what the fallbacks'
            error, under the odometry model's covariance, adds to the covariance of
            ``increment`` (not in ``covariance``). Where the match places the scan against
            keyframes mapped before the fallbacks, its increment from the fallbacks' pose
            takes their error back; a filter that predicted the fallbacks with the model's
            covariance let its walls take that error out already, and must not be told it
            twice with a match's σ (:class:`bsslam.mapper.Mapper` adds it then). An upper
            bound: a fallback's scan kept as a keyframe at the fallback's pose anchors the
            match partly there, and then less is taken back. None otherwise.
    """

    increment: np.ndarray | None
    covariance: np.ndarray | None
    pose: np.ndarray
    odometry_increment: np.ndarray | None
    match: MatchResult | None
    fallback: bool
    keyframe: bool
    carried: np.ndarray | None = None


@dataclass
class FrontendStats:
    """Counters over all frames fed so far.

    Attributes:
        frames: frames processed.
        matched: frames whose increment comes from a trusted match.
        fallbacks: frames (after the first) that used the raw odometry increment.
        reasons: fallback counts by reason (:data:`~bsslam.frontend.scan_matcher.FAIL_REASONS`,
            or ``inconsistent_with_odometry``: see :attr:`FrontendConfig.odometry_gate`).
        degenerate: trusted matches flagged degenerate.
        keyframes: keyframes made.
        gated_over_steps: trusted matches that disagreed with their own odometry
            increment but agreed with the odometry summed over the last few steps
            (``odometry_gate_steps``: an odometry skewed in time).
    """

    frames: int = 0
    matched: int = 0
    fallbacks: int = 0
    reasons: dict[str, int] = field(default_factory=dict)
    degenerate: int = 0
    keyframes: int = 0
    gated_over_steps: int = 0


def _increment_covariance(start: np.ndarray, end: np.ndarray, start_covariance: np.ndarray) -> np.ndarray:
    """(3, 3) the first-order covariance of the increment from ``start`` to ``end`` (each
    (3,), front-end frame) that an error of ``start`` with covariance (3, 3) makes."""
    inverse, inverse_covariance = inverse_with_covariance(start, start_covariance)
    return compose_with_covariance(inverse, inverse_covariance, end, np.zeros((3, 3)))[1]


@dataclass(frozen=True)
class _Keyframe:
    pose: np.ndarray          # (3,) robot pose in the front-end frame
    points: np.ndarray        # (k, 2) thinned points, robot frame
    normals: np.ndarray       # (k, 2) their normals, robot frame
    linear: np.ndarray        # (k,) line-like
    world: np.ndarray         # (k, 2) the points in the front-end frame (the pose is fixed)
    world_normals: np.ndarray  # (k, 2) their normals in the front-end frame


class LaserOdometry:
    """Scan-matched odometry; feed it frames in order with :meth:`step`.

    Args:
        config: front-end parameters.
    """

    def __init__(self, config: FrontendConfig = FrontendConfig()) -> None:
        self.config = config
        self.stats = FrontendStats()
        self.pose: np.ndarray | None = None
        self._prev_odometry: np.ndarray | None = None
        self._keyframes: deque[_Keyframe] = deque(maxlen=config.submap_keyframes)
        self._reference: ReferenceMap | None = None
        self._since_rebuild = 0
        # the last trusted matches, newest last, each (increment, covariance, odometry
        # increment) (3,), (3, 3), (3,); emptied by a fallback. The earlier steps' odometry
        # covariance is not kept: the window adds none of their freedom
        self._recent: deque[tuple[np.ndarray, np.ndarray, np.ndarray]] = deque(
            maxlen=config.odometry_gate_steps - 1)
        # the last well-constrained trusted matches' squared disagreement with the odometry,
        # forward, sideways and in heading, each in σ² of the odometry model; newest last
        self._odometry_misfit: deque[tuple[float, float, float]] = deque(maxlen=config.odometry_learned_window)
        # since the last trusted match, the covariances (3, 3) of the fallbacks' error in
        # :attr:`pose` (front-end frame): under the odometry model's covariance (what a
        # filter step that predicted them with it must take back, ``carried``) and under
        # the covariance each was given (what the wheels err by, for the odometry gate)
        self._carried: tuple[np.ndarray, np.ndarray] | None = None

    def odometry_covariance(self, increment: np.ndarray) -> np.ndarray:
        """(3, 3) diagonal covariance of a raw odometry increment under the config's model."""
        cfg = self.config
        d = float(np.hypot(increment[0], increment[1]))
        sxy = cfg.odom_sigma_xy_m + cfg.odom_sigma_xy_per_m * d
        sphi = cfg.odom_sigma_rad + cfg.odom_sigma_rad_per_rad * abs(float(increment[2])) + cfg.odom_sigma_rad_per_m * d
        return np.diag([sxy ** 2, sxy ** 2, sphi ** 2])

    def step(self, frame: Frame) -> FrontendStep:
        """Process one frame; returns the corrected increment since the previous frame.

        Raises:
            InputError: the frame's odometry pose or laser offset is non-finite or beyond
                the physical limits (readers bridge such poses before they get here).
        """
        cfg = self.config
        reason = pose_problem(frame.odometry, _LIMITS) or (
            None if frame.laser_offset is None else offset_problem(frame.laser_offset, _LIMITS))
        if reason is not None:
            raise InputError(f"front end at stamp {frame.stamp}: {reason}")
        odometry = np.asarray(frame.odometry, dtype=float).reshape(3)
        points = scan_points(frame.scan, frame.laser_offset, cfg)
        self.stats.frames += 1
        if self.pose is None:
            self.pose = odometry.copy()
            self._prev_odometry = odometry
            self._add_keyframe(self.pose, points)
            return FrontendStep(None, None, self.pose.copy(), None, None, False, True)

        odometry3 = _triple(odometry)
        odo_inc = np.array(_between(_triple(self._prev_odometry), odometry3))
        self._prev_odometry = odometry
        odo_cov = self.odometry_covariance(odo_inc)
        prev = self.pose
        prev3 = _triple(prev)
        # Robot-frame (of the previous pose) ↔ front-end frame: rotate by its heading.
        rot = np.eye(3)
        c, s = np.cos(prev[2]), np.sin(prev[2])
        rot[:2, :2] = [[c, -s], [s, c]]
        guess = np.array(_compose(prev3, odo_inc.tolist()))
        match = None
        reference = self._submap()
        prior_cov = rot @ odo_cov @ rot.T
        if reference is not None:
            scale = self.odometry_scale()
            weak_prior = None if scale is None else rot @ (odo_cov * np.outer(scale, scale)) @ rot.T
            match = reference.match(points, guess, prior_cov, weak_prior)
        if match is not None and match.ok:
            increment = np.array(_between(prev3, match.pose.tolist()))
            covariance = rot.T @ match.covariance @ rot
            covariance = 0.5 * (covariance + covariance.T)
            # After fallbacks the match (against keyframes from before them) also undoes
            # their error, which the raw increment it is gated against does not hold: as
            # much as the wheels err by (the model's σ let in matches 0.47–0.85 m off on
            # the campus's open ground, where the wheels were 1–7 cm off). An upper bound,
            # as `carried`: an episode longer than the window leaves no keyframe from
            # before it, and the match then undoes none of it. The window test below sees
            # no earlier steps after a fallback (they are cleared)
            gated = covariance if self._carried is None else \
                covariance + _increment_covariance(prev, match.pose, self._carried[1])
            if not self._agrees_with_odometry(increment, gated, odo_inc, odo_cov):
                if self._agrees_over_steps(increment, gated, odo_inc, odo_cov):
                    self.stats.gated_over_steps += 1
                else:
                    match = dataclasses.replace(match, ok=False, reason="inconsistent_with_odometry")
        carried = None
        if match is not None and match.ok:
            self.stats.matched += 1
            self.stats.degenerate += int(match.degenerate)
            fallback = False
            if self._carried is not None:
                carried, self._carried = _increment_covariance(prev, match.pose, self._carried[0]), None
            self._recent.append((increment, covariance, odo_inc))   # maxlen 0 keeps none
            if self._learns_from(match):
                self._learn_odometry(match, guess, prior_cov, odo_cov, rot)
        else:
            increment, covariance, fallback = odo_inc, self.fallback_covariance(odo_cov), True
            self._recent.clear()
            reason = "too_few_reference_points" if match is None else match.reason
            self.stats.fallbacks += 1
            self.stats.reasons[reason] = self.stats.reasons.get(reason, 0) + 1
            model, given = self._carried or (np.zeros((3, 3)), np.zeros((3, 3)))
            self._carried = (compose_with_covariance(prev, model, increment, odo_cov)[1],
                             compose_with_covariance(prev, given, increment, covariance)[1])
        self.pose = np.array(_compose(prev3, increment.tolist()))
        keyframe = self._is_keyframe(self.pose)
        if keyframe:
            self._add_keyframe(self.pose, points)
        return FrontendStep(increment, covariance, self.pose.copy(), odo_inc, match, fallback, keyframe, carried)

    def odometry_scale(self) -> np.ndarray | None:
        """(3,) factors on the odometry model's σ of the robot-frame Δx (forward), Δy and
        Δφ (always 1) that the last well-constrained matches measured
        (``odometry_learned_window``): for Δx and Δy, √(median squared disagreement in the
        model's σ ÷ the median of χ²₁), within [0.1, 10]. None until 20 matches are in,
        or when not learning.

        It is the prior a degenerate match's weak direction is refined with
        (:meth:`ReferenceMap.match`): the model's σ must cover the worst wheels bsslam may
        meet, so where the wheels are better, a corridor's position along itself came from
        the scan's few features along it (which pull towards where the submap has points:
        on Acapulco four matches in a row came out 20–50 % short while the odometry was
        within 10 %). The heading keeps the model's σ: a wheel odometry's heading drifts
        by a bias (0.29° a metre on the synthetic logs) that a σ does not describe."""
        if len(self._odometry_misfit) < _LEARN_MIN_MATCHES:
            return None
        scale = np.sqrt(np.median(np.asarray(self._odometry_misfit)[:, :2], axis=0) / _CHI2_1_MEDIAN)
        return np.r_[np.clip(scale, *_LEARN_SCALE_BOUNDS), 1.0]

    def fallback_covariance(self, odometry_covariance: np.ndarray) -> np.ndarray:
        """(3, 3) the covariance of a fallback (the raw odometry increment standing in for a
        match) whose odometry model covariance is ``odometry_covariance`` (3, 3, robot
        frame): with ``fallback_learned``, the model's with its σ of Δx, Δy and Δφ each
        scaled by the RMS disagreement of the last well-constrained matches with the
        odometry in the model's σ (``odometry_learned_window``; within [0.1, 10]), the model's
        own until 20 matches are in.

        The model is the refinement's prior and must be wide enough for the worst wheels
        bsslam may meet (3° + 0.2·|Δφ| + 5°/m in heading); as a fallback's covariance it said
        8–12° for a 1 m step of the campus's wheels, which erred by at most 3.1° (three
        perturbed runs), and the filter, with no old wall
        in sight to take it back, carried that into the seam and the pose graph's heading
        until the next loop closure (the online covariance's median NEES 0.3). The RMS, not
        the median the weak prior uses, because real wheels' errors have tails (CSAIL: the
        median says 0.45 of the model's heading σ, the RMS 0.64, and the 99th percentile of
        the error is 2.58 × 0.80 of it) and a fallback is a step the scan could not check.
        A direction the wheels never err in measurably (sideways, in simulation) sits at
        the 0.1 bound. Alone, it left three campus runs of forty 0.75–5.5 m off (a submap
        bent after a fallback, then a loop closure wrong in heading let in); the mapper
        therefore checks each such step against the walls
        (:meth:`bsslam.mapper.Mapper._checked_by_walls`; docs/real_logs.md, "A fallback as
        wide as the wheels err")."""
        cov = np.asarray(odometry_covariance, dtype=float)
        if not self.config.fallback_learned or len(self._odometry_misfit) < _LEARN_MIN_MATCHES:
            return cov
        scale = np.clip(np.sqrt(np.mean(np.asarray(self._odometry_misfit), axis=0)), *_LEARN_SCALE_BOUNDS)
        return cov * np.outer(scale, scale)

    def _learns_from(self, match: MatchResult) -> bool:
        """Whether a trusted ``match`` measures the odometry: it constrains every direction
        well enough that no weak prior would touch it (its share, :func:`weak_prior_share`
        of its weakness, is 0; such a match is never degenerate). Decided by the scan alone,
        so the matches learned from are the same whether or not a weak prior was on offer
        (none is before the first 20)."""
        return weak_prior_share(match.weakness, self.config.degenerate_ratio) == 0.0

    def _learn_odometry(self, match: MatchResult, guess: np.ndarray, prior_cov: np.ndarray,
                        odo_cov: np.ndarray, rot: np.ndarray) -> None:
        """Record how far a trusted, well-constrained ``match`` lies from the odometry's
        ``guess`` (3,, front-end frame), forward and sideways in the previous robot frame
        (``rot``: its rotation, 3 × 3) and in heading, each squared in σ² of the odometry
        model ``odo_cov`` (3, 3, robot frame). The refinement's prior ``prior_cov`` (3, 3,
        front-end frame) pulled the match towards the guess; the pull is undone
        (:func:`~bsslam.frontend.scan_matcher.scan_disagreement`) so that the disagreement
        is the scan's, not partly the prior's."""
        try:
            e = scan_disagreement(match, guess, prior_cov, self.config)
        except np.linalg.LinAlgError:
            return
        e = rot.T @ e
        misfit = (float(e[0] ** 2 / odo_cov[0, 0]), float(e[1] ** 2 / odo_cov[1, 1]), float(e[2] ** 2 / odo_cov[2, 2]))
        if all(math.isfinite(m) for m in misfit):
            self._odometry_misfit.append(misfit)

    def _agrees_with_odometry(self, increment: np.ndarray, covariance: np.ndarray, odometry: np.ndarray,
                              odometry_covariance: np.ndarray, probability: float | None = None) -> bool:
        """Whether a match's ``increment`` (3,) lies within the ``odometry_gate`` region of
        the odometry's ``odometry`` (3,), with both covariances (3, 3), as the filter gates
        an observation against its prediction. A scene that looks alike at another pose
        (a corner, a doorway seen from a sparse log's 1 m steps) gives a confident match
        tens of degrees off; on the shared logs every match beyond the 99 % region was
        further from the reference than the odometry, and none was on ACES, Edmonton and
        Acapulco. ``probability``: a region other than the gate's (the window's, below)."""
        gate = self.config.odometry_gate
        if gate >= 1.0:
            return True
        gate = gate if probability is None else probability
        try:
            distance = squared_mahalanobis(increment, odometry, covariance + odometry_covariance)
        except np.linalg.LinAlgError:
            return True
        return distance <= chi2_quantile(gate, 3)

    def _agrees_over_steps(self, increment: np.ndarray, covariance: np.ndarray, odometry: np.ndarray,
                           odometry_covariance: np.ndarray) -> bool:
        """Whether the match's ``increment`` composed after the trusted matches just before
        it (up to ``odometry_gate_steps`` − 1 of them, none past a fallback) agrees with the
        odometry's increments composed over the same steps, over any of those windows:
        the composed difference within the 50 % region (:data:`_WINDOW_PROBABILITY`) of
        the matches' composed covariance and *this* step's odometry covariance (the window
        moves the odometry's motion between its steps but adds none of their freedom).

        A log's odometry can be skewed in time against its scans: motion is then booked to
        the wrong one of two neighbouring increments, each off by tens of degrees in
        opposite directions while their sum is right (CSAIL's first scans: −23.7° and
        −29.5° where the robot turned −12.1° and −43.1°). A noise model of independent
        increments calls the right match of the second step an outlier; over the two
        steps it is not. A match wrong on its own step stays as wrong over the window and
        is judged by its own step's σ, so the earlier steps' wide regions (a sharp turn
        just before) do not let it in.

        The window is a second test, so it must not merely pass a match the first one
        turned away at the gate's edge: it has to *explain* the disagreement, placing the
        match as close as a typical consistent one. On the shared logs the right matches
        it saved came to 0.7 and 1.0 (χ²₃, from 11.4 and 16.8 alone: CSAIL's scan 19,
        the campus's scan 1710), the wrong ones it would have let in at the 99 % gate to
        10.7–11.1 (intel-noisy's scan 778 under 1 mm of range noise, from 14.0)."""
        matched, matched_cov = increment, covariance
        odo, odo_cov = odometry, odometry_covariance
        zero = np.zeros((3, 3))
        for inc, cov, o_inc in reversed(self._recent):
            matched, matched_cov = compose_with_covariance(inc, cov, matched, matched_cov)
            odo, odo_cov = compose_with_covariance(o_inc, zero, odo, odo_cov)
            if self._agrees_with_odometry(matched, matched_cov, odo, odo_cov, _WINDOW_PROBABILITY):
                return True
        return False

    # -- submap ----------------------------------------------------------------------------

    def _is_keyframe(self, pose: np.ndarray) -> bool:
        if not self._keyframes:
            return True
        rel = _between(_triple(self._keyframes[-1].pose), _triple(pose))
        return bool(np.hypot(rel[0], rel[1]) >= self.config.keyframe_distance_m
                    or abs(rel[2]) >= self.config.keyframe_angle_rad)

    def _add_keyframe(self, pose: np.ndarray, points: np.ndarray) -> None:
        keep = voxel_thin(points, self.config.submap_voxel_m)
        pts = points[keep]
        normals, linear = estimate_normals(pts, self.config.normal_neighbours)
        pose = np.asarray(pose, dtype=float).copy()
        kf = _Keyframe(pose, pts, normals, linear, *self._to_world(pose, pts, normals))
        reach = 2.0 * self.config.max_range_m + self.config.search_window_m
        x, y = pose[0], pose[1]      # the same differences, without a slice and array per keyframe
        near = [k for k in self._keyframes if math.hypot(k.pose[0] - x, k.pose[1] - y) <= reach]
        if len(near) < len(self._keyframes):
            # the robot jumped away from them: they cannot overlap its scans any more
            self._keyframes = deque(near, maxlen=self.config.submap_keyframes)
            self._reference = None
        self._keyframes.append(kf)
        self.stats.keyframes += 1
        self._since_rebuild += 1
        # Rebuilding the fields of the whole submap costs a few ms; in between, the new
        # keyframe is added in place (old keyframes then stay a few keyframes longer).
        if self._reference is not None and self._since_rebuild < self.config.submap_rebuild_every:
            if self._reference.extend(kf.world, kf.world_normals, kf.linear):
                return
        self._reference = None

    @staticmethod
    def _to_world(pose: np.ndarray, points: np.ndarray, normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Robot-frame points and normals (k, 2) at ``pose`` (3,) in the front-end frame."""
        c, s = np.cos(pose[2]), np.sin(pose[2])
        R = np.array([[c, -s], [s, c]])
        return points @ R.T + pose[:2], normals @ R.T

    def _submap(self) -> ReferenceMap | None:
        """The reference of the last keyframes in the front-end frame (built lazily)."""
        if self._reference is not None:
            return self._reference
        pts, nrm, lin = [], [], []
        for kf in self._keyframes:
            pts.append(kf.world)
            nrm.append(kf.world_normals)
            lin.append(kf.linear)
        self._since_rebuild = 0
        points = np.concatenate(pts) if pts else np.zeros((0, 2))
        if points.shape[0] < self.config.min_points:
            return None
        normals, linear = np.concatenate(nrm), np.concatenate(lin)
        # Newest first, so thinning keeps the most recent point of each cell.
        order = np.arange(points.shape[0])[::-1]
        keep = order[voxel_thin(points[order], self.config.submap_voxel_m)]
        self._reference = ReferenceMap(points[keep], self.config, normals=normals[keep], linear=linear[keep])
        return self._reference
