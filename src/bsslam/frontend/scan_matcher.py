"""Matching one laser scan against reference points: correlative search, then robust
point-to-line Gauss–Newton (ICP), with a covariance and a trust decision.

The pose found is that of the *robot* in the frame of the reference points; the scan's
points are given in the robot frame (laser offset already applied, see
:func:`scan_points`).

1. Correlative search (Olson 2009, "Real-time correlative scan matching"): the reference
   is rasterised into two likelihood fields, ``exp(−d²/2σ²)`` of the distance ``d`` to the
   nearest reference point, a coarse blurred one and a fine one. Every rotation × translation
   of a grid around the odometry guess is scored at once (the mean field value under the
   moved scan points), first on the coarse grid over the whole window, then on the fine grid
   around the best few distinct coarse maxima. Translations are whole cells, so a score
   is one gather per point; no Python loop runs per point, pose or beam.
2. Refinement: Gauss–Newton on point-to-line residuals ``nᵀ(R p + t − q)`` to the nearest
   reference point ``q`` (normal ``n`` from a local line fit), Huber weights, a shrinking
   correspondence gate, and the odometry guess as a weak prior (it only decides the
   directions the scan leaves free, e.g. along a corridor). It runs from the correlative
   search's best pose and from the guess; the result with the lower truncated cost
   (:meth:`ReferenceMap.cost`) is the match.
3. Covariance: the inverse of the Gauss–Newton information, the residual σ being the larger
   of the stated ``range_sigma_m`` and the one estimated from the residuals, inflated by
   ``covariance_inflation`` for the correlation of neighbouring residuals, plus the prior
   and a floor.
4. Trust: too few points, too few inliers → ``ok = False`` (the caller falls back to
   odometry); a weak translation direction → ``degenerate = True``.

Bounded work: the fields' size grows with the extent of the reference points, so a
reference wider than :data:`MAX_FIELD_CELLS` allows is not rasterised (the map is not
usable, reason ``reference_too_large``, and the caller falls back to odometry) and the
numba kernels only ever see finite coordinates within :data:`MAX_EXTENT_M`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property, lru_cache

import numpy as np
from scipy.spatial import cKDTree

from bsslam.errors import InputError
from bsslam.config import FrontendConfig
from bsslam.frontend.kernels import first_per_cell, grid_index, point_to_line, splat_max, window_scores
from bsslam.scan.laser_scan import LaserScan
from bsslam.se2 import compose

def _wrap(a: float) -> float:
    """:func:`~bsslam.trajectory.wrap_angle` of one float (rad), the same arithmetic without
    numpy's per-call cost (Python's float ``%`` is numpy's ``mod``)."""
    return math.pi - (math.pi - a) % (2.0 * math.pi)


#: Reasons a match is not trusted (``MatchResult.reason``); "ok" otherwise.
FAIL_REASONS = ("too_few_scan_points", "too_few_reference_points", "too_few_correspondences", "poor_score",
                "reference_too_large")

#: Most cells one likelihood field may have (float32: 64 MiB). A submap of the default
#: front end (20 keyframes within 2·max_range + window of the newest) needs at most ~13 M
#: cells at 5 cm; real runs use ~1–2 M.
MAX_FIELD_CELLS = 1 << 24
#: Largest extent (m) of reference or scan points handed to the kernels: their cell
#: arithmetic is in machine integers, which huge coordinates would overflow.
MAX_EXTENT_M = 1e6


# ---------------------------------------------------------------------------------------------
# points


def scan_points(scan: LaserScan, laser_offset: np.ndarray | None, config: FrontendConfig) -> np.ndarray:
    """(m, 2) end points (m) of the usable beams of ``scan`` in the robot frame.

    Beams are dropped as :func:`bsslam.scan.valid_beams` drops them (NaN/inf, no return at
    or above the scan's ``max_range``, at or below ``min_range_m``) and at or beyond
    ``max_range_m`` — unless fewer than ``min_points`` cells of ``scan_voxel_m`` hold a
    beam within it and ``full_range_when_sparse`` is set, when every return up to the
    scan's ``max_range`` is kept (open ground: the far walls are all there is to match).
    The laser offset is applied.
    """
    ranges = scan.ranges
    # valid_beams' rules in two comparisons (NaN compares False, ±inf fails one of them);
    # tests/frontend check the two agree.
    valid = ranges > config.min_range_m
    mask = valid & (ranges < min(scan.max_range, config.max_range_m))
    points = _end_points(scan.angles[mask], ranges[mask], laser_offset)
    if (config.full_range_when_sparse and config.max_range_m < scan.max_range
            and voxel_thin(points, config.scan_voxel_m).shape[0] < config.min_points):
        mask = valid & (ranges < scan.max_range)
        points = _end_points(scan.angles[mask], ranges[mask], laser_offset)
    return points


def _end_points(angles: np.ndarray, ranges: np.ndarray, laser_offset: np.ndarray | None) -> np.ndarray:
    """(m, 2) end points (m) of beams at ``angles`` (rad) and ``ranges`` (m) in the robot
    frame, the laser at ``laser_offset`` (3,; the robot's origin when None)."""
    if laser_offset is None:
        ox, oy, otheta = 0.0, 0.0, 0.0
    else:
        ox, oy, otheta = np.asarray(laser_offset, dtype=float).reshape(3).tolist()
    c, s = np.cos(otheta + angles), np.sin(otheta + angles)
    points = np.empty((ranges.shape[0], 2))
    points[:, 0] = ox + ranges * c
    points[:, 1] = oy + ranges * s
    return points


def voxel_thin(points: np.ndarray, cell_m: float) -> np.ndarray:
    """Indices (increasing) of one point per occupied ``cell_m`` square: the first one.

    Compiled (:func:`~bsslam.frontend.kernels.first_per_cell`, a hash of the cells seen):
    the numpy form, a sort of the cell keys, is the tests' oracle
    (``tests/frontend/test_kernels.py``)."""
    points = np.ascontiguousarray(points, dtype=float).reshape(-1, 2)
    return first_per_cell(points, float(cell_m))


