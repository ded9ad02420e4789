"""The measurement model: laser ranges against the map's splines (paper §III-D, spec §6).

A beam assigned to a map spline measures the distance from the laser, along the beam, to
where the spline crosses it. :class:`RangeModel` takes the matched intervals of a scan to
the beams (:meth:`RangeModel.beams`) and linearises those at a state mean into the stacked
``(cols, H, residual, R)`` an :class:`~bsslam.slam.estimator.Estimator` updates with
(:meth:`RangeModel.linearize`); :meth:`RangeModel.select` keeps the rows the gates pass.
The range and its Jacobians (22)–(27) are computed by one compiled call over all the beams'
splines (:meth:`bsslam.slam.map_curves.MapCurves.linearize`); the numpy form it replaced is
the tests' oracle (``tests/slam/observation_oracle.py``).

The laser sits at ``laser_offset`` (x m, y m, φ rad) in the robot frame. For a beam with
bearing τ the world beam angle is μ = φ + φ_o + τ and the beam starts at
``p_l = t_r + R(φ) o``. The predicted range z is where the spline, moved into the beam
frame, crosses the beam's x-axis. With the tangent ratio ``r = x̃'(t*)/ỹ'(t*)``:

* ∂z/∂p_l = g = (−cos μ − r sin μ, −sin μ + r cos μ);
* ∂z/∂μ = z·r, so ∂z/∂φ = z·r + g·R'(φ)·o (the lever arm of an offset laser);
* ∂z/∂(x_i, y_i) = −β_i(t*)·g — moving the curve by δ is moving the sensor by −δ.

These are (22)–(27) of the paper; tests check them against finite differences.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from scipy.linalg import solve_triangular

from bsslam.config import ObservationConfig
from bsslam.scan import ObservedSpline
from bsslam.slam import beam_kernels, bend_kernels, range_kernels
from bsslam.slam.bends import spline_bends, wall_angle_weight
from bsslam.slam.association import Match
from bsslam.se2 import compose
from bsslam.slam.map_curves import MapCurves


def laser_pose(robot_pose: np.ndarray, laser_offset: np.ndarray) -> np.ndarray:
    """World pose (3,) of the laser mounted at ``laser_offset`` on a robot at ``robot_pose``:
    their composition, the heading not wrapped (the beam angles μ = φ + φ_o + τ are formed
    from it as the compiled kernels form them)."""
    return compose(robot_pose, laser_offset, wrap=False)


@dataclass(frozen=True, eq=False)
class Beams:
    """The beams of one scan assigned to map splines, each (k,).

    Attributes:
        curve: index of each beam's map spline in the filter's :class:`MapCurves` table.
        bearings: robot-frame bearings (rad); ranges: measured ranges (m);
        t0: Newton start on the map spline (m).
        second_order: (k, k) the covariance of the beams' second-order errors under the
            state's spread (m²), or None (:meth:`RangeModel.with_second_order`).
    """

    curve: np.ndarray
    bearings: np.ndarray
    ranges: np.ndarray
    t0: np.ndarray
    second_order: np.ndarray | None = None

    @functools.cached_property
    def used_curves(self) -> np.ndarray:
        """The distinct map splines of the beams (increasing)."""
        return range_kernels.used_curves(self.curve)


@dataclass(frozen=True)
class Linearization:
    """Stacked ranges and Jacobian of the beams of one scan at one estimate.

    Attributes:
        cols: (c,) touched state indices (the pose's 0, 1, 2 first); H_c: (m, c) the
            Jacobian on them; residual: (m,) z − h(x) (m); with a bearing σ both rows
            scaled so that each has variance R (:meth:`RangeModel.linearize`); R: the
            ranges' noise, r for R = r I (m²);
        beam: (m,) the beam (index into the linearised :class:`Beams`) of each row;
        hit_t: (m,) map-spline parameter of each hit (m).
    """

    cols: np.ndarray
    H_c: np.ndarray
    residual: np.ndarray
    R: float
    beam: np.ndarray
    hit_t: np.ndarray

    def with_rows(self, cols: np.ndarray, H_c: np.ndarray) -> Linearization:
        """The same beams with the Jacobian H_c (m, c') on ``cols`` (c',) instead (a
        constrained or scaled one): ``dataclasses.replace`` at under half its cost (0.9 µs
        against 2.0), which counts at several calls a scan."""
        return Linearization(cols, H_c, self.residual, self.R, self.beam, self.hit_t)


@dataclass(frozen=True)
class AlongLimits:
    """What the walls of one linearisation may say along themselves (:meth:`RangeModel.along_limits`).

    Attributes:
        labels, weights: (L,) the splines whose rows are scaled along their own mean
            tangent, and their weights w ∈ [0, 1) (a bend within its noise: 0).
        walls: (K,) every spline of the rows (all in the state) when the scan's weakest
            direction is weighed, else None; wall_noise: N = Σ_j I_j Var(ψ_j), what those
            walls, were they parallel, would say along it through their directions' noise
            (dimensionless · rad², as Σ g gᵀ's eigenvalues).
    """

    labels: np.ndarray
    weights: np.ndarray
    walls: np.ndarray | None = None
    wall_noise: float = 0.0


def bearing_derivatives(H_c: np.ndarray, ranges_predicted: np.ndarray, beam_angles: np.ndarray) -> np.ndarray:
    """(m,) ∂z/∂τ of m beams (m/rad): how a beam's predicted range moves with its bearing.

    The range depends on the bearing only through the beam angle μ, and ∂z/∂μ = z·r (the
    module docstring), r = x̃'/ỹ' the tangent ratio (tan of the incidence). The first two
    columns of a beam's Jacobian are g = ∂z/∂p_l = (−cos μ − r sin μ, −sin μ + r cos μ),
    so r = −g_x sin μ + g_y cos μ, whatever the laser's offset.

    Args:
        H_c: (m, c) the beams' Jacobians, the robot's x and y first (the standard ones,
            before an estimator's change of coordinates).
        ranges_predicted: (m,) predicted ranges z (m); beam_angles: (m,) world μ (rad).
    """
    r = -H_c[:, 0] * np.sin(beam_angles) + H_c[:, 1] * np.cos(beam_angles)
    return ranges_predicted * r


class Drops(Protocol):
    """Where dropped beams are counted (:class:`~bsslam.slam.filter.StepReport`)."""

    def drop(self, reason: str, count: int) -> None: ...


class MeasurementModel(Protocol):
    """From a scan's matched beams to the stacked linearisation an estimator updates with."""

    def beams(self, observed: list[ObservedSpline], matches: list[list[Match]], curves: MapCurves) -> Beams | None:
        """The beams of the matched intervals; None when there are none."""

    def linearize(self, beams: Beams, curves: MapCurves, x: np.ndarray, laser_offset: np.ndarray,
                  drops: Drops | None = None) -> Linearization | None:
        """The beams linearised at the state mean ``x``; None when no beam is left."""

    def select(self, beams: Beams, lin: Linearization, keep: np.ndarray) -> tuple[Beams, Linearization]:
        """The beams and their rows restricted to ``keep`` (m,) bool."""

    def whitened(self, beams: Beams, lin: Linearization) -> Linearization:
        """The rows with noise ``lin.R``·I that carry the same information as ``lin`` with
        its full noise (``lin`` itself when its beams are independent)."""


class RangeModel:
    """The ray–spline range model. Each beam's range error is its own, of variance
    R = (σ_range² + σ_model²)·inflation, plus (∂z/∂τ σ_bearing)²·inflation from its bearing
    τ (:func:`bearing_derivatives`; the rows are rescaled to variance R, see
    :meth:`linearize`), plus one shared by every beam of the scan on the same map spline, of
    variance σ_shared²·inflation (m²): the beams of one wall are not independent where the
    wall is not where its spline says or the laser is biased on that surface; with
    ``observation.second_order``, plus the ranges' second-order error under the state's spread
    (:meth:`with_second_order`). Implements :class:`MeasurementModel`.

    Args:
        config: the observation settings (noise, beam stride, grazing limit).

    Attributes:
        R: the independent variance (m²); shared: the shared one (m²);
        bearing_variance: σ_bearing²·inflation (rad²);
        row_variance: a beam's whole variance R + shared (m²), what its gates weigh.
    """

    def __init__(self, config: ObservationConfig):
        self.significant_bends_only = config.significant_bends_only
        self.significant_wall_angles = config.significant_wall_angles
        self.second_order = config.second_order
        self.R = (config.sigma_range_m ** 2 + config.sigma_model_m ** 2) * config.r_inflation
        self.shared = config.sigma_shared_m ** 2 * config.r_inflation
        self.bearing_variance = config.sigma_bearing_rad ** 2 * config.r_inflation
        self.row_variance = self.R + self.shared
        self.stride = config.beam_stride
        self.max_tan = math.tan(config.max_incidence_rad)

    def beams(self, observed: list[ObservedSpline], matches: list[list[Match]], curves: MapCurves) -> Beams | None:
        """The beams of the matched intervals, each with its map spline (its index in
        ``curves``, which only ``curves.index`` is read of) and Newton start; a beam inside
        several matched intervals goes to the first (by ``u_ini``).

        The matches and the matched splines' beams go to one compiled call
        (:func:`beam_kernels.beam_groups`) as a table and one array: a loop over them here
        was about a hundred numpy calls a scan."""
        table = [(i, obs.params.shape[0], m.u_ini, m.u_fin, m.t_ini, m.t_fin, curves.index[m.feature_id])
                 for i, (obs, obs_matches) in enumerate(zip(observed, matches)) for m in obs_matches]
        if not table:
            return None
        beams = np.concatenate([a for obs, obs_matches in zip(observed, matches) if obs_matches
                                for a in (obs.params, obs.angles, obs.ranges)])
        curve, values = beam_kernels.beam_groups(np.array(table, dtype=float), beams, self.stride)
        if curve.shape[0] == 0:
            return None
        return Beams(curve, values[0], values[1], values[2])

    def linearize(self, beams: Beams, curves: MapCurves, x: np.ndarray, laser_offset: np.ndarray,
                  drops: Drops | None = None) -> Linearization | None:
        """Predicted ranges and the stacked Jacobian of every beam at the estimate ``x``, in
        one compiled call over all the beams' map splines (:meth:`MapCurves.linearize`).

        Beams that miss their spline or hit it at grazing incidence are dropped (and
        counted when ``drops`` is given). Returns None when no beam is left.

        With a bearing σ each row j (its Jacobian and residual) is multiplied by
        √(R / (R + σ_τ² (∂z_j/∂τ)²)): the rows then have the one variance R the
        compressed update needs (a diagonal R would cost a factorisation of S) and carry
        exactly the information of the beams with their own variances; the gates, which
        compare a row's residual with its variance, weigh each beam by its own.
        """
        cols, H_c, residual, rows, hit_t, missed, grazing = curves.linearize(
            x, laser_offset, beams.curve, beams.bearings, beams.ranges, beams.t0, self.max_tan)
        if drops is not None:
            drops.drop("missed", missed)
            drops.drop("grazing", grazing)
        if rows.size == 0:
            return None
        if self.bearing_variance > 0.0:
            scale = self._bearing_scale(beams, rows, H_c, residual, x, laser_offset)
            H_c, residual = H_c * scale[:, None], residual * scale
        return Linearization(cols, H_c, residual, self.R, rows, hit_t)

    def _bearing_scale(self, beams: Beams, rows: np.ndarray, H_c: np.ndarray, residual: np.ndarray,
                       x: np.ndarray, laser_offset: np.ndarray) -> np.ndarray:
        """(m,) √(R / (R + σ_τ² (∂z/∂τ)²)) of the rows of an unscaled linearisation
        (``rows`` their beams, ``H_c`` and ``residual`` as the range model gives them at
        ``x``): what :meth:`linearize` multiplies each row by."""
        dz_dtau = bearing_derivatives(H_c, ranges_predicted=beams.ranges[rows] - residual,
                                      beam_angles=x[2] + laser_offset[2] + beams.bearings[rows])
        return np.sqrt(self.R / (self.R + self.bearing_variance * dz_dtau ** 2))

    def select(self, beams: Beams, lin: Linearization, keep: np.ndarray) -> tuple[Beams, Linearization]:
        """The beams and their linearisation restricted to the rows in ``keep``, Newton
        restarted from the rows' last hit parameters (one compiled call for the copies)."""
        index, values, H_c = beam_kernels.select_rows(keep, lin.beam, beams.curve, beams.bearings, beams.ranges,
                                                      lin.H_c, lin.residual, lin.hit_t)
        second = None
        if self.second_order and beams.second_order is not None:
            kept = lin.beam[keep]
            second = beams.second_order[np.ix_(kept, kept)]
        return (Beams(index[0], values[0], values[1], values[2], second),
                Linearization(lin.cols, H_c, values[3], lin.R, index[1], values[4]))

    def with_second_order(self, beams: Beams, curves: MapCurves, x: np.ndarray, laser_offset: np.ndarray,
                          covariance: np.ndarray, work: np.ndarray,
                          curvature: Callable[[np.ndarray, np.ndarray], np.ndarray | None] | None = None) -> Beams:
        """``beams`` with their ranges' second-order error under the state's spread P,
        ½ tr(∇²h_i P ∇²h_j P) between every two beams (:attr:`Beams.second_order`), which
        :meth:`whitened` adds to their noise (``observation.second_order``).

        A range depends on the pose and on the p + 1 control points of the piece it hits
        only: its Hessian is (3 + 2(p+1))² on those variables. Each is a central difference
        of the beams' Jacobians between x ± one σ of P along the variable (the Hessian
        where the range is quadratic, its average over the spread where it is not), and
        one step serves every beam at once: the pose's three entries, then the x (and the
        y) coordinates of every (p+1)-th control point, which puts exactly one control
        point of each piece's window in each step. A beam the range model loses at
        a step counts 0 along it. The pairs' traces then read P only on the two beams'
        variables. Each beam's error is scaled by the factor :meth:`linearize` scales its
        row by for its bearing's σ at x (the row's second-order error scales with the row).

        Args:
            beams: the beams to linearise (b of them); curves: the map's table.
            x: (n,) the state mean; laser_offset: (3,) the laser in the robot frame.
            covariance: (w, w) P, on the state entries ``work`` (w,) (the pose and the
                beams' splines' control points: all the ranges depend on); the filter
                passes its first gain's posterior there (:meth:`SplineSLAM._update`).
            curvature: the estimator's error coordinates' own second-order terms,
                ``curvature(index, G)`` → (b', L, L) or None, for the variables ``index``
                (b', L) (−1: none) of the b' beams that hit at x and their gradients G
                (b', L) there (:meth:`Estimator.error_curvature`); the Hessians are then
                those along the estimator's error, not along x − x̂. None: x − x̂.
        """
        n_beams = beams.ranges.shape[0]
        block = np.zeros((n_beams, n_beams))
        bearing_variance, self.bearing_variance = self.bearing_variance, 0.0   # the ranges' own Hessian, unscaled
        try:
            lin = self.linearize(beams, curves, x, laser_offset)
            if lin is None:
                return dataclasses.replace(beams, second_order=block)
            index, local, hessians = self._local_hessians(beams, lin, curves, x, laser_offset, covariance, work)
        finally:
            self.bearing_variance = bearing_variance
        if curvature is not None:
            place = np.full(x.shape[0], -1, dtype=np.intp)
            place[lin.cols] = np.arange(lin.cols.shape[0])
            G = np.where(index >= 0, np.take_along_axis(lin.H_c, place[np.maximum(index, 0)], axis=1), 0.0)
            extra = curvature(index, G)
            if extra is not None:
                hessians += extra
        if bearing_variance > 0.0:
            hessians *= self._bearing_scale(beams, lin.beam, lin.H_c, lin.residual, x, laser_offset)[:, None, None]
        block[np.ix_(lin.beam, lin.beam)] = beam_kernels.half_pair_traces(hessians @ covariance[local], local)
        return dataclasses.replace(beams, second_order=block)

    def _local_hessians(self, beams: Beams, lin: Linearization, curves: MapCurves, x: np.ndarray,
                        laser_offset: np.ndarray, covariance: np.ndarray, work: np.ndarray
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(index (m, L), local (m, L), H (m, L, L))``: the variables of each of the m
        beams of ``lin`` (the pose, then its piece's control points' x, then their y; −1 for
        a padded or fixed one), their places in ``work`` (those of −1: any, their rows of H
        are zero) and its range's Hessian on them (1/m), symmetric; L = 3 + 2(p+1)."""
        table, p1 = curves.table, curves.table.p + 1
        piece, _, _ = table.locate(beams.curve[lin.beam], lin.hit_t)
        window = table.window[piece]                                     # (m, p+1) control-point rows
        rows_xy = curves.state_rows[window]                              # (m, p+1, 2)
        real = table.real[piece] & (rows_xy[:, :, 0] >= 0)
        m = lin.beam.shape[0]
        index = np.concatenate([np.broadcast_to(np.arange(3), (m, 3)),
                                np.where(real, rows_xy[:, :, 0], -1), np.where(real, rows_xy[:, :, 1], -1)], axis=1)
        # each variable's step: the pose's three, then the x and the y of every (p+1)-th row
        step_of = np.concatenate([np.broadcast_to(np.arange(3), (m, 3)), 3 + window % p1, 3 + p1 + window % p1],
                                 axis=1)
        sigma = np.zeros(x.shape[0])
        sigma[work] = np.sqrt(np.maximum(np.diag(covariance), 0.0))
        cp_rows = np.unique(window[real])
        members = [np.array([k]) for k in range(3)]
        for coord in range(2):
            for r in range(p1):
                members.append(curves.state_rows[cp_rows[cp_rows % p1 == r], coord])
        place = np.full(x.shape[0], -1, dtype=np.intp)
        place[work] = np.arange(work.shape[0])
        local = place[np.maximum(index, 0)]                              # (m, L) places in work
        H = np.zeros((m, index.shape[1], index.shape[1]))
        for s, entries in enumerate(members):
            entries = entries[sigma[entries] > 0.0]
            slots = (step_of == s) & (index >= 0) & (sigma[np.maximum(index, 0)] > 0.0)
            if entries.size == 0 or not slots.any():
                continue
            step = np.zeros_like(x)
            step[entries] = sigma[entries]
            plus = self._jacobian_rows(beams, curves, x + step, laser_offset, place, work.shape[0])[lin.beam]
            minus = self._jacobian_rows(beams, curves, x - step, laser_offset, place, work.shape[0])[lin.beam]
            diff = np.nan_to_num(0.5 * (plus - minus))                     # a beam lost at a step: 0
            beam, slot = np.nonzero(slots)
            H[beam, :, slot] = np.take_along_axis(diff, local, axis=1)[beam] / sigma[index[beam, slot]][:, None]
        H[index < 0] = 0.0
        H.transpose(0, 2, 1)[index < 0] = 0.0
        return index, local, 0.5 * (H + H.transpose(0, 2, 1))

    def _jacobian_rows(self, beams: Beams, curves: MapCurves, x: np.ndarray, laser_offset: np.ndarray,
                       place: np.ndarray, width: int) -> np.ndarray:
        """(b, w) each beam's Jacobian at ``x`` on the working entries (``place``: each
        state index's column, −1 off them); NaN rows for the beams the model drops."""
        out = np.full((beams.ranges.shape[0], width), np.nan)
        lin = self.linearize(beams, curves, x, laser_offset)
        if lin is not None:
            at = place[lin.cols]
            rows = np.zeros((lin.beam.shape[0], width))
            rows[:, at[at >= 0]] = lin.H_c[:, at >= 0]
            out[lin.beam] = rows
        return out

    def whitened(self, beams: Beams, lin: Linearization) -> Linearization:
        """``lin`` with its rows whitened against the shared errors
        (:func:`beam_kernels.whiten_shared`, one group per map spline), so that the rows with
        noise R·I give the update, NIS and gains of the block noise; with the beams'
        second-order block (:meth:`with_second_order`) their error ½ tr(∇²h_i P ∇²h_j P)
        joins that noise. ``lin`` itself when there is neither. Gate on the rows of ``lin`` with
        :attr:`row_variance`: a whitened row is no longer one beam."""
        if self.second_order and beams.second_order is not None:
            return self._whitened_full(beams, lin)
        if self.shared == 0.0:
            return lin
        H_c, residual = beam_kernels.whiten_shared(beams.curve[lin.beam], self.shared / self.R, lin.H_c, lin.residual)
        return dataclasses.replace(lin, H_c=H_c, residual=residual)

    def _whitened_full(self, beams: Beams, lin: Linearization) -> Linearization:
        """:meth:`whitened` with the second-order error: R = r I + the shared block + the
        beams' :attr:`Beams.second_order` block, whitened by its Cholesky factor (a dense (m, m)
        factorisation)."""
        ratio = beams.second_order[np.ix_(lin.beam, lin.beam)] / self.R
        if self.shared:
            group = beams.curve[lin.beam]
            ratio += (self.shared / self.R) * (group[:, None] == group[None, :])
        ratio[np.diag_indices_from(ratio)] += 1.0
        L = np.linalg.cholesky(ratio)
        H_c = solve_triangular(L, lin.H_c, lower=True)
        residual = solve_triangular(L, lin.residual, lower=True)
        return dataclasses.replace(lin, H_c=H_c, residual=residual)

    def along_limits(self, beams: Beams, lin: Linearization, curves: MapCurves, x: np.ndarray,
                     variances_of) -> AlongLimits | None:
        """How much of what the rows of ``lin`` say along their walls their bends support
        (:mod:`bsslam.slam.bends`), for :meth:`limit_along_splines`; None when neither
        ``observation.significant_bends_only`` nor ``observation.significant_wall_angles``
        is on, or neither applies.

        ``variances_of(state_indices (k,), rows (g, k))`` gives the prior variances (g,) of
        linear functions of the state (a covariance window's); it is asked once, for the
        bends of the splines with two hits or more (at ``x``, between the extreme hits of
        ``lin``'s rows) and for the scan's walls' directions relative to one another (each
        wall's mean tangent angle at its two extreme hits less their mean weighted by what
        each wall's rows weigh). The scan's weakest direction and its weight need the rows
        as the bends scale them, so :meth:`limit_along_splines` finds them."""
        bends, walls = self.significant_bends_only, self.significant_wall_angles
        if not (bends or walls):
            return None
        table = curves.table
        group = beams.curve[lin.beam]
        labels, t_first, t_last, count, info = bend_kernels.hit_groups(
            group, lin.hit_t, lin.H_c, curves.state_rows[table.cp_start[:-1], 0])
        # walls of localisation mode are exact: their angles are information, nothing to weigh
        walls = walls and labels.shape[0] >= 2 and int(count.sum()) == group.shape[0]
        bent = count >= 2 if bends else np.zeros(labels.shape[0], dtype=bool)
        if not (walls or bent.any()):
            return None
        if not walls:
            labels, t_first, t_last = labels[bent], t_first[bent], t_last[bent]
            bent = np.ones(labels.shape[0], dtype=bool)
        bend, rows, grad = spline_bends(table, curves.control_points(x), labels, t_first, t_last)
        g = labels.shape[0]
        # every control point of the splines, not only those the two tangents move: the
        # OC-EKF's constraint on a row depends on the columns it is given
        union = curves.state_indices(labels, x.shape[0])
        index, grad = curves.state_rows[rows].reshape(g, -1), grad.reshape(g, -1)
        variances = variances_of(union, bend_kernels.along_rows(union, index, grad, bent, info, walls))
        n_bent = int(np.count_nonzero(bent))    # the bends' rows first, then the walls'
        weights = bend_kernels.bend_weights(bend[bent], variances[:n_bent])
        scaled = weights < 1.0
        return AlongLimits(labels[bent][scaled], weights[scaled],
                           labels if walls else None, float(info @ variances[n_bent:]) if walls else 0.0)

    def limit_along_splines(self, beams: Beams, lin: Linearization, curves: MapCurves,
                            limits: AlongLimits | None) -> Linearization:
        """``lin`` with each spline's rows scaled along the spline by its weight, then every
        row scaled along the scan's weakest direction by the walls' angles' weight
        (:meth:`along_limits`, :func:`bsslam.slam.bends.wall_angle_weight`; ``lin`` itself
        when neither applies); compiled: :func:`bend_kernels.scale_along_splines`,
        :func:`bend_kernels.scale_along_direction`."""
        if limits is None:
            return lin
        H_c, group = lin.H_c.copy(), beams.curve[lin.beam]
        if limits.labels.shape[0]:
            bend_kernels.scale_along_splines(H_c, lin.cols, group, limits.labels, limits.weights, curves.state_rows,
                                             curves.table.cp_start)
        if limits.walls is not None:
            e, w = wall_angle_weight(H_c, limits.wall_noise)
            if w < 1.0:
                bend_kernels.scale_along_direction(H_c, lin.cols, group, limits.walls, e, w, curves.state_rows,
                                                   curves.table.cp_start)
        return lin.with_rows(lin.cols, H_c)
