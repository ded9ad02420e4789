"""The ranges' second-order error under the prior, ½ tr(∇²h_i P ∇²h_j P), in its first,
plain form: every beam's Hessian in the prior's principal axes S (P = S Sᵀ) by central
differences of the Jacobian at x ± s_k along each axis, and the invariant EKF's curvature
written in those axes. The library computes it on each beam's own variables
(:meth:`bsslam.slam.measurement.RangeModel.with_second_order`); this is its oracle. So is
:func:`half_pair_traces`, the numpy form of the compiled pairs' traces."""

from __future__ import annotations

import numpy as np

from bsslam.slam.invariant_ekf import HEADING, InvariantEKF
from bsslam.slam.map_curves import MapCurves
from bsslam.slam.measurement import Beams, RangeModel


def jacobian_rows(model: RangeModel, beams: Beams, curves: MapCurves, x: np.ndarray, laser_offset: np.ndarray,
                  work: np.ndarray) -> np.ndarray:
    """(b, w) each beam's unscaled Jacobian at ``x`` on ``work``; NaN rows for lost beams."""
    place = np.full(x.shape[0], -1, dtype=np.intp)
    place[work] = np.arange(work.shape[0])
    out = np.full((beams.ranges.shape[0], work.shape[0]), np.nan)
    bearing_variance, model.bearing_variance = model.bearing_variance, 0.0
    try:
        lin = model.linearize(beams, curves, x, laser_offset)
    finally:
        model.bearing_variance = bearing_variance
    if lin is not None:
        at = place[lin.cols]
        rows = np.zeros((lin.beam.shape[0], work.shape[0]))
        rows[:, at[at >= 0]] = lin.H_c[:, at >= 0]
        out[lin.beam] = rows
    return out


def invariant_curvature(est: InvariantEKF, work: np.ndarray, G: np.ndarray, S: np.ndarray) -> np.ndarray:
    """(b, K, K) the invariant error's second-order terms in the axes S (w, K) of x − x̂
    for gradients G (b, w) on ``work``: ``c u_φk u_φl + T_k u_φl + T_l u_φk`` with
    u = A⁻¹ S, c = −Σ_p g_p · p̂ and T = Σ_p (Jᵀ g_p / 2) · u_p."""
    at = int(np.flatnonzero(work == HEADING)[0])
    sign = est._sign[work]
    place = np.full(est.size, -1, dtype=np.intp)
    place[work] = np.arange(work.shape[0])
    mate = place[est._mate[work]]
    U = S - np.outer(est.turn(est.x, work), S[at])
    phi = U[at]
    position = sign != 0
    c = -(G[:, position] @ est.x[work[position]])
    half_jt_g = -0.5 * sign * G[:, np.where(position, mate, 0)]
    T = half_jt_g @ U
    return c[:, None, None] * np.outer(phi, phi)[None] + T[:, :, None] * phi[None, None, :] + phi[None, :, None] * T[:, None, :]


def second_order_block(model: RangeModel, beams: Beams, curves: MapCurves, x: np.ndarray,
                       laser_offset: np.ndarray, prior: np.ndarray, work: np.ndarray,
                       est: InvariantEKF | None = None) -> np.ndarray:
    """(b, b) ½ F Fᵀ, F's rows Sᵀ ∇²h_i S (+ the invariant curvature with ``est``), each
    row times the factor the model scales the beam's row by for its bearing σ (m²)."""
    lam, V = np.linalg.eigh(0.5 * (prior + prior.T))
    axes = lam > 1e-12 * max(float(lam[-1]), 0.0)
    S = V[:, axes] * np.sqrt(lam[axes])
    b, k = beams.ranges.shape[0], S.shape[1]
    hessian_s = np.zeros((b, k, work.shape[0]))
    for j in range(k):
        step = np.zeros_like(x)
        step[work] = S[:, j]
        plus = jacobian_rows(model, beams, curves, x + step, laser_offset, work)
        minus = jacobian_rows(model, beams, curves, x - step, laser_offset, work)
        both = ~(np.isnan(plus[:, 0]) | np.isnan(minus[:, 0]))
        hessian_s[both, j] = 0.5 * (plus[both] - minus[both])
    rows = hessian_s @ S
    rows = 0.5 * (rows + rows.transpose(0, 2, 1))
    if est is not None:
        G = jacobian_rows(model, beams, curves, x, laser_offset, work)
        hit = ~np.isnan(G[:, 0])
        rows[hit] += invariant_curvature(est, work, G[hit], S)
    lin = model.linearize(beams, curves, x, laser_offset)
    exact = jacobian_rows(model, beams, curves, x, laser_offset, work)
    scale = np.ones(b)
    if lin is not None:
        at = np.searchsorted(work, lin.cols[0])   # the pose's x column: a row's scale is its ratio there
        scale[lin.beam] = lin.H_c[:, 0] / exact[lin.beam, at]
    F = rows.reshape(b, k * k) * scale[:, None]
    return 0.5 * F @ F.T


def half_pair_traces(Y: np.ndarray, local: np.ndarray) -> np.ndarray:
    """(m, m) ½ Σ_ac Y[i, a, L_j c] Y[j, c, L_i a] for Y (m, L, w) and ``local`` (m, L), as
    numpy: every pair's products gathered at once, (m L)² of them."""
    X = Y[:, :, local]                                   # (m, L, m, L): Y_i[a, L_j c]
    return 0.5 * np.einsum("iajc,jcia->ij", X, X)
