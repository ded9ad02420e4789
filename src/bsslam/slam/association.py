"""Data association of observed splines with map splines (spec §4, paper §III-B, Fig. 6).

Both curves are in the world frame (the observed one moved there with the current pose
estimate). A match gives corresponding parameter intervals ``[u_ini, u_fin]`` on the
observed spline and ``[t_ini, t_fin]`` on the map spline; whatever lies beyond a map
spline's end is a candidate for extending it.

All pairs of a scan are decided together: the observed and the map splines come as
:class:`~bsslam.spline.batch.CurveBatch` es, and each step of Fig. 6 (gates, closest
points of the observed ends, re-query at a map end, the final distance test) is one
vectorised computation over every (observed, map) pair, not a loop over pairs.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

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


def _ragged(counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For groups of ``counts`` (k,) items: each item's group (Σ,) and its position in it (Σ,)."""
    owner = np.repeat(np.arange(counts.shape[0]), counts)
    return owner, np.arange(owner.shape[0]) - np.repeat(np.cumsum(counts) - counts, counts)


def control_point_gaps(a: CurveBatch, b: CurveBatch, ia: np.ndarray, ib: np.ndarray) -> np.ndarray:
    """(k,) smallest distance between a control point of curve ``ia[j]`` of ``a`` and one of
    curve ``ib[j]`` of ``b`` (m), for k pairs."""
    ta, tb = a.table, b.table
    na = ta.cp_start[ia + 1] - ta.cp_start[ia]
    nb = tb.cp_start[ib + 1] - tb.cp_start[ib]
    pair, local = _ragged(na * nb)                 # every (point of a, point of b) of every pair
    ra = ta.cp_start[ia][pair] + local // nb[pair]
    rb = tb.cp_start[ib][pair] + local % nb[pair]
    d = a.control_points[ra] - b.control_points[rb]
    d2 = np.einsum("ij,ij->i", d, d)
    return np.sqrt(np.minimum.reduceat(d2, np.cumsum(na * nb) - na * nb))


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


def _at_end(t: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Whether parameters t are at the lower / upper end of domains [lo, hi] (same shapes)."""
    tol = 1e-6 * np.maximum(1.0, hi - lo)
    return t <= lo + tol, t >= hi - tol


def _per_pair(value, k: int, f: int) -> np.ndarray:
    """A threshold given as one value, (k,) per observed spline or (k, f) per pair, as (k, f)."""
    a = np.asarray(value, dtype=float)
    return np.broadcast_to(a[:, None] if a.ndim == 1 else a, (k, f))


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
    result: list[list[Match]] = [[] for _ in range(k)]
    candidates = np.asarray(candidates, dtype=np.intp)
    if k == 0 or candidates.size == 0:
        return result
    gates = _per_pair(gate_m, k, candidates.size)
    deltas = _per_pair(match_distance_m, k, candidates.size)
    ob = observed.bboxes()[:, None, :]                       # (k, 1, 4)
    mb = mapped.bboxes()[candidates][None, :, :]             # (1, F, 4)
    # bounding boxes farther apart than the gate cannot pass it; then the control points
    near = ~((mb[..., 0] - ob[..., 2] > gates) | (ob[..., 0] - mb[..., 2] > gates) |
             (mb[..., 1] - ob[..., 3] > gates) | (ob[..., 1] - mb[..., 3] > gates))
    io, jf = np.nonzero(near)                                # pairs, observed-major
    im = candidates[jf]
    if io.size:
        close = control_point_gaps(observed, mapped, io, im) <= gates[io, jf]
        io, jf, im = io[close], jf[close], im[close]
    if io.size == 0:
        return result
    # Closest map points to both ends of each observed spline: (P, 2) parameters.
    to, tm = observed.table, mapped.table
    u_ends = np.column_stack([to.lo[io], to.hi[io]])
    obs2, map2 = np.repeat(io, 2), np.repeat(im, 2)
    end_points = observed.evaluate(obs2, u_ends.ravel())[0]
    t_ends = closest_points_batch(mapped, map2, end_points)[0].reshape(-1, 2)
    lo_m, hi_m = tm.lo[im][:, None], tm.hi[im][:, None]
    at_lo, at_hi = _at_end(t_ends, lo_m, hi_m)
    requery = at_lo | at_hi
    if requery.any():
        # the observed end lies beyond the map spline: the correspondence starts at the map
        # spline's end instead, at the observed point closest to it
        map_end = mapped.evaluate(map2[requery.ravel()], t_ends[requery])[0]
        u_ends[requery] = closest_points_batch(observed, obs2[requery.ravel()], map_end)[0]
    # opposite orientation (far side of a wall) or no overlap, then the distance test
    ordered = (t_ends[:, 1] > t_ends[:, 0]) & (u_ends[:, 1] > u_ends[:, 0])
    gap = observed.evaluate(obs2, u_ends.ravel())[0] - mapped.evaluate(map2, t_ends.ravel())[0]
    gap = np.hypot(gap[:, 0], gap[:, 1]).reshape(-1, 2).max(axis=1)
    accepted = np.flatnonzero(ordered & (gap <= deltas[io, jf]))
    for p in accepted:  # one Match per accepted pair (a handful per scan)
        result[io[p]].append(Match(int(feature_ids[im[p]]), float(u_ends[p, 0]), float(u_ends[p, 1]),
                                   float(t_ends[p, 0]), float(t_ends[p, 1]),
                                   at_lo=bool(at_lo[p, 0]), at_hi=bool(at_hi[p, 1])))
    for matches in result:
        matches.sort(key=lambda m: m.u_ini)
    return result
