"""Data association of observed splines with map splines (spec §4, paper §III-B, Fig. 6).

Both curves are in the world frame (the observed one moved there with the current pose
estimate). A match gives corresponding parameter intervals ``[u_ini, u_fin]`` on the
observed spline and ``[t_ini, t_fin]`` on the map spline; whatever lies beyond a map
spline's end is a candidate for extending it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bsslam.spline import BSplineCurve, closest_point


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


def control_point_gap(a: BSplineCurve, b: BSplineCurve) -> float:
    """Smallest distance between a control point of ``a`` and one of ``b`` (m)."""
    d = a.control_points[:, None, :] - b.control_points[None, :, :]
    return float(np.sqrt(np.min(np.einsum("ijk,ijk->ij", d, d))))


def match_pair(observed: BSplineCurve, mapped: BSplineCurve, feature_id: int,
               match_distance_m: float) -> Match | None:
    """Fig. 6 of the paper for one (observed, map) pair; None when they do not match."""
    lo_o, hi_o = observed.domain
    lo_m, hi_m = mapped.domain
    tol = 1e-6 * max(1.0, hi_m - lo_m)
    ends_o = observed.evaluate(np.array([lo_o, hi_o]))
    t_ends, _, _ = closest_point(mapped, ends_o)
    t_ini, t_fin = float(t_ends[0]), float(t_ends[1])
    at_lo_ini, at_hi_ini = t_ini <= lo_m + tol, t_ini >= hi_m - tol
    at_lo_fin, at_hi_fin = t_fin <= lo_m + tol, t_fin >= hi_m - tol
    u_ini, u_fin = lo_o, hi_o
    # When the observed end lies beyond the map spline, the correspondence starts at the map
    # spline's end instead: find the observed point closest to it.
    requery = []
    if at_lo_ini or at_hi_ini:
        requery.append(0)
    if at_lo_fin or at_hi_fin:
        requery.append(1)
    if requery:
        u_new, _, _ = closest_point(observed, mapped.evaluate(np.array([t_ends[i] for i in requery])))
        for i, u in zip(requery, u_new):
            if i == 0:
                u_ini = float(u)
            else:
                u_fin = float(u)
    if not (t_fin > t_ini and u_fin > u_ini):
        return None  # opposite orientation (far side of a wall) or no overlap
    pts = observed.evaluate(np.array([u_ini, u_fin])) - mapped.evaluate(np.array([t_ini, t_fin]))
    if np.max(np.hypot(pts[:, 0], pts[:, 1])) > match_distance_m:
        return None
    return Match(feature_id, u_ini, u_fin, t_ini, t_fin, at_lo=at_lo_ini, at_hi=at_hi_fin)


def associate(observed: list[BSplineCurve], mapped: dict[int, BSplineCurve], gate_m,
              match_distance_m) -> list[list[Match]]:
    """Match every observed spline against the candidate map splines.

    Args:
        observed: observed splines in the world frame.
        mapped: candidate map splines (already limited to the robot's surroundings) by id.
        gate_m: δ_mincp, the cheap control-point gate (m): one value, or one per observed spline.
        match_distance_m: δ_match (m): one value, or one per observed spline.
    Returns:
        for each observed spline, its matches sorted by ``u_ini``.
    """
    boxes = {fid: c.bbox() for fid, c in mapped.items()}
    gates = np.broadcast_to(np.asarray(gate_m, dtype=float), (len(observed),))
    deltas = np.broadcast_to(np.asarray(match_distance_m, dtype=float), (len(observed),))
    result: list[list[Match]] = []
    for obs, gate_m, match_distance_m in zip(observed, gates, deltas):
        ob = obs.bbox()
        matches = []
        for fid, curve in mapped.items():
            b = boxes[fid]
            # bounding boxes farther apart than the gate cannot pass it
            if (b[0] - ob[2] > gate_m or ob[0] - b[2] > gate_m or
                    b[1] - ob[3] > gate_m or ob[1] - b[3] > gate_m):
                continue
            if control_point_gap(obs, curve) > gate_m:
                continue
            m = match_pair(obs, curve, fid, match_distance_m)
            if m is not None:
                matches.append(m)
        matches.sort(key=lambda m: m.u_ini)
        result.append(matches)
    return result