@lru_cache(maxsize=1024)
def even_subset(n: int, k: int) -> np.ndarray:
    """Indices of at most ``k`` of ``n`` items, evenly spread (all when n ≤ k); read-only
    (cached: the same few (n, k) recur scan after scan)."""
    if n <= k:
        sub = np.arange(n)
    else:
        sub = np.unique(np.linspace(0, n - 1, k).round().astype(np.intp))
    sub.flags.writeable = False
    return sub


def _kdtree(points: np.ndarray) -> cKDTree:
    """KD-tree of (m, 2) points for nearest-neighbour queries. Split at the midpoint, not
    the median, and without shrinking the node boxes: ~1.4x faster to build, queries as
    fast and exact all the same (the trees are rebuilt with every keyframe)."""
    return cKDTree(points, balanced_tree=False, compact_nodes=False)


def estimate_normals(points: np.ndarray, neighbours: int) -> tuple[np.ndarray, np.ndarray]:
    """Unit normals (m, 2) of the line through each point's ``neighbours`` nearest points,
    and a flag (m,) that the fit is line-like (thickness σ_min < 0.3·σ_max, so corners and
    clutter are excluded from the point-to-line refinement)."""
    m = points.shape[0]
    if m < 3:
        return np.zeros((m, 2)), np.zeros(m, dtype=bool)
    k = min(neighbours, m)
    _, idx = _kdtree(points).query(points, k=k)
    nb = points[idx]                                         # (m, k, 2)
    centred = nb - nb.mean(axis=1, keepdims=True)
    sxx = np.einsum("ij,ij->i", centred[..., 0], centred[..., 0])
    syy = np.einsum("ij,ij->i", centred[..., 1], centred[..., 1])
    sxy = np.einsum("ij,ij->i", centred[..., 0], centred[..., 1])
    # Principal axis angle of the 2×2 scatter; the normal is perpendicular to it.
    axis = 0.5 * np.arctan2(2 * sxy, sxx - syy)
    normals = np.column_stack((-np.sin(axis), np.cos(axis)))
    half_trace, half_diff = 0.5 * (sxx + syy), np.hypot(0.5 * (sxx - syy), sxy)
    lam_max, lam_min = half_trace + half_diff, half_trace - half_diff
    linear = lam_min < 0.09 * lam_max                        # σ ratio 0.3
    return normals, linear


# ---------------------------------------------------------------------------------------------
# likelihood fields


