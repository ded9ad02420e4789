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


def _decide(observed: BSplineCurve, mapped: BSplineCurve, feature_id: int, match_distance_m: float,
            t_ends: np.ndarray, u_ends: np.ndarray) -> Match | None:
    """Fig. 6 of the paper for one pair, given the map parameters ``t_ends`` (2,) closest to
    the observed spline's ends and the observed parameters ``u_ends`` (2,) to use for them
    (the observed ends, or — where ``t`` is an end of the map spline — the observed point
    closest to that map end)."""
    lo_m, hi_m = mapped.domain
    tol = 1e-6 * max(1.0, hi_m - lo_m)
    t_ini, t_fin = float(t_ends[0]), float(t_ends[1])
    u_ini, u_fin = float(u_ends[0]), float(u_ends[1])
    if not (t_fin > t_ini and u_fin > u_ini):
        return None  # opposite orientation (far side of a wall) or no overlap
    gap = observed.evaluate(np.array([u_ini, u_fin])) - mapped.evaluate(np.array([t_ini, t_fin]))
    if np.max(np.hypot(gap[:, 0], gap[:, 1])) > match_distance_m:
        return None
    return Match(feature_id, u_ini, u_fin, t_ini, t_fin, at_lo=t_ini <= lo_m + tol, at_hi=t_fin >= hi_m - tol)


def _at_end(t: np.ndarray, curve: BSplineCurve) -> np.ndarray:
    lo, hi = curve.domain
    tol = 1e-6 * max(1.0, hi - lo)
    return (t <= lo + tol) | (t >= hi - tol)


def _match_many(observed: list[BSplineCurve], mapped: BSplineCurve, feature_id: int,
                match_distance_m: np.ndarray) -> list[Match | None]:
    """Fig. 6 of the paper for several observed splines against one map spline (None where
    a pair does not match), with one closest-point query for all their end points."""
    ends = np.vstack([o.evaluate(np.array(o.domain)) for o in observed])          # (2k, 2)
    t_ends, _, _ = closest_point(mapped, ends)
    t_ends = t_ends.reshape(-1, 2)
    requery = _at_end(t_ends, mapped)                                             # (k, 2)
    map_ends = mapped.evaluate(t_ends[requery]) if requery.any() else np.empty((0, 2))
    out, used = [], 0
    for i, obs in enumerate(observed):
        u_ends = np.array(obs.domain, dtype=float)
        n_q = int(requery[i].sum())
        if n_q:
            # the observed end lies beyond the map spline: the correspondence starts at the map
            # spline's end instead, at the observed point closest to it
            u_new, _, _ = closest_point(obs, map_ends[used:used + n_q])
            u_ends[requery[i]] = u_new
            used += n_q
        out.append(_decide(obs, mapped, feature_id, float(match_distance_m[i]), t_ends[i], u_ends))
    return out


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
    gates = np.broadcast_to(np.asarray(gate_m, dtype=float), (len(observed),))
    deltas = np.broadcast_to(np.asarray(match_distance_m, dtype=float), (len(observed),))
    obs_boxes = [o.bbox() for o in observed]
    result: list[list[Match]] = [[] for _ in observed]
    for fid, curve in mapped.items():
        b = curve.bbox()
        # bounding boxes farther apart than the gate cannot pass it; then the control points
        near = [i for i, ob in enumerate(obs_boxes)
                if not (b[0] - ob[2] > gates[i] or ob[0] - b[2] > gates[i] or
                        b[1] - ob[3] > gates[i] or ob[1] - b[3] > gates[i])
                and control_point_gap(observed[i], curve) <= gates[i]]
        if not near:
            continue
        for i, m in zip(near, _match_many([observed[i] for i in near], curve, fid, deltas[near])):
            if m is not None:
                result[i].append(m)
    for matches in result:
        matches.sort(key=lambda m: m.u_ini)
    return result
