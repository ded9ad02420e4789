"""Loop closure between frozen submaps: a wide correlative search of one submap's spline
points against another's, then verification, because a wrong loop closure is worse than
none.

The matching is the front end's scan matcher (:class:`~bsslam.frontend.scan_matcher.ReferenceMap`:
likelihood fields, coarse-to-fine correlative search, robust point-to-line Gauss–Newton)
with a wide window; the query submap plays the scan, the reference submap the map. The
points are sampled on the splines, so their normals are exact.

A match is accepted only if all of these hold (``LoopMatch.reason`` names the first that
fails):

- ``too_few_points``: either submap has too few points to match;
- ``too_little_overlap``: the query points that, after alignment, lie within
  ``loop_overlap_distance_m`` of a reference point (the overlap: the two submaps share only
  part of their walls) and within ``loop_inlier_distance_m`` (inliers) cover less than
  ``loop_min_overlap_m`` of wall;
- ``poor_inlier_fraction``: inliers / overlapping points < ``loop_min_inlier_fraction``;
- ``degenerate``: the information leaves a direction nearly free (a corridor, an arc);
- ``ambiguous``: a distinct alignment (``loop_distinct_m`` / ``loop_distinct_rad`` away,
  and beyond the 99 % region of the match's own covariance: a slide along a corridor the
  walls leave free is the same answer) within the window scores more than
  ``loop_max_ambiguity`` × the best when the pose graph expects the match and not that
  rival, ``loop_max_ambiguity_alone`` × the best otherwise (repetitive structure). Only
  the window is searched: a copy of the structure outside it is not seen, so the window
  must cover the relative pose's real uncertainty. With ``loop_slides`` a rival joined to
  the match by a ridge of the same score (every pose on the line between them scores above
  the bound: a slide along straight walls the refinement's covariance holds too tightly) is
  no rival: the match is kept as a *slide*, its covariance widened along that line
  (:func:`slide_covariance`), and the best alignment beyond the widened region is held to
  the same bound;
- ``incompatible``: the spline associations are not jointly compatible: fewer than two of
  the query's overlapping curves, or fewer than two thirds of them, agree with the
  alignment on their own (a match carried by one wall; a near-symmetric building matched
  turned round, where the outer walls agree and the inner ones do not).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from bsslam.chi2 import chi2_quantile
from bsslam.config import FrontendConfig, SubmapConfig
from bsslam.errors import InputError
from bsslam.frontend.scan_matcher import ReferenceMap, even_subset, transform_points, voxel_thin
from bsslam.se2 import squared_mahalanobis
from bsslam.spline import BSplineCurve
from bsslam.trajectory import wrap_angle

#: Reasons a match is rejected (``LoopMatch.reason``); "ok" otherwise.
REJECT_REASONS = ("too_few_points", "too_little_overlap", "poor_inlier_fraction", "degenerate", "ambiguous",
                  "incompatible")

#: A query curve takes part in the joint-compatibility vote when this much of it (m)
#: overlaps the reference: shorter pieces are too short to agree or disagree.
MIN_CURVE_OVERLAP_M = 1.0
#: … and at least this fraction of the voting curves must agree with the alignment.
MIN_AGREEING_FRACTION = 2.0 / 3.0
#: Radius of curvature (m) below which a sampled point is not used as a line in the
#: point-to-line refinement (the refinement's gate is ~0.15–0.3 m).
MIN_LINE_RADIUS_M = 1.0
#: χ²(3) at 99 %: an alternative alignment within this Mahalanobis distance² of the
#: match (under its covariance) is not a rival.
_ADMITTED_CHI2 = chi2_quantile(0.99, 3)
#: Dense samples per point spacing when the curves are resampled by arc length.
_DENSE_PER_SPACING = 8


@dataclass(frozen=True)
class SubmapShape:
    """What matching needs of a frozen submap, in its own frame.

    Attributes:
        points: (k, 2) points sampled every ``spacing_m`` of arc length along its curves (m).
        normals: (k, 2) unit normals (the tangents turned by +90°), exact from the curves.
        curvature: (k,) signed curvature of the curves at the points (1/m).
        curve_index: (k,) index of the curve each point lies on.
        sigma: (k,) how well the place of that curve is known in the submap's frame (m;
            :attr:`~bsslam.slam.MapSpline.position_sigma`), 0 where not given.
        center: (2,) centre of a circle enclosing all points (the bounding box's centre, m).
        radius: its radius (m).
        length_m: total curve length (m).
        spacing_m: the sampling spacing (m).
    """

    points: np.ndarray
    normals: np.ndarray
    curvature: np.ndarray
    curve_index: np.ndarray
    sigma: np.ndarray
    center: np.ndarray
    radius: float
    length_m: float
    spacing_m: float

    @classmethod
    def from_curves(cls, curves: list[BSplineCurve], spacing_m: float,
                    sigmas: list[float] | np.ndarray | None = None) -> SubmapShape:
        """Sample ``curves`` every ``spacing_m`` (m) of arc length (each from its start, so
        a curve shorter than the spacing gives one point); ``sigmas`` (one per curve, m):
        how well each curve's place is known in the submap (default 0)."""
        if not spacing_m > 0:
            raise InputError("spacing_m must be > 0")
        sigmas = np.zeros(len(curves)) if sigmas is None else np.asarray(sigmas, dtype=float).reshape(-1)
        if sigmas.shape[0] != len(curves) or not np.all(np.isfinite(sigmas) & (sigmas >= 0)):
            raise InputError("sigmas must be one finite σ ≥ 0 per curve")
        pts, nrm, kap, idx, total = [], [], [], [], 0.0
        # One pass per curve (a submap has tens of curves); within a curve all is vectorised.
        for i, curve in enumerate(curves):
            a, b = curve.domain
            dense_n = max(2, int(math.ceil(_DENSE_PER_SPACING * (b - a) / spacing_m)) + 1)
            t = np.linspace(a, b, dense_n)
            d1 = curve.evaluate(t, 1)
            speed = np.hypot(d1[:, 0], d1[:, 1])
            # Arc length by the trapezoid rule on the dense samples (knot units are ~m of
            # arc length already, so 8 samples per spacing resolve it to ≪ spacing).
            s = np.concatenate(([0.0], np.cumsum(0.5 * (speed[1:] + speed[:-1]) * np.diff(t))))
            length = float(s[-1])
            total += length
            targets = np.arange(0.0, length + 1e-12, spacing_m)
            tq = np.interp(targets, s, t)
            der = curve.derivatives(tq, 2)
            tangent = der[1] / np.maximum(np.hypot(der[1][:, 0], der[1][:, 1]), 1e-300)[:, None]
            sp = np.hypot(der[1][:, 0], der[1][:, 1])
            cross = der[1][:, 0] * der[2][:, 1] - der[1][:, 1] * der[2][:, 0]
            pts.append(der[0])
            nrm.append(np.column_stack((-tangent[:, 1], tangent[:, 0])))
            kap.append(cross / np.maximum(sp ** 3, 1e-300))
            idx.append(np.full(tq.shape[0], i, dtype=np.intp))
        if not pts:
            z = np.zeros((0, 2))
            return cls(z, z.copy(), np.zeros(0), np.zeros(0, dtype=np.intp), np.zeros(0), np.zeros(2), 0.0, 0.0,
                       spacing_m)
        points = np.concatenate(pts)
        index = np.concatenate(idx)
        lo, hi = points.min(axis=0), points.max(axis=0)
        center = 0.5 * (lo + hi)
        radius = float(np.max(np.hypot(*(points - center).T)))
        return cls(points, np.concatenate(nrm), np.concatenate(kap), index, sigmas[index], center, radius,
                   total, float(spacing_m))


@dataclass(frozen=True)
class LoopMatch:
    """The outcome of matching a query submap against a reference submap.

    Attributes:
        ok: the match passed every check (a loop closure to add to the pose graph).
        reason: "ok" or the first check failed (:data:`REJECT_REASONS`).
        relative: (3,) pose of the query submap's frame in the reference submap's frame
            (x m, y m, φ rad); the guess when no alignment was computed.
        covariance: (3, 3) its covariance (m², m·rad, rad²), in the reference frame, from
            the refinement's information alone (not the guess), × ``loop_covariance_inflation``,
            plus (``loop_wall_covariance``) what the matched walls' own places in their
            submaps add (:func:`matched_walls_covariance`).
        inlier_fraction: inliers / overlapping query points, in [0, 1].
        overlap_m: length of matched wall (inliers × spacing, m).
        ambiguity: the best distinct alternative's (``alternative``'s) correlative score /
            the best's (0 when the window holds no distinct pose beyond the match's
            covariance region; above 1 only when the tie-break towards the guess chose the
            lower of two near-equal peaks).
        information_ratio: smallest / largest eigenvalue of the scaled information.
        curves_overlapping: query curves with at least :data:`MIN_CURVE_OVERLAP_M` of overlap.
        curves_agreeing: of which those that agree with the alignment on their own.
        correlation: the best fine correlative score (mean likelihood, in [0, 1]).
        alternative: (3,) the best distinct alternative alignment.
        expected: the alignment lies within the 99 % region of the guess under its
            covariance (the pose graph expects it); False when no alignment was computed.
        slide: kept although its runner-up scored above the ambiguity bound, the two
            joined by a ridge of that score (``loop_slides``; its covariance widened along
            it, and ``alternative`` and ``ambiguity`` then the best alignment beyond it).
    """

    ok: bool
    reason: str
    relative: np.ndarray
    covariance: np.ndarray
    inlier_fraction: float = 0.0
    overlap_m: float = 0.0
    ambiguity: float = 1.0
    information_ratio: float = 0.0
    curves_overlapping: int = 0
    curves_agreeing: int = 0
    correlation: float = 0.0
    alternative: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    expected: bool = False
    slide: bool = False


def matcher_config(window_m: float, window_rad: float, config: SubmapConfig,
                   base: FrontendConfig = FrontendConfig()) -> FrontendConfig:
    """The scan matcher's parameters for a loop-closure search: ``base`` with the window
    (clipped to what the correlative search admits: the rotation to just under ±π, which
    the fine level's ±1 coarse step then covers), the point budgets, and the loop
    closure's covariance inflation (which weighs the points against the guess)."""
    window_rad = min(float(window_rad), math.pi - base.coarse_step_rad)
    return dataclasses.replace(base, search_window_m=float(window_m), search_window_rad=window_rad,
                               max_scan_points=config.loop_refine_points, search_points=config.loop_search_points,
                               covariance_inflation=config.loop_covariance_inflation)


def match_submaps(reference: SubmapShape, query: SubmapShape, guess: np.ndarray, guess_covariance: np.ndarray,
                  window_m: float, window_rad: float, config: SubmapConfig) -> LoopMatch:
    """Align ``query`` to ``reference`` by a correlative search of ±``window_m`` (m) in x
    and y and ±``window_rad`` (rad) around ``guess`` (3,) (the query frame's pose in the
    reference frame), refine, and verify (see the module docstring).

    Args:
        guess_covariance: (3, 3) positive-definite covariance of the guess: the
            refinement's weak prior (it decides nothing the walls fix); not part of the
            returned covariance.
        window_m, window_rad: the search's half-widths (m, rad); at most
            ``MAX_LOOP_WINDOW_M`` (18 m); a rotation window of π or more searches all
            headings.

    Returns:
        :class:`LoopMatch`; only ``ok`` matches are loop closures.
    """
    guess = np.asarray(guess, dtype=float).reshape(3)
    guess_covariance = np.asarray(guess_covariance, dtype=float).reshape(3, 3)
    if not (np.all(np.isfinite(guess)) and np.all(np.isfinite(guess_covariance))):
        raise InputError("guess and guess_covariance must be finite")
    cfg = matcher_config(window_m, window_rad, config)

    def reject(reason: str, relative: np.ndarray = guess, **extra) -> LoopMatch:
        return LoopMatch(False, reason, np.array(relative, dtype=float), guess_covariance.copy(), **extra)

    linear = np.abs(reference.curvature) < 1.0 / MIN_LINE_RADIUS_M
    if reference.points.shape[0] < cfg.min_points or query.points.shape[0] < cfg.min_points:
        return reject("too_few_points")
    ref = ReferenceMap(reference.points, cfg, normals=reference.normals, linear=linear)
    if not ref.usable:
        return reject("too_few_points")

    # The matcher's own thinning (one point per voxel, then an even subset), done here so
    # that the correlative search and its runner-up see the same points.
    pts = query.points[voxel_thin(query.points, cfg.scan_voxel_m)]
    pts = pts[even_subset(pts.shape[0], cfg.max_scan_points)]
    search = pts[even_subset(pts.shape[0], cfg.search_points)]
    coarse = ref.coarse_scores(search, guess)     # the best's and the runner-up's search share it
    start, correlation = ref.correlative(search, guess, coarse)
    pose, info, residuals, weights, _ = ref.refine(pts, start, guess, np.linalg.inv(guess_covariance))

    # Covariance: the residual σ the larger of the stated and the estimated one, inflated.
    found = np.isfinite(residuals)
    r, w = residuals[found], weights[found]
    if r.shape[0] < cfg.min_points:          # nothing of the reference near the query
        return reject("too_little_overlap", pose, correlation=correlation)
    sigma2_hat = float(np.sum(w * r * r)) / max(1.0, float(np.sum(w)) - 3.0)
    sigma2 = max(cfg.range_sigma_m ** 2, sigma2_hat) * config.loop_covariance_inflation
    # Rotation in metres of arc at the query's radius, so the eigenvalues are comparable.
    scale = np.array([1.0, 1.0, 1.0 / max(query.radius, 1.0)])
    eig = np.linalg.eigvalsh(info * np.outer(scale, scale))
    info_ratio = float(max(eig[0], 0.0) / max(eig[2], 1e-300))
    try:
        covariance = np.linalg.inv(info / sigma2) if eig[0] > 0 else np.full((3, 3), np.inf)
    except np.linalg.LinAlgError:
        covariance = np.full((3, 3), np.inf)
    covariance = 0.5 * (covariance + covariance.T)

    # Overlap and inliers over all query points (not only those matched), by the distance
    # to the nearest reference point.
    moved = transform_points(pose, query.points)
    dist, near = cKDTree(reference.points).query(moved, distance_upper_bound=config.loop_overlap_distance_m)
    close = dist <= config.loop_overlap_distance_m
    near = np.where(close, near, 0)
    # A point beside a reference curve overlaps it; one beyond a curve's end, along its
    # line, is a wall the reference did not see that far (occlusion, range), which neither
    # confirms nor contradicts the alignment.
    offset = moved - reference.points[near]
    along = np.abs(offset[:, 0] * reference.normals[near, 1] - offset[:, 1] * reference.normals[near, 0])
    overlapping = close & (along <= max(reference.spacing_m, config.loop_inlier_distance_m))
    inlier = overlapping & (dist <= config.loop_inlier_distance_m)
    n_over, n_in = int(np.count_nonzero(overlapping)), int(np.count_nonzero(inlier))
    fraction = n_in / n_over if n_over else 0.0
    overlap_m = n_in * query.spacing_m

    # Joint compatibility: each overlapping query curve on its own.
    n_curves = int(query.curve_index.max()) + 1
    over_c = np.bincount(query.curve_index, weights=overlapping, minlength=n_curves)
    in_c = np.bincount(query.curve_index, weights=inlier, minlength=n_curves)
    voting = over_c * query.spacing_m >= MIN_CURVE_OVERLAP_M
    agree = voting & (in_c >= config.loop_min_inlier_fraction * over_c)
    n_voting, n_agree = int(np.count_nonzero(voting)), int(np.count_nonzero(agree))

    # The rival is sought beyond the region the match's covariance admits: an alignment
    # inside it (a slide along a corridor) is the same answer, and taking it as the rival
    # would hide a farther copy (the next bay of a facade) behind it.
    admitted = None
    if np.all(np.isfinite(covariance)):
        admitted = (pose, np.linalg.inv(covariance), _ADMITTED_CHI2)
    alternative, alt_score = ref.alternative(search, guess, start, config.loop_distinct_m, config.loop_distinct_rad,
                                             coarse, admitted)
    ambiguity = alt_score / correlation if correlation > 0 else 1.0

    expected = squared_mahalanobis(pose, guess, guess_covariance) <= _ADMITTED_CHI2
    result = dict(inlier_fraction=fraction, overlap_m=overlap_m, ambiguity=ambiguity, information_ratio=info_ratio,
                  curves_overlapping=n_voting, curves_agreeing=n_agree, correlation=correlation,
                  alternative=alternative, expected=expected)
    if overlap_m < config.loop_min_overlap_m:
        return reject("too_little_overlap", pose, **result)
    if fraction < config.loop_min_inlier_fraction:
        return reject("poor_inlier_fraction", pose, **result)
    if info_ratio < config.loop_min_information_ratio or not np.all(np.isfinite(covariance)):
        return reject("degenerate", pose, **result)
    # the graph tells the match from its rival when it expects the one and not the other;
    # otherwise the walls alone must
    def bound(rival: np.ndarray) -> float:
        told = expected and squared_mahalanobis(rival, guess, guess_covariance) > _ADMITTED_CHI2
        return config.loop_max_ambiguity if told else config.loop_max_ambiguity_alone

    slide = False
    if ambiguity > bound(alternative):
        # a slide moves along the walls: a rival distinct by its heading alone is no slide
        along = math.hypot(*_step(pose, alternative)[:2]) > config.loop_distinct_m
        if not (config.loop_slides and along
                and on_ridge(ref, search, pose, alternative, bound(alternative) * correlation)):
            return reject("ambiguous", pose, **result)
        slide = True
        covariance = covariance + slide_covariance(pose, alternative, window_m)
        # the slide is one answer; the rival is now the best alignment beyond it (a copy
        # of the walls elsewhere, e.g. the next corridor), held to the same test
        alternative, alt_score = ref.alternative(search, guess, start, config.loop_distinct_m,
                                                 config.loop_distinct_rad, coarse,
                                                 (pose, np.linalg.inv(covariance), _ADMITTED_CHI2))
        ambiguity = alt_score / correlation if correlation > 0 else 1.0
        result.update(ambiguity=ambiguity, alternative=alternative)
        if ambiguity > bound(alternative):
            return reject("ambiguous", pose, **result)
    if n_agree < 2 or n_agree < MIN_AGREEING_FRACTION * n_voting:
        return reject("incompatible", pose, **result)
    if config.loop_wall_covariance:
        # after the ambiguity test: that asks whether the alignment is unique, not where
        # the walls are
        covariance = covariance + matched_walls_covariance(reference.sigma[near[inlier]], query.sigma[inlier],
                                                           moved[inlier])
    return LoopMatch(True, "ok", pose, covariance, slide=slide, **result)


def on_ridge(ref: ReferenceMap, points: np.ndarray, pose: np.ndarray, rival: np.ndarray, floor: float) -> bool:
    """Whether every pose on the straight line from ``pose`` to ``rival`` (3,) (heading
    interpolated the short way round), close enough that no point moves more than one fine
    cell from one to the next, puts ``points`` (n, 2, the query's, its own frame) at a mean
    likelihood of at least ``floor`` in ``ref``'s fine field: the two are one answer slid
    along walls, not two copies of them."""
    step = _step(pose, rival)
    reach = float(np.max(np.hypot(points[:, 0], points[:, 1]))) if points.shape[0] else 0.0
    travel = math.hypot(step[0], step[1]) + abs(step[2]) * reach
    n = max(2, int(math.ceil(travel / ref.fine.resolution)) + 1)
    line = pose[None, :] + np.linspace(0.0, 1.0, n)[:, None] * step[None, :]
    scores = ref.fine.score_poses(points, line, np.zeros((1, 2), dtype=np.intp))[:, 0]
    return bool(np.all(scores >= floor))


def _step(pose: np.ndarray, rival: np.ndarray) -> np.ndarray:
    """(3,) ``rival − pose`` (x, y m in the reference frame; the heading wrapped)."""
    step = np.asarray(rival, dtype=float) - pose
    step[2] = wrap_angle(step[2])
    return step


def slide_covariance(pose: np.ndarray, rival: np.ndarray, window_m: float) -> np.ndarray:
    """(3, 3) what a slide adds to its match's covariance: σ² u uᵀ along the line u (per
    metre of translation, its heading change included) from ``pose`` to ``rival`` (3,),
    σ the larger of their distance and the search window's half-width ``window_m`` (m):
    the walls say nothing along the ridge, and it may run on to the window's edge."""
    step = _step(pose, rival)
    distance = math.hypot(step[0], step[1])
    if distance == 0.0:
        return np.zeros((3, 3))
    u = step / distance
    return max(distance, float(window_m)) ** 2 * np.outer(u, u)


def matched_walls_covariance(reference_sigma: np.ndarray, query_sigma: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(3, 3) what the matched walls' own uncertainty adds to a loop closure's covariance.

    The alignment fixes the query's walls on the reference's *as each submap mapped them*;
    the loop closure relates the submaps' bases, and a wall's place relative to its base is
    known only to its σ (mostly the local filter's drift when it saw the wall). The
    alignment's covariance, which weighs every point as an independent measurement, leaves
    that out: in simulation loop closures 0.12 m off carried σ of 1 cm. Walls seen
    together drift together, so the σ are not averaged down by their number: the variance
    added is the mean of the reference's plus the mean of the query's (m²) in x and y, and
    the same displacement over the matched walls' lever arm in heading (rad²).

    Args:
        reference_sigma: (n,) σ (m) of the reference wall under each matched point.
        query_sigma: (n,) σ (m) of the query wall each matched point lies on.
        points: (n, 2) the matched points (m), for the lever arm: their RMS distance from
            their centroid, at least 1 m.
    """
    if points.shape[0] == 0:
        return np.zeros((3, 3))
    variance = float(np.mean(reference_sigma ** 2) + np.mean(query_sigma ** 2))
    lever2 = max(float(np.mean(np.sum((points - points.mean(axis=0)) ** 2, axis=1))), 1.0)
    return variance * np.diag([1.0, 1.0, 1.0 / lever2])