@dataclass(frozen=True)
class LikelihoodField:
    """``exp(−d²/2σ²)`` of the distance ``d`` (m) from each cell centre to the nearest
    reference cell, on a padded grid, stored flat (row = x cell, column = y cell).

    Attributes:
        origin: (2,) world position (m) of the corner of cell (0, 0).
        resolution: cell size (m).
        shape: (nx, ny) cells.
        values: (nx·ny,) float32 field.
        pad: points are clipped to this many cells inside the border before offsets of at
            most ``pad`` cells are added; the outer ``2·pad`` cells are zero.
    """

    origin: np.ndarray
    resolution: float
    shape: tuple[int, int]
    values: np.ndarray
    pad: int
    kernel_offset: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0, dtype=np.int64))
    kernel_value: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0, dtype=np.float32))
    radius: int = 0

    @staticmethod
    def cells_needed(points: np.ndarray, resolution: float, sigma: float, max_offset_m: float) -> float:
        """Cells (a float, may be huge) the field of ``points`` (m, 2) would have."""
        pad = math.ceil(max_offset_m / resolution) + 1
        margin = 2 * (2 * pad + math.ceil(3.0 * sigma / resolution) + 1) + 2
        span = points.max(axis=0) - points.min(axis=0)
        return float(np.prod(span / resolution + margin))

    @classmethod
    def build(cls, points: np.ndarray, resolution: float, sigma: float, max_offset_m: float) -> LikelihoodField:
        """Rasterise ``points`` (m, 2); offsets of up to ``max_offset_m`` are scored later.

        Raises:
            InputError: the field would exceed :data:`MAX_FIELD_CELLS` (check with
                :meth:`cells_needed` first).
        """
        if cls.cells_needed(points, resolution, sigma, max_offset_m) > MAX_FIELD_CELLS:
            raise InputError("reference points too far apart for a likelihood field (MAX_FIELD_CELLS)")
        pad = int(np.ceil(max_offset_m / resolution)) + 1
        radius = int(np.ceil(3.0 * sigma / resolution))
        margin = 2 * pad + radius + 1
        lo = points.min(axis=0)
        origin = (np.floor(lo / resolution) - margin) * resolution
        cells = np.floor((points - origin) / resolution).astype(np.int64)
        nx, ny = (cells.max(axis=0) + margin + 1).tolist()
        occupied = np.unique(cells[:, 0] * ny + cells[:, 1])
        ox, oy = np.meshgrid(np.arange(-radius, radius + 1), np.arange(-radius, radius + 1), indexing="ij")
        d2 = (ox * ox + oy * oy).ravel() * resolution ** 2
        near = d2 <= (3.0 * sigma) ** 2 + 1e-12
        kernel_offset = (ox.ravel() * ny + oy.ravel())[near]
        kernel_value = np.exp(-0.5 * d2[near] / sigma ** 2).astype(np.float32)
        values = np.zeros(nx * ny, dtype=np.float32)
        built = cls(origin, resolution, (int(nx), int(ny)), values, pad, kernel_offset, kernel_value, radius)
        built._splat_cells(occupied)
        return built

    def add(self, points: np.ndarray) -> None:
        """Raise the field in place for more reference ``points`` (m, 2); points whose
        kernel would leave the zero border (outside the grid built) are ignored."""
        c = np.floor((points - self.origin) / self.resolution).astype(np.int64)
        lo, hi = 2 * self.pad + self.radius + 1, np.array(self.shape) - 2 * self.pad - self.radius - 2
        inside = np.all((c >= lo) & (c <= hi), axis=1)
        self._splat_cells(np.unique(c[inside, 0] * self.shape[1] + c[inside, 1]))

    def _splat_cells(self, occupied: np.ndarray) -> None:
        """Raise the field to the kernel around each flat cell of ``occupied`` (q,)."""
        splat_max(self.values, occupied, self.kernel_offset, self.kernel_value)

    def cell_index(self, points: np.ndarray) -> np.ndarray:
        """Flat cell index (...,) of world points (..., 2), clipped ``pad`` cells inside."""
        c = np.floor((points - self.origin) / self.resolution).astype(np.intp)
        ix = np.clip(c[..., 0], self.pad, self.shape[0] - 1 - self.pad)
        iy = np.clip(c[..., 1], self.pad, self.shape[1] - 1 - self.pad)
        return ix * self.shape[1] + iy

    def score_poses(self, points: np.ndarray, poses: np.ndarray, offsets: np.ndarray) -> np.ndarray:
        """Mean field value of robot-frame ``points`` (n, 2) at every pose ``poses[p]``
        shifted by every whole-cell offset ``offsets[t]`` (t, 2) (int cells): (p, t) float32.

        The plain form (one flat index per pose, offset and point), kept as the oracle of
        :meth:`score_grid`. The sum over the points is taken in float64, where it is exact
        (see :func:`~bsslam.frontend.kernels.window_scores`), then rounded to float32 and
        divided by n in float32, so the two agree to the bit."""
        c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
        wx = c[:, None] * points[None, :, 0] - s[:, None] * points[None, :, 1] + poses[:, 0:1]
        wy = s[:, None] * points[None, :, 0] + c[:, None] * points[None, :, 1] + poses[:, 1:2]
        base = self.cell_index(np.stack((wx, wy), axis=-1))               # (p, n)
        flat_offset = offsets[:, 0] * self.shape[1] + offsets[:, 1]       # (t,)
        idx = base[:, None, :] + flat_offset[None, :, None]               # (p, t, n)
        total = np.take(self.values, idx).sum(axis=2, dtype=np.float64).astype(np.float32)
        return total / np.float32(points.shape[0])

    def score_grid(self, points: np.ndarray, poses: np.ndarray, half_cells: int, step_cells: int) -> np.ndarray:
        """:meth:`score_poses` for the offsets ``_offset_grid(half_cells, step_cells)`` (in
        that order, x offset major): (p, t) mean field values, t = (2·(half//step) + 1)².

        The offsets form a square grid of cells, so each moved point reads one strided
        window of the 2-D field in place (:func:`~bsslam.frontend.kernels.window_scores`).
        ``half_cells`` must not exceed ``pad`` (the clipped base cell then keeps the window
        inside the grid).
        """
        if half_cells > self.pad:
            raise ValueError("offsets beyond the field's padding")
        poses = np.asarray(poses, dtype=float)
        nx, ny = self.shape
        return window_scores(self.values, nx, ny, float(self.origin[0]), float(self.origin[1]), self.resolution,
                             self.pad, np.ascontiguousarray(points, dtype=float), np.cos(poses[:, 2]),
                             np.sin(poses[:, 2]), np.ascontiguousarray(poses[:, 0]), np.ascontiguousarray(poses[:, 1]),
                             half_cells // step_cells, step_cells)


def _offset_axis(half_cells: int, step_cells: int) -> np.ndarray:
    """(w,) int offsets k·step in [−half, half] along one axis (cells), ascending."""
    return np.arange(-(half_cells // step_cells), half_cells // step_cells + 1) * step_cells


def _offset_grid(half_cells: int, step_cells: int) -> np.ndarray:
    """(t, 2) int offsets k·step for k·step in [−half, half] on both axes: the square
    grid of :func:`_offset_axis` on x and y, x offset major."""
    k = _offset_axis(half_cells, step_cells)
    gx, gy = np.meshgrid(k, k, indexing="ij")
    return np.column_stack((gx.ravel(), gy.ravel()))


@dataclass(frozen=True)
class _SearchGrid:
    """The pose grids of the two correlative levels, which depend only on the
    configuration and the two fields' resolutions (so they are built once, not per scan).

    Attributes:
        rot_steps: (r,) coarse rotations relative to the guess (rad).
        coarse_half, coarse_step: the coarse offsets are ``_offset_grid(coarse_half,
            coarse_step)`` (coarse cells); offsets (t, 2) those cells, offsets_m (t, 2) in m;
            axis (w,) the grid's coordinates on either axis, ``_offset_axis(coarse_half,
            coarse_step)`` (t = w²).
        coarse_penalty: (r, t) ``search_prior_weight`` × the quadratic penalty of each
            coarse pose's distance from the guess.
        fine_rot: (f,) fine rotations relative to a coarse candidate (rad).
        fine_half: the fine offsets are ``_offset_grid(fine_half, 1)`` (fine cells);
            fine_offsets_m (t', 2) in m.
        rot_poses: (r, 3) poses (0, 0, rot_steps): the coarse poses less the guess.
        fine_trans_prior: (t, t') the translation part of the quadratic penalty (without
            the weight) of fine offset t' around coarse offset t.
        fine_rot_prior: (r, f) its rotation part, fine rotation f around coarse rotation r.
    """

    rot_steps: np.ndarray
    coarse_half: int
    coarse_step: int
    offsets: np.ndarray
    offsets_m: np.ndarray
    axis: np.ndarray
    coarse_penalty: np.ndarray
    fine_rot: np.ndarray
    fine_half: int
    fine_offsets_m: np.ndarray
    fine_trans_prior: np.ndarray
    fine_rot_prior: np.ndarray


@lru_cache(maxsize=16)
def _search_grid(cfg: FrontendConfig, res_c: float, res_f: float) -> _SearchGrid:
    n_rot = int(np.floor(cfg.search_window_rad / cfg.coarse_step_rad + 1e-9))
    rot_steps = cfg.coarse_step_rad * np.arange(-n_rot, n_rot + 1)
    step_c = max(1, int(round(cfg.coarse_step_m / res_c)))
    half_c = int(round(cfg.search_window_m / res_c))
    offsets = _offset_grid(half_c, step_c)
    offsets_m = offsets * res_c
    penalty = cfg.search_prior_weight * (np.sum(offsets_m ** 2, axis=1)[None, :] / (2 * cfg.search_window_m ** 2)
                                         + (rot_steps ** 2)[:, None] / (2 * cfg.search_window_rad ** 2))
    n_fine_rot = int(round(cfg.coarse_step_rad / cfg.fine_step_rad))
    fine_rot = cfg.fine_step_rad * np.arange(-n_fine_rot, n_fine_rot + 1)
    half_f = int(round(cfg.coarse_step_m / res_f))
    fine_offsets_m = _offset_grid(half_f, 1) * res_f
    dx = offsets_m[:, 0:1] + fine_offsets_m[None, :, 0]
    dy = offsets_m[:, 1:2] + fine_offsets_m[None, :, 1]
    trans = (dx * dx + dy * dy) / (2 * cfg.search_window_m ** 2)
    rot = (rot_steps[:, None] + fine_rot[None, :]) ** 2 / (2 * cfg.search_window_rad ** 2)
    grid = _SearchGrid(rot_steps, half_c, step_c, offsets, offsets_m, _offset_axis(half_c, step_c), penalty,
                       fine_rot, half_f, fine_offsets_m, trans, rot)
    for a in (grid.rot_steps, grid.offsets, grid.offsets_m, grid.axis, grid.coarse_penalty, grid.fine_rot,
              grid.fine_offsets_m, grid.fine_trans_prior, grid.fine_rot_prior):
        a.flags.writeable = False          # shared between calls
    return grid


# ---------------------------------------------------------------------------------------------
# result


@dataclass(frozen=True)
class MatchResult:
    """The outcome of one scan match.

    Attributes:
        pose: (3,) robot pose in the reference frame (x m, y m, φ rad); the guess when
            ``ok`` is False.
        covariance: (3, 3) its covariance (m², m·rad, rad²); the prior's when not ``ok``.
        score: fraction of the refined scan points that are inliers (residual below
            ``inlier_distance_m``), in [0, 1].
        ok: whether the match is trusted.
        reason: "ok" or one of :data:`FAIL_REASONS`.
        degenerate: the scan fixes one translation direction only weakly (a corridor);
            that direction then comes from the prior.
        weak_prior_weight: how much of ``weak_prior_covariance`` (see :meth:`ReferenceMap.match`)
            the refinement used, in [0, 1]: 1 for a degenerate match, 0 for a well-constrained
            one (or when none was given).
        weakness: the smallest over the largest eigenvalue of the translation block of
            the scan's information at the first refinement (near 0 in a corridor): what
            ``weak_prior_weight`` follows, whether or not a weak prior was given.
        correlation: best mean likelihood of the fine correlative search, in [0, 1].
        points: scan points used in the refinement.
        inliers: of which inliers.
        iterations: Gauss–Newton iterations run.
        information: (3, 3) information of the scan alone (without the prior).
    """

    pose: np.ndarray
    covariance: np.ndarray
    score: float
    ok: bool
    reason: str
    degenerate: bool = False
    correlation: float = 0.0
    points: int = 0
    inliers: int = 0
    iterations: int = 0
    information: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))
    weak_prior_weight: float = 0.0
    weakness: float = 0.0


# ---------------------------------------------------------------------------------------------
# reference and matcher


class ReferenceMap:
    """Reference points prepared for matching: two likelihood fields and a grid of the
    line-like points with their normals. Build once, match many scans against it.

    Args:
        points: (m, 2) reference points (m), in the frame the poses are expressed in.
        normals: (m, 2) their unit normals and ``linear`` (m,) whether each lies on a line;
            both estimated from the points when None.
        config: the matcher parameters.
    """

    def __init__(self, points: np.ndarray, config: FrontendConfig = FrontendConfig(), *,
                 normals: np.ndarray | None = None, linear: np.ndarray | None = None) -> None:
        points = np.asarray(points, dtype=float).reshape(-1, 2)
        if not np.all(np.isfinite(points)):
            raise InputError("reference points must be finite")
        self.config = config
        self.points = points
        if normals is None or linear is None:
            normals, linear = estimate_normals(points, config.normal_neighbours)
        self.size = points.shape[0]
        self.usable = self.size >= config.min_points and int(np.count_nonzero(linear)) >= 3
        self.unusable_reason = "too_few_reference_points"
        if self.usable and not self._fits(points):
            self.usable, self.unusable_reason = False, "reference_too_large"
        if not self.usable:
            return
        window = config.search_window_m
        self.coarse = LikelihoodField.build(points, 0.5 * config.coarse_step_m, config.coarse_sigma_m, window)
        self.fine = LikelihoodField.build(points, config.fine_step_m, config.fine_sigma_m,
                                          window + config.coarse_step_m)
        self.line_points = points[linear]
        self.line_normals = np.asarray(normals, dtype=float)[linear]
        self._index_lines()

    def _fits(self, points: np.ndarray) -> bool:
        """Whether the fields of ``points`` stay within :data:`MAX_FIELD_CELLS` and the
        coordinates within :data:`MAX_EXTENT_M`."""
        cfg = self.config
        if np.max(np.abs(points)) > MAX_EXTENT_M:
            return False
        fine = LikelihoodField.cells_needed(points, cfg.fine_step_m, cfg.fine_sigma_m,
                                            cfg.search_window_m + cfg.coarse_step_m)
        coarse = LikelihoodField.cells_needed(points, 0.5 * cfg.coarse_step_m, cfg.coarse_sigma_m,
                                              cfg.search_window_m)
        return max(fine, coarse) <= MAX_FIELD_CELLS

    def _index_lines(self) -> None:
        """Grid of the line points (:func:`~bsslam.frontend.kernels.grid_index`, cells of
        the final gate's size), and their points and normals side by side (k, 4) in the
        grid's order, so that a correspondence is one row."""
        lo_x, lo_y, cell, nx, ny, start, order = grid_index(self.line_points, self.config.icp_min_distance_m,
                                                            8 * self.line_points.shape[0] + 4096)
        self._line_grid = (start, lo_x, lo_y, cell, nx, ny)
        self._line_qn = np.concatenate((self.line_points, self.line_normals), axis=1)[order]

    def extend(self, points: np.ndarray, normals: np.ndarray, linear: np.ndarray) -> bool:
        """Add reference points (with normals and line flags) in place: both fields are
        raised where the new points fall inside the grids built, and the line points'
        grid is rebuilt.
        Returns False (nothing changed) when the map was not usable; build anew then."""
        if not self.usable:
            return False
        points = np.asarray(points, dtype=float).reshape(-1, 2)
        if not np.all(np.isfinite(points)) or (points.size and np.max(np.abs(points)) > MAX_EXTENT_M):
            return False
        self.coarse.add(points)
        self.fine.add(points)
        self.points = np.concatenate((self.points, points))
        self.size = self.points.shape[0]
        self.line_points = np.concatenate((self.line_points, points[linear]))
        self.line_normals = np.concatenate((self.line_normals, np.asarray(normals, dtype=float)[linear]))
        self._index_lines()
        return True

    # -- correlative search ------------------------------------------------------------------

    @cached_property
    def _grid(self) -> _SearchGrid:
        """The search's pose grids (looked up once per map: hashing the configuration for
        the shared cache costs more than a scan's use of it)."""
        return _search_grid(self.config, self.coarse.resolution, self.fine.resolution)

    def _coarse_poses(self, guess: np.ndarray) -> np.ndarray:
        """(r, 3) the coarse level's rotations of ``guess`` (3,), translations whole cells
        added by :meth:`LikelihoodField.score_grid`."""
        grid = self._grid
        poses = np.empty((grid.rot_steps.shape[0], 3))
        poses[:, 0], poses[:, 1] = guess[0], guess[1]
        poses[:, 2] = guess[2] + grid.rot_steps
        return poses

    def coarse_scores(self, points: np.ndarray, guess: np.ndarray) -> np.ndarray:
        """(r, t) float32, read-only: the raw coarse level of the search around ``guess``
        (every rotation × offset, no tie-break), which :meth:`correlative` and
        :meth:`alternative` both start from; pass it to both (``coarse=``) to compute it
        once for the same points and guess."""
        grid = self._grid
        score = self.coarse.score_grid(points, self._coarse_poses(np.asarray(guess, dtype=float)), grid.coarse_half,
                                       grid.coarse_step)
        score.flags.writeable = False
        return score

    def _fine_poses(self, guess: np.ndarray, poses: np.ndarray, candidates: list[tuple[int, int]]
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The fine level's poses around the coarse candidates: ±1 coarse step around each,
        in rotation here and in translation through the fine offsets the scoring adds, as
        the blurred coarse peak can sit a whole step from the true one.

        Args:
            guess: (3,) the search's centre (m, m, rad).
            poses: (r, 3) :meth:`_coarse_poses` of ``guess``.
            candidates: k ≥ 1 (rotation, offset) indices into the coarse (r, t) grid.

        Returns:
            cand_rot (k,) and cand_off (k,), the candidates' rotation and offset indices,
            and the fine poses (k·f, 3) (m, m, rad), candidate major: candidate i's coarse
            offset added to ``guess`` with each of its f fine rotations; the fine offsets
            (t', 2) of :meth:`LikelihoodField.score_grid` are added to these.
        """
        grid = self._grid
        cand_rot, cand_off = (np.array(c) for c in zip(*candidates))
        shift = grid.offsets_m[cand_off]                                          # (k, 2) m from the guess
        n_fine = grid.fine_rot.shape[0]
        fine_poses = np.empty((len(candidates), n_fine, 3))
        fine_poses[:, :, 0] = (guess[0] + shift[:, 0])[:, None]
        fine_poses[:, :, 1] = (guess[1] + shift[:, 1])[:, None]
        fine_poses[:, :, 2] = poses[cand_rot, 2][:, None] + grid.fine_rot
        return cand_rot, cand_off, fine_poses.reshape(-1, 3)

    def _fine_pose(self, fine_poses: np.ndarray, p: int, t: int) -> np.ndarray:
        """(3,) a new array: the pose (m, m, rad) of fine cell (p, t), fine pose ``p`` of
        :meth:`_fine_poses` (k·f, 3) moved by fine offset ``t`` (m)."""
        pose = fine_poses[p].copy()
        pose[:2] += self._grid.fine_offsets_m[t]
        return pose

    def correlative(self, points: np.ndarray, guess: np.ndarray, coarse: np.ndarray | None = None
                    ) -> tuple[np.ndarray, float]:
        """Best pose (3,) of the two-level correlative search around ``guess`` and its fine
        mean likelihood. ``coarse``: :meth:`coarse_scores` of these points and guess, if
        already computed."""
        cfg = self.config
        guess = np.asarray(guess, dtype=float)
        grid = self._grid
        poses = self._coarse_poses(guess)
        score = self.coarse_scores(points, guess) if coarse is None else coarse   # (r, t)
        # Quadratic tie-break towards the guess: −w at the window's corner.
        score = score - grid.coarse_penalty
        candidates = _distinct_maxima(score, cfg.coarse_candidates, rot_sep=2, axis=grid.axis,
                                      off_sep=2 * grid.coarse_step, overwrite=True)
        # Fine level: ±1 coarse step (rotation and translation) around each candidate.
        cand_rot, cand_off, fine_poses = self._fine_poses(guess, poses, candidates)
        fine = self.fine.score_grid(points, fine_poses, grid.fine_half, 1)
        # The same penalty, split into its translation (k, t) and rotation (k, f) parts.
        trans = grid.fine_trans_prior[cand_off]
        rot = grid.fine_rot_prior[cand_rot]
        fprior = (trans[:, None, :] + rot[:, :, None]).reshape(fine.shape)
        total = fine - cfg.search_prior_weight * fprior
        p, t = divmod(int(np.argmax(total)), total.shape[1])
        return self._fine_pose(fine_poses, p, t), float(fine[p, t])

    def alternative(self, points: np.ndarray, guess: np.ndarray, best: np.ndarray, sep_m: float,
                    sep_rad: float, coarse: np.ndarray | None = None,
                    admitted: tuple[np.ndarray, np.ndarray, float] | None = None) -> tuple[np.ndarray, float]:
        """The runner-up of :meth:`correlative`: the best pose (3,) of the same two-level
        search around ``guess`` among the poses *distinct* from ``best`` (more than
        ``sep_m`` in translation or ``sep_rad`` in heading away), and its fine mean
        likelihood (0 and ``guess`` when the window holds no such pose).

        Scores are raw (without the tie-break towards the guess) so that the ratio to the
        best's score measures ambiguity (repetitive structure), not distance from the guess.
        ``coarse``: :meth:`coarse_scores` of these points and guess, if already computed.
        ``admitted``: (centre (3,), information (3, 3), bound): poses within that squared
        Mahalanobis distance of the centre are excluded too (the region a match's own
        covariance admits: the same answer as the best, not a rival).
        """
        cfg = self.config
        guess = np.asarray(guess, dtype=float)
        best = np.asarray(best, dtype=float)
        grid = self._grid
        poses = self._coarse_poses(guess)
        score = (self.coarse_scores(points, guess) if coarse is None else coarse).astype(float)

        def near(x: np.ndarray, y: np.ndarray, phi: np.ndarray) -> np.ndarray:
            turn = np.abs((phi - best[2] + np.pi) % (2 * np.pi) - np.pi)
            out = (np.hypot(x - best[0], y - best[1]) <= sep_m) & (turn <= sep_rad)
            if admitted is not None:
                centre, a, bound = admitted
                dx, dy = x - centre[0], y - centre[1]
                dphi = (phi - centre[2] + np.pi) % (2 * np.pi) - np.pi
                # dᵀ A d grouped so that the xy terms are computed on the offsets alone and
                # only two products span the whole (rotations × offsets) grid
                xy = a[0, 0] * dx * dx + (a[0, 1] + a[1, 0]) * dx * dy + a[1, 1] * dy * dy
                cross = (a[0, 2] + a[2, 0]) * dx + (a[1, 2] + a[2, 1]) * dy
                out = out | (xy + dphi * (cross + a[2, 2] * dphi) <= bound)
            return out

        # A coarse pose is knocked out when it is near ``best`` (its fine neighbourhood of
        # ±1 coarse step is masked again below).
        score[near(guess[0] + grid.offsets_m[None, :, 0], guess[1] + grid.offsets_m[None, :, 1],
                   poses[:, 2:3])] = -np.inf
        # _distinct_maxima stops at the first −inf: every candidate is distinct from best.
        candidates = _distinct_maxima(score, cfg.coarse_candidates, rot_sep=2, axis=grid.axis,
                                      off_sep=2 * grid.coarse_step, overwrite=True)
        if not candidates:
            return guess.copy(), 0.0
        _, _, fine_poses = self._fine_poses(guess, poses, candidates)
        fine = self.fine.score_grid(points, fine_poses, grid.fine_half, 1).astype(float)
        fine[near(fine_poses[:, 0:1] + grid.fine_offsets_m[None, :, 0],
                  fine_poses[:, 1:2] + grid.fine_offsets_m[None, :, 1], fine_poses[:, 2:3])] = -np.inf
        p, t = divmod(int(np.argmax(fine)), fine.shape[1])
        if not np.isfinite(fine[p, t]):
            return guess.copy(), 0.0
        return self._fine_pose(fine_poses, p, t), float(fine[p, t])

    # -- refinement ------------------------------------------------------------------------

    def refine(self, points: np.ndarray, start: np.ndarray, prior_mean: np.ndarray,
               prior_information: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, int]:
        """Robust point-to-line Gauss–Newton from ``start``.

        Returns:
            pose (3,), the scan's information (3, 3) in units of 1/σ² (without the prior),
            the final residuals (n,) (NaN where no correspondence), weights (n,), iterations.
        """
        pose, info, Jr, w, found, it = self._refine(points, start, prior_mean, prior_information)
        residuals = np.full(found.shape[0], np.nan)
        residuals[found] = Jr[:, 3]
        weights = np.zeros(found.shape[0])
        weights[found] = w
        return pose, info, residuals, weights, it

    def _refine(self, points: np.ndarray, start: np.ndarray, prior_mean: np.ndarray, prior_information: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, int]:
        """:meth:`refine`, returning the final residuals as :meth:`_linearise` does: pose
        (3,), information (3, 3), Jr (m, 4), w (m,), found (n,), iterations."""
        cfg = self.config
        points = np.ascontiguousarray(points, dtype=float)
        x0, x1, x2 = (float(v) for v in start)
        m0, m1, m2 = (float(v) for v in prior_mean)
        sigma2 = _refinement_sigma2(cfg)
        gate = cfg.icp_max_distance_m
        # The pose is kept as three floats and the 3×3 algebra done with scalars where that
        # is exact: a few-element numpy call costs more than its arithmetic (~7 iterations
        # per scan).
        it = 0
        for it in range(1, cfg.icp_iterations + 1):
            Jr, w, _ = self._linearise(points, x0, x1, x2, gate)
            # [H | g] of the scan in one product: Jᵀ W [J | r].
            Hg = (Jr[:, :3] * w[:, None]).T @ Jr / sigma2
            e = np.array((x0 - m0, x1 - m1, _wrap(x2 - m2)))
            H = Hg[:, :3] + prior_information
            g = Hg[:, 3] + prior_information @ e
            try:
                delta = -np.linalg.solve(H, g)
            except np.linalg.LinAlgError:
                break
            d0, d1, d2 = delta.tolist()
            x0, x1, x2 = x0 + d0, x1 + d1, _wrap(x2 + d2)
            small = math.hypot(d0, d1) < 2e-4 and abs(d2) < 2e-4
            if small and gate <= cfg.icp_min_distance_m:
                break
            # The correlative start is within a fine step: the wide gate is only needed to
            # pull in points the first step, then it shrinks to the final one.
            gate = max(cfg.icp_min_distance_m, 0.5 * gate)
        Jr, w, found = self._linearise(points, x0, x1, x2, gate)
        J = np.ascontiguousarray(Jr[:, :3])
        info = (J * w[:, None]).T @ J
        return np.array((x0, x1, x2)), info, Jr, w, found, it

    def _linearise(self, points: np.ndarray, x0: float, x1: float, x2: float, gate: float
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Point-to-line residuals of robot-frame ``points`` (n, 2) moved by the pose
        (x0 m, x1 m, x2 rad) against their nearest line-like reference point within ``gate``
        (m), with their Jacobian.

        Returns:
            Jr (m, 4): the Jacobian (m, 3) of the residuals in (x, y, φ) and, in the last
            column, the residuals nᵀ(R p + t − q) (m); w (m,) Huber weights; found (n,)
            which points had a correspondence (m of them).
        """
        c, s = math.cos(x2), math.sin(x2)
        # R p by numpy's matrix product (BLAS, with fused multiply-adds the kernel would not
        # reproduce); the rest is one compiled pass over the points.
        rotated = points @ np.array(((c, s), (-s, c)))                     # (n, 2)
        start, lo_x, lo_y, cell, nx, ny = self._line_grid
        return point_to_line(rotated, x0, x1, gate, self._line_qn, start, lo_x, lo_y, cell, nx, ny,
                             self.config.huber_m)

    def _residuals(self, points: np.ndarray, x: np.ndarray, gate: float):
        """Point-to-line residuals of robot-frame ``points`` (n, 2) moved by the pose ``x``
        (3,) against their nearest line-like reference point within ``gate`` (m).

        Returns:
            r (m,) residuals nᵀ(R p + t − q) (m), J (m, 3) their Jacobian in (x, y, φ),
            w (m,) Huber weights, found (n,) which points had a correspondence (m of them).
        """
        Jr, w, found = self._linearise(np.ascontiguousarray(points, dtype=float), float(x[0]), float(x[1]),
                                       float(x[2]), gate)
        return Jr[:, 3], Jr[:, :3], w, found

    # -- the whole match ---------------------------------------------------------------------

    def match(self, points: np.ndarray, guess: np.ndarray, prior_covariance: np.ndarray | None = None,
              weak_prior_covariance: np.ndarray | None = None) -> MatchResult:
        """Match robot-frame scan ``points`` (n, 2) around the pose ``guess`` (3,).

        Args:
            prior_covariance: (3, 3) covariance of the guess in the reference frame; the
                refinement's weak prior and the covariance returned when the match fails.
                None: a diagonal one from the search window.
            weak_prior_covariance: (3, 3) covariance of the guess for a scan that fixes a
                translation direction only weakly (a corridor): how well the guess is
                actually known there, when that is better than ``prior_covariance`` says.
                A degenerate match is refined again with this prior (the scan's few
                features along the corridor otherwise decide that direction); one whose
                weakest-to-strongest ratio lies between ``degenerate_ratio`` and twice it
                with a prior blended in information between the two (1 at the ratio, 0 at
                twice it, linear in its logarithm), so that no ratio is a knife edge.
                None: ``prior_covariance`` for every match.

        Returns:
            :class:`MatchResult`; ``ok`` False means: use the guess.
        """
        cfg = self.config
        guess = np.asarray(guess, dtype=float).reshape(3)
        if prior_covariance is None:
            prior_covariance = np.diag([cfg.search_window_m ** 2, cfg.search_window_m ** 2,
                                        cfg.search_window_rad ** 2])
        prior_covariance = np.asarray(prior_covariance, dtype=float)
        points = np.asarray(points, dtype=float).reshape(-1, 2)

        def fail(reason: str, score: float = 0.0, **extra) -> MatchResult:
            return MatchResult(guess.copy(), prior_covariance.copy(), score, False, reason, **extra)

        if not self.usable:
            return fail(self.unusable_reason)
        if not (np.all(np.isfinite(guess)) and np.all(np.isfinite(points))
                and np.max(np.abs(guess[:2]), initial=0.0) <= MAX_EXTENT_M):
            raise InputError("scan points and pose guess must be finite and within MAX_EXTENT_M")
        keep = voxel_thin(points, cfg.scan_voxel_m)
        pts = points[keep]
        if pts.shape[0] < cfg.min_points:
            return fail("too_few_scan_points", points=int(pts.shape[0]))
        pts = pts[even_subset(pts.shape[0], cfg.max_scan_points)]
        search = pts[even_subset(pts.shape[0], cfg.search_points)]

        start, correlation = self.correlative(search, guess)
        prior_info = np.linalg.inv(prior_covariance)
        pose, info, Jr, w, found, iterations = self._refine(pts, start, guess, prior_info)
        # The correlative search scores a blurred field, not the refinement's objective: its
        # best cell can lead to a local minimum that explains the scan worse than the one
        # the guess leads to (CSAIL's scan 370: 29 of 97 inliers, 26° off the odometry,
        # against 35 from the guess). Refine from both; the lower cost wins. When the best
        # cell is the guess itself (about one match in ten) the two are the same refinement.
        if not np.array_equal(start, guess):
            from_guess = self._refine(pts, guess, guess, prior_info)
            if self.cost(pts.shape[0], from_guess[2][:, 3], from_guess[0], guess, prior_info) < \
                    self.cost(pts.shape[0], Jr[:, 3], pose, guess, prior_info):
                start = guess
                pose, info, Jr, w, found, iterations = from_guess
        weakness = self._weakness(info)
        weak_weight = 0.0 if weak_prior_covariance is None else weak_prior_share(weakness, cfg.degenerate_ratio)
        if weak_weight > 0.0:
            prior_info = prior_info + weak_weight * (np.linalg.inv(weak_prior_covariance) - prior_info)
            pose, info, Jr, w, found, iterations = self._refine(pts, start, guess, prior_info)

        r = Jr[:, 3]                                      # residuals of the points found
        inliers = int(np.count_nonzero(np.abs(r) < cfg.inlier_distance_m))
        n = pts.shape[0]
        score = inliers / n
        base = dict(correlation=correlation, points=n, inliers=inliers, iterations=iterations, information=info,
                    weak_prior_weight=weak_weight, weakness=weakness)
        if r.shape[0] < cfg.min_points:
            return fail("too_few_correspondences", **base)
        if score < cfg.min_inlier_fraction:
            return fail("poor_score", score, **base)

        # Residual σ: the stated one, or the (Huber-weighted) estimate when larger.
        dof = max(1.0, float(np.sum(w)) - 3.0)
        sigma2_hat = float(np.sum(w * r * r)) / dof
        sigma2 = max(cfg.range_sigma_m ** 2, sigma2_hat) * cfg.covariance_inflation
        info_scan = info / sigma2
        cov = np.linalg.inv(info_scan + prior_info)
        cov = 0.5 * (cov + cov.T) + np.diag([cfg.min_sigma_xy_m ** 2, cfg.min_sigma_xy_m ** 2, cfg.min_sigma_rad ** 2])
        # the information changed only if the weak prior refined the match again
        degenerate = (weakness if weak_weight == 0.0 else self._weakness(info)) < cfg.degenerate_ratio
        return MatchResult(pose, cov, score, True, "ok", degenerate, **base)

    def cost(self, n: int, residuals: np.ndarray, pose: np.ndarray, prior_mean: np.ndarray,
             prior_information: np.ndarray) -> float:
        """The truncated-quadratic cost of a refined match of ``n`` scan points, by which
        two local minima are compared: each point's squared ``residuals`` (m; one per point
        with a correspondence) capped at ``inlier_distance_m``², a point without one at the
        cap, over the refinement's σ²; plus the prior's squared Mahalanobis distance of
        ``pose`` (3,) from ``prior_mean`` (3,) under ``prior_information`` (3, 3).
        Dimensionless; it is continuous in the residuals, so a ulp does not flip a choice
        made by it unless the two minima are tied."""
        cap = self.config.inlier_distance_m ** 2
        e = np.asarray(pose, dtype=float) - prior_mean
        e[2] = _wrap(float(e[2]))
        scan = float(np.sum(np.minimum(residuals * residuals, cap))) + (n - residuals.shape[0]) * cap
        return scan / _refinement_sigma2(self.config) + float(e @ prior_information @ e)

    @staticmethod
    def _weakness(information: np.ndarray) -> float:
        """The smallest over the largest eigenvalue of the translation block of a scan's
        ``information`` (3, 3): near 0 in a corridor."""
        eig = np.linalg.eigvalsh(information[:2, :2])
        return float(eig[0] / max(eig[1], 1e-12))


def weak_prior_share(ratio: float, degenerate_ratio: float) -> float:
    """The share of the weak prior (:meth:`ReferenceMap.match`) for a scan of weakness
    ``ratio`` (:meth:`ReferenceMap._weakness`): 1 at or below ``degenerate_ratio``, 0 at
    or above twice it, linear in the logarithm of the ratio between."""
    if ratio <= degenerate_ratio:
        return 1.0
    if ratio >= 2.0 * degenerate_ratio:
        return 0.0
    return math.log(2.0 * degenerate_ratio / ratio) / math.log(2.0)


def _refinement_sigma2(config: FrontendConfig) -> float:
    """σ² (m²) the refinement gives each point-to-line residual: the stated σ, inflated."""
    return config.range_sigma_m ** 2 * config.covariance_inflation


def scan_disagreement(match: MatchResult, guess: np.ndarray, prior_covariance: np.ndarray,
                      config: FrontendConfig) -> np.ndarray:
    """(3,) where the scan alone puts the pose, less ``guess`` (3,; the heading wrapped):
    ``match.pose`` with the refinement's pull towards ``guess`` under ``prior_covariance``
    (3, 3) undone, from the Gauss–Newton normal equations at the match,
    H_scan (x − x_scan) + I_prior (x − guess) = 0.

    Raises:
        numpy.linalg.LinAlgError: the scan's information is singular.
    """
    e = match.pose - guess
    e[2] = _wrap(float(e[2]))
    scan_information = match.information / _refinement_sigma2(config)
    return e + np.linalg.solve(scan_information, np.linalg.solve(prior_covariance, e))


def _distinct_maxima(score: np.ndarray, k: int, *, rot_sep: int, axis: np.ndarray, off_sep: int,
                     overwrite: bool = False) -> list[tuple[int, int]]:
    """Up to ``k`` (rotation, offset) indices of the highest scores, each at least
    ``rot_sep`` rotation steps or ``off_sep`` cells from those already taken.

    Args:
        score: (r, t) scores (rotations × offsets); not modified unless ``overwrite``.
        axis: (w,) ascending coordinates (cells) of the square grid of offsets that the
            columns are, x offset major (t = w², as :func:`_offset_grid` of the same
            :func:`_offset_axis` lays them out).
        overwrite: ``score`` is a float64 scratch array that may be used up.

    Greedy: take the highest remaining score, then knock out its neighbourhood (a band
    of rotations × the square of offsets near it) and repeat; ``k`` argmax passes over the
    (r, t) array instead of a full sort. Ties go to the lowest flat index. The
    neighbourhood is a block of the offset grid, so nothing of size t × t is made (a
    loop closure's wide window has 10⁴ offsets).
    """
    left = score if overwrite else np.array(score, dtype=float)   # knocked-out entries become −inf
    left = np.ascontiguousarray(left)           # so that the views below write into it
    n_rot, n_off = left.shape
    width = axis.shape[0]
    if width * width != n_off:
        raise ValueError(f"{n_off} offsets are not the square grid of {width} coordinates")
    block = left.reshape(n_rot, width, width)
    flat = left.reshape(-1)
    taken: list[tuple[int, int]] = []
    for _ in range(min(k, flat.shape[0])):
        j = int(flat.argmax())
        if flat[j] == -np.inf:
            break
        r, t = divmod(j, n_off)
        taken.append((r, t))
        ix, iy = divmod(t, width)
        # |rotation − r| < rot_sep: a band of rows; |offset − off[t]| < off_sep on both
        # axes: a run of grid coordinates on each (the axis is sorted).
        x0, x1 = np.searchsorted(axis, axis[ix] - off_sep, "right"), np.searchsorted(axis, axis[ix] + off_sep, "left")
        y0, y1 = np.searchsorted(axis, axis[iy] - off_sep, "right"), np.searchsorted(axis, axis[iy] + off_sep, "left")
        block[max(r - rot_sep + 1, 0):max(r + rot_sep, 0), x0:x1, y0:y1] = -np.inf
    return taken


def match_scan(reference_points: np.ndarray, points: np.ndarray, guess: np.ndarray,
               config: FrontendConfig = FrontendConfig(), prior_covariance: np.ndarray | None = None) -> MatchResult:
    """One-off match of robot-frame scan ``points`` (n, 2) against ``reference_points``
    (m, 2) around the robot pose ``guess`` (3,) in the reference frame. Build a
    :class:`ReferenceMap` instead to match several scans against the same reference."""
    return ReferenceMap(reference_points, config).match(points, guess, prior_covariance)


def transform_points(pose: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Points (n, 2) of the frame at ``pose`` expressed in the parent frame."""
    pts = np.column_stack((points, np.zeros(points.shape[0])))
    return compose(np.asarray(pose, dtype=float)[None, :], pts)[:, :2]
