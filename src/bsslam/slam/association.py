"""Data association of observed splines with map splines (spec §4, paper §III-B, Fig. 6).

Both curves are in the world frame (the observed one moved there with the current pose
estimate). A match gives corresponding parameter intervals ``[u_ini, u_fin]`` on the
observed spline and ``[t_ini, t_fin]`` on the map spline; whatever lies beyond a map
spline's end is a candidate for extending it.

All pairs of a scan are decided together: the observed and the map splines come as
:class:`~bsslam.spline.batch.CurveBatch` es, and each step of Fig. 6 (gates, closest
points of the observed ends, re-query at a map end, the final distance test) is one call
over every (observed, map) pair, not a Python loop over pairs, and all the steps are one
compiled call (:func:`bsslam.slam.kernels.match_pairs`: the closest points are the
batched searches of :mod:`bsslam.spline.batch`, their compiled steps called from it),
bit-identical to the numpy form they replaced and a fraction of its numpy call overhead.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bsslam.slam import kernels
from bsslam.spline.batch import CurveBatch, CurveTable
from bsslam.spline.batch import _CLOSEST_MAX_NEWTON, _CLOSEST_STEP_TOLERANCE, MAX_SAMPLES_PER_SPAN

#: The closest-point searches' sampling (closest_points_batch's defaults, which association
#: has always used): largest arc length between samples (m), fewest samples per piece.
_SAMPLE_STEP_M = 0.1
_SAMPLES_PER_SPAN = 4


@dataclass(frozen=True)
class Match:
    """Correspondence between an observed spline and a map spline.

    Attributes:
        feature_id: id of the map spline.
        u_ini, u_fin: matched interval on the observed spline (its parameter, m).
        t_ini, t_fin: the corresponding interval on the map spline (its parameter, m).
        at_lo, at_hi: the match reaches the map spline's lower / upper domain end, so the
            observed spline may extend it there.
    """

    feature_id: int
    u_ini: float
    u_fin: float
    t_ini: float
    t_fin: float
    at_lo: bool
    at_hi: bool


def control_point_gaps(a: CurveBatch, b: CurveBatch, ia: np.ndarray, ib: np.ndarray) -> np.ndarray:
    """(k,) smallest distance between a control point of curve ``ia[j]`` of ``a`` and one of
    curve ``ib[j]`` of ``b`` (m), for k pairs."""
    return kernels.control_point_gaps(a.control_points, a.table.cp_start, b.control_points, b.table.cp_start,
                                      np.asarray(ia, dtype=np.intp), np.asarray(ib, dtype=np.intp))


def relative_sigma(pose: np.ndarray, pose_covariance: np.ndarray, points: np.ndarray, cross: np.ndarray,
                   map_variance: np.ndarray) -> np.ndarray:
    """(k, F) σ (m) of the offset between k points seen from the robot and F map control
    points, for gating: √trace of its 2×2 covariance.

    A point seen from the robot moves with the pose, J = ∂p/∂(x, y, φ); a control point is
    its own state entries. The offset's covariance J P_pp Jᵀ − J P_pc − P_cp Jᵀ + P_cc keeps
    the cross terms, so a wall mapped from the recent, equally drifted poses is close to the
    robot in this measure, however far both are from where the filter started.

    Args:
        pose: (3,) robot pose (m, m, rad); pose_covariance: (3, 3) P_pp.
        points: (k, 2) world points that move rigidly with the pose (m).
        cross: (3, F, 2) P_pc, the pose's covariance with each control point's x and y
            (zeros for a fixed point).
        map_variance: (F,) trace of each control point's 2×2 block P_cc (m²; 0 if fixed).
    """
    J = kernels.point_jacobians(np.asarray(pose, dtype=float), np.asarray(points, dtype=float))
    return kernels.offset_sigma(*_pose_terms(J, pose_covariance, cross), np.asarray(map_variance, dtype=float))


def _pose_terms(J: np.ndarray, pose_covariance: np.ndarray, cross: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """tr(J P_pp Jᵀ) (k,) and tr(J P_pc) (k, F) for point Jacobians J (k, 2, 3): einsum's
    sums, in numpy (a compiled loop would add the terms in its own order)."""
    return (np.einsum("kab,bc,kac->k", J, pose_covariance, J),
            np.einsum("kab,bfa->kf", J, cross))


def association_thresholds(J: np.ndarray, pose_covariance: np.ndarray, cross: np.ndarray, map_diagonal: np.ndarray,
                           near: np.ndarray, sigmas: float, match_m: float, max_match_m: float,
                           gate_m: float) -> np.ndarray:
    """(2, k, F) control-point gate and match distance (m) of each (observed, candidate)
    pair, grown by ``sigmas`` σ of :func:`relative_sigma` (the match distance capped at
    ``max_match_m``).

    Args:
        J: (k, 2, 3) pose Jacobians of the observed points (:func:`kernels.point_jacobians`).
        pose_covariance, cross: as :func:`relative_sigma` (``cross`` zero where fixed).
        map_diagonal: (2F,) variances of each candidate's control point's x and y (m²);
            near: (F, 2) their state rows, −1 where fixed (then no variance).
    """
    return kernels.association_thresholds(*_pose_terms(J, pose_covariance, cross), map_diagonal, near,
                                          float(sigmas), float(match_m), float(max_match_m), float(gate_m))


def _per_pair(value, k: int, f: int) -> np.ndarray:
    """A threshold given as one value, (k,) per observed spline or (k, f) per pair, as a
    (k, f) C-contiguous array (the compiled steps read it pair by pair)."""
    a = np.asarray(value, dtype=float)
    if a.shape == (k, f):       # the filter's case
        return np.ascontiguousarray(a)
    out = np.empty((k, f))
    out[...] = a[:, None] if a.ndim == 1 else a
    return out


def associate(observed: CurveBatch, mapped: CurveBatch, feature_ids: np.ndarray, candidates: np.ndarray,
              gate_m, match_distance_m) -> list[list[Match]]:
    """Match every observed spline against the candidate map splines (Fig. 6 of the paper).

    Args:
        observed: the k observed splines, world frame.
        mapped: the map splines (world frame).
        feature_ids: (C,) feature id of each curve of ``mapped``.
        candidates: indices of the curves of ``mapped`` to try (the robot's surroundings).
        gate_m: δ_mincp, the cheap control-point gate (m): one value, (k,) one per observed
            spline, or (k, len(candidates)) one per pair.
        match_distance_m: δ_match (m): shaped like ``gate_m``.
    Returns:
        for each observed spline, its matches sorted by ``u_ini``.
    """
    k = observed.table.n_curves
    candidates = np.asarray(candidates, dtype=np.intp)
    if k == 0 or candidates.size == 0:
        return [[] for _ in range(k)]
    return associate_curves(observed.table, observed.control_points, observed.coeffs_t, mapped.table,
                            mapped.control_points, mapped.coeffs_t, np.asarray(feature_ids, dtype=np.intp), candidates,
                            _per_pair(gate_m, k, candidates.size), _per_pair(match_distance_m, k, candidates.size))


def associate_curves(observed: CurveTable, observed_cp: np.ndarray, observed_coeffs_t: np.ndarray, mapped: CurveTable,
                     mapped_cp: np.ndarray, mapped_coeffs_t: np.ndarray, feature_ids: np.ndarray,
                     candidates: np.ndarray, gates: np.ndarray, deltas: np.ndarray) -> list[list[Match]]:
    """:func:`associate` on the curves' tables, control points (N, 2) and coefficients
    (p+1, 2, S) (as :attr:`CurveBatch.coeffs_t`), without building the batches: the filter
    has the arrays. ``feature_ids`` (C,) and ``candidates`` (F,) are intp arrays, ``gates``
    and ``deltas`` (k, F) C-contiguous (m); F > 0.

    Every step of Fig. 6 (gates, closest points of the observed ends, re-query at a map
    end, the final distance test) is one compiled call (:func:`kernels.match_pairs`)."""
    to, tm = observed, mapped
    values, labels, at_end = kernels.match_pairs(
        observed_cp, to.cp_start, observed_coeffs_t, to.window, to.piece_lo, to.width, to.piece_start, to.lo, to.hi,
        mapped_cp, tm.cp_start, mapped_coeffs_t, tm.window, tm.piece_lo, tm.width, tm.piece_start, tm.lo, tm.hi,
        candidates, feature_ids, gates, deltas, _SAMPLE_STEP_M, _SAMPLES_PER_SPAN, MAX_SAMPLES_PER_SPAN,
        _CLOSEST_MAX_NEWTON, _CLOSEST_STEP_TOLERANCE)
    result: list[list[Match]] = [[] for _ in range(to.n_curves)]
    # one Match per accepted pair (a handful per scan), already in each curve's u_ini order
    for (i, fid), (u_ini, u_fin, t_ini, t_fin), (lo_end, hi_end) in zip(labels.tolist(), values.tolist(),
                                                                        at_end.tolist()):
        result[i].append(Match(fid, u_ini, u_fin, t_ini, t_fin, at_lo=lo_end, at_hi=hi_end))
    return result
