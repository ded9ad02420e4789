"""Data association of observed splines with map splines (spec §4, paper §III-B, Fig. 6).

Both curves are in the world frame (the observed one moved there with the current pose
estimate). A match gives corresponding parameter intervals ``[u_ini, u_fin]`` on the
observed spline and ``[t_ini, t_fin]`` on the map spline; whatever lies beyond a map
spline's end is a candidate for extending it.

All pairs of a scan are decided together: the observed and the map splines come as
:class:`~bsslam.spline.batch.CurveBatch` es, and each step of Fig. 6 (gates, closest
points of the observed ends, re-query at a map end, the final distance test) is one call
over every (observed, map) pair, not a Python loop over pairs. The closest points are the
batched searches of :mod:`bsslam.spline.batch`; the steps between them are compiled loops
over the pairs (:mod:`bsslam.slam.kernels`), bit-identical to the numpy form they replaced
and a fraction of its numpy call overhead.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bsslam.slam import kernels
from bsslam.spline.batch import CurveBatch, closest_points_batch


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

    def map_parameter(self, u: np.ndarray) -> np.ndarray:
        """Initial guess (linear between the matched ends) of the map parameter for u."""
        scale = (self.t_fin - self.t_ini) / (self.u_fin - self.u_ini)
        return self.t_ini + (np.asarray(u) - self.u_ini) * scale


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
    lever = points - pose[:2]
    k = points.shape[0]
    J = np.zeros((k, 2, 3))
    J[:, 0, 0] = J[:, 1, 1] = 1.0
    J[:, 0, 2], J[:, 1, 2] = -lever[:, 1], lever[:, 0]
    own = np.einsum("kab,bc,kac->k", J, pose_covariance, J)
    coupled = np.einsum("kab,bfa->kf", J, cross)                          # tr(J P_pc)
    return np.sqrt(np.maximum(own[:, None] - 2.0 * coupled + map_variance[None, :], 0.0))


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
    to, tm = observed.table, mapped.table
    k = to.n_curves
    result: list[list[Match]] = [[] for _ in range(k)]
    candidates = np.asarray(candidates, dtype=np.intp)
    if k == 0 or candidates.size == 0:
        return result
    obs = (observed.coeffs_t, to.piece_lo, to.piece_start, to.lo, to.hi)
    maps = (mapped.coeffs_t, tm.piece_lo, tm.piece_start, tm.lo, tm.hi)
    # bounding boxes, then control points within the gate; the observed ends of those pairs
    pairs, end_points, curves = kernels.gated_pairs(observed.control_points, to.cp_start, *obs,
                                                    mapped.control_points, tm.cp_start, candidates,
                                                    _per_pair(gate_m, k, candidates.size))
    if curves.size == 0:
        return result
    # Closest map points to both ends of each observed spline: (2P,) parameters, pair by pair.
    t_ends = closest_points_batch(mapped, curves, end_points)[0]
    # where that is the map spline's end, the correspondence starts there instead, at the
    # observed point closest to it
    map_end, requeried = kernels.map_end_queries(t_ends, pairs, curves, *maps)
    u_requeried = closest_points_batch(observed, requeried, map_end)[0] if requeried.size else np.empty(0)
    # opposite orientation (far side of a wall) or no overlap, then the distance test
    values, labels, at_end = kernels.accepted_pairs(t_ends, u_requeried, pairs, curves,
                                                    np.asarray(feature_ids, dtype=np.intp),
                                                    _per_pair(match_distance_m, k, candidates.size), *obs, *maps)
    # one Match per accepted pair (a handful per scan), already in each curve's u_ini order
    for (i, fid), (u_ini, u_fin, t_ini, t_fin), (lo_end, hi_end) in zip(labels.tolist(), values.tolist(),
                                                                        at_end.tolist()):
        result[i].append(Match(fid, u_ini, u_fin, t_ini, t_fin, at_lo=lo_end, at_hi=hi_end))
    return result
