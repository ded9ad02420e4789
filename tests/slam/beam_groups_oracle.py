"""The numpy forms of the filter's beam bookkeeping as they were before they were compiled
into :func:`bsslam.slam.beam_kernels.beam_groups` and
:func:`bsslam.slam.beam_kernels.select_rows`: the oracles the kernels must match bit for
bit."""

from __future__ import annotations

import numpy as np


def map_parameter(match, u: np.ndarray) -> np.ndarray:
    """Initial guess (linear between the matched ends) of the map parameter for u (formerly
    ``Match.map_parameter``)."""
    scale = (match.t_fin - match.t_ini) / (match.u_fin - match.u_ini)
    return match.t_ini + (np.asarray(u) - match.u_ini) * scale


def beam_groups(observed, matches, index: dict, stride: int):
    """``(curve, bearings, ranges, t0)`` of the beams of the matched intervals, or None
    (formerly ``SplineSLAM._beam_groups``; ``index`` maps a feature id to its curve)."""
    parts = []
    for obs, obs_matches in zip(observed, matches):
        taken = np.zeros(obs.params.shape[0], dtype=bool)
        if stride > 1:
            taken[np.arange(obs.params.shape[0]) % stride != 0] = True
        for m in obs_matches:
            sel = ~taken & (obs.params >= m.u_ini) & (obs.params <= m.u_fin)
            if not sel.any():
                continue
            taken |= sel
            parts.append((np.full(int(sel.sum()), index[m.feature_id]), obs.angles[sel],
                          obs.ranges[sel], map_parameter(m, obs.params[sel])))
    if not parts:
        return None
    return tuple(np.concatenate(p) for p in zip(*parts))


def select_rows(keep, beam, curve, bearings, ranges, H_c, residual, hit_t):
    """The kept rows and their beams (formerly ``SplineSLAM._select``): the beams' curve,
    bearings, ranges and Newton starts, the rows' Jacobian, residuals, beam and hit
    parameters."""
    rows = beam[keep]
    return (curve[rows], bearings[rows], ranges[rows], hit_t[keep], H_c[keep], residual[keep],
            np.arange(rows.size), hit_t[keep])
