"""All map splines as one table of curves, for the filter's per-scan searches.

Association and the observation model query every map spline near the robot in one
compiled call each (:func:`bsslam.slam.kernels.association_frame`,
:func:`bsslam.slam.range_kernels.linearize_beams`), which read the knot structure
(:class:`~bsslam.spline.batch.CurveTable`) and the control points from the state mean (or
the fixed ones) and build the pieces' coefficients themselves. The knot structure changes
only when a spline is added, extended or removed, so the filter keeps it between scans and
updates it in place after such a change.
"""

from __future__ import annotations

import functools

import numpy as np

from bsslam.slam import range_kernels
from bsslam.slam.features import SplineFeature
from bsslam.slam.kernels import association_frame, curve_state_indices
from bsslam.spline.batch import CurveTable, concat_tables, curve_table, kept_rows, take_curves
from bsslam.spline.intersect import _MAX_NEWTON, _MAX_REFINE, _ROOT_TOLERANCE_M, _STEP_TOLERANCE, _unit_grid


class MapCurves:
    """The knot structure of a set of map features and where their control points live.

    Attributes:
        features: the features, in table order (curve c is ``features[c]``).
        ids: (C,) their ids.
        table: their :class:`~bsslam.spline.batch.CurveTable`.
        state_rows: (N, 2) state indices of each control point's x and y; −1 for the fixed
            control points of localisation mode.
    """

    def __init__(self, features: list[SplineFeature], table: CurveTable | None = None,
                 state_rows: np.ndarray | None = None, fixed: np.ndarray | None = None):
        self.features = list(features)
        self.ids = np.array([f.id for f in self.features], dtype=np.intp)
        self.index = {f.id: c for c, f in enumerate(self.features)}
        if table is None:
            table = curve_table([f.knots for f in self.features], [f.degree for f in self.features])
            state_rows, fixed = _rows_of(self.features)
        self.table = table
        self.state_rows = state_rows
        self._in_state = self.state_rows[:, 0] >= 0
        self._all_in_state = bool(self._in_state.all())
        self._fixed = fixed
        # a map that never moves (localisation in a fixed map): its control points are fixed
        self._static = not self._in_state.any()

    @property
    def fixed_control_points(self) -> np.ndarray:
        """(N, 2) the fixed control points (localisation mode) (m); zeros where in the state."""
        return self._fixed

    def with_added(self, features: list[SplineFeature]) -> MapCurves:
        """This table with new features appended after the current ones: only theirs is
        built (a map gains a spline every other scan, and rebuilding all of it cost 5 ms)."""
        degrees = [f.degree for f in features]
        if any(d != self.table.p for d in degrees):   # a different degree: pad everything again
            return MapCurves(self.features + list(features))
        rows, fixed = _rows_of(features)
        table = concat_tables(self.table, curve_table([f.knots for f in features], degrees))
        return MapCurves(self.features + list(features), table, np.vstack([self.state_rows, rows]),
                         np.vstack([self._fixed, fixed]))

    def with_replaced(self, feature: SplineFeature, table: CurveTable) -> MapCurves:
        """This table with ``feature`` (already in it, e.g. just extended) given new knots and
        state rows: ``table`` is its own one-curve table. The other curves' rows are kept
        (:meth:`_kept`) instead of built again."""
        c, C = self.index[feature.id], len(self.features)
        parts = [np.arange(c), np.arange(c + 1, C)]
        if table.p != self.table.p or any(k.size and self.table.degree[k].max() != self.table.p for k in parts):
            return MapCurves(self.features)   # a part without the padded degree: build anew
        seq = [self._kept(parts[0]) if parts[0].size else None, (table, *_rows_of([feature])),
               self._kept(parts[1]) if parts[1].size else None]
        seq = [p for p in seq if p is not None]
        joined = functools.reduce(concat_tables, [p[0] for p in seq])
        return MapCurves(self.features, joined, np.vstack([p[1] for p in seq]), np.vstack([p[2] for p in seq]))

    def without(self, removed_ids, mapping: np.ndarray | None) -> MapCurves | None:
        """This table less the features ``removed_ids``, the kept ones' rows taken out
        (:meth:`_kept`) instead of built again; ``mapping`` (old state index → new, from
        :meth:`JointState.remove`) renumbers the state rows. None when no feature is left."""
        keep = np.flatnonzero(~np.isin(self.ids, np.asarray(list(removed_ids), dtype=np.intp)))
        if keep.size == 0:
            return None
        features = [self.features[c] for c in keep]
        if int(self.table.degree[keep].max()) != self.table.p:   # the padding changes: build anew
            return MapCurves(features)
        table, rows, fixed = self._kept(keep)
        if mapping is not None:
            rows = np.where(rows >= 0, mapping[np.maximum(rows, 0)], -1)
        return MapCurves(features, table, rows, fixed)

    def _kept(self, curves: np.ndarray) -> tuple[CurveTable, np.ndarray, np.ndarray]:
        """The table (:func:`~bsslam.spline.batch.take_curves`), state rows and fixed control
        points of the curves ``curves`` (sorted indices, at least one of the padded degree)."""
        cp, _, _ = kept_rows(self.table.cp_start, curves)
        return take_curves(self.table, curves), self.state_rows[cp], self._fixed[cp]

    def state_indices(self, curves: np.ndarray, size: int) -> np.ndarray:
        """(k,) sorted state indices of the control points of ``curves`` (none for fixed ones),
        in a state of ``size`` entries (compiled: :func:`~bsslam.slam.kernels.curve_state_indices`)."""
        return curve_state_indices(self.state_rows, self.table.cp_start, np.asarray(curves, dtype=np.intp), size)

    def control_points(self, x: np.ndarray) -> np.ndarray:
        """(N, 2) stacked control points at the state mean ``x`` (m); do not modify them."""
        if self._static:
            return self._fixed
        cp = x[np.maximum(self.state_rows, 0)]
        if not self._all_in_state:
            cp = np.where(self._in_state[:, None], cp, self._fixed)
        return cp

    # -- the compiled searches on the table ---------------------------------------------
    def association_frame(self, cp: np.ndarray, world: np.ndarray, observed: CurveTable, laser_pose: np.ndarray,
                          radius2: float, pose: np.ndarray):
        """The candidate pairs of observed and map splines and what the association gates
        need of them, in one compiled call (:func:`~bsslam.slam.kernels.association_frame`).

        Args:
            cp: (N, 2) the map's control points (:meth:`control_points`) (m).
            world: (M, 2) the observed splines' control points in the world frame (m);
                observed: their table.
            laser_pose: (3,) (m, m, rad); radius2: squared map radius (m²); pose: (3,) the
                robot pose.
        Returns:
            ``(candidates, near, J, map_coeffs_t, world_coeffs_t)`` as the kernel gives them.
        """
        t = self.table
        return association_frame(cp, t.cp_start, t.power_basis, t.window, t.piece_start, self.state_rows, world,
                                 observed.cp_start, observed.power_basis, observed.window, observed.piece_start,
                                 laser_pose, radius2, pose)

    def linearize(self, x: np.ndarray, laser_offset: np.ndarray, curve: np.ndarray, bearings: np.ndarray,
                  ranges: np.ndarray, t0: np.ndarray, max_tan: float, max_range: float = np.inf):
        """The linearisation of m beams at the state mean ``x`` (n,): each beam with
        robot-frame bearing ``bearings[j]`` (rad) and measured range ``ranges[j]`` (m) against
        map curve ``curve[j]``, Newton from ``t0[j]`` (m). Beams that miss their curve
        (within ``max_range``) or hit it with a tangent ratio |r| > ``max_tan`` (grazing) are
        dropped.

        All the beams' curves at once at the pose ``x[:3]``, stacked over ``state_rows``, in
        one compiled call (:func:`bsslam.slam.range_kernels.linearize_beams`); the tests check
        it bit for bit against the numpy observation model it replaced
        (``tests/slam/observation_oracle.py``).

        Returns:
            ``(cols, H_c, residual, rows, hit_t, missed, grazing)``: the pose indices 0, 1, 2
            then the touched state indices (c,); the Jacobian (k, c) of the k kept beams
            ``rows`` (k,) (increasing); their residuals z − h(x) (k,) (m) and hit parameters
            (k,) (m); the counts of missed and grazing beams.
        """
        phi = x[2]
        cos_phi, sin_phi = np.cos(phi), np.sin(phi)
        # computed once: the intersection and the Jacobian use the same numbers
        mu = (phi + laser_offset[2]) + bearings
        cos_mu, sin_mu = np.cos(mu), np.sin(mu)
        t = self.table
        missed, grazing, cols, H_c, rows, values = range_kernels.linearize_beams(
            x, self.state_rows, self._fixed, t.power_basis, t.window, t.real, t.piece_lo, t.width, t.piece_start,
            t.lo, t.hi, curve, ranges, t0, cos_mu, sin_mu, cos_phi, sin_phi, laser_offset, max_tan, max_range,
            _MAX_NEWTON, _STEP_TOLERANCE, _ROOT_TOLERANCE_M, _unit_grid(8), _MAX_REFINE)
        return cols, H_c, values[0], rows, values[1], missed, grazing


def _rows_of(features: list[SplineFeature]) -> tuple[np.ndarray, np.ndarray]:
    """(N, 2) state rows of the features' control points (−1 where fixed) and (N, 2) the
    fixed control points (zeros where in the state)."""
    rows, fixed = [], []
    for f in features:
        if f.in_state:
            rows.append(np.column_stack([f.idx_x, f.idx_y]))
            fixed.append(np.zeros((f.idx_x.shape[0], 2)))
        else:
            rows.append(np.full(f.fixed_control_points.shape, -1, dtype=np.intp))
            fixed.append(f.fixed_control_points)
    return np.vstack(rows).astype(np.intp), np.vstack(fixed)
