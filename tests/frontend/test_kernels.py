"""The front end's compiled loops (bsslam.frontend.kernels) against plain numpy forms."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial import cKDTree

from bsslam.frontend.kernels import _nearest, first_per_cell, grid_index, point_to_line, splat_max
from bsslam.frontend.scan_matcher import LikelihoodField, voxel_thin


@pytest.mark.parametrize("seed", range(3))
def test_splat_max_is_numpys_maximum_at(seed):
    """Exact: a maximum does not round, whatever the order (cells repeat on purpose)."""
    rng = np.random.default_rng(seed)
    field = LikelihoodField.build(rng.uniform(-3.0, 3.0, size=(50, 2)), 0.05, 0.07, 0.4)
    nx, ny = field.shape
    r = field.radius + 1
    cells = rng.integers(r, nx - r, 300) * ny + rng.integers(r, ny - r, 300)
    cells = np.concatenate((cells, cells[:20]))
    expected = field.values.copy()
    np.maximum.at(expected, (cells[:, None] + field.kernel_offset[None, :]).ravel(),
                  np.tile(field.kernel_value, cells.shape[0]))
    got = field.values.copy()
    splat_max(got, cells, field.kernel_offset, field.kernel_value)
    np.testing.assert_array_equal(got, expected)


def _grid(pts, cell, max_cells=10 ** 6):
    lo_x, lo_y, cell, nx, ny, start, order = grid_index(pts, cell, max_cells)
    return order, (start, lo_x, lo_y, cell, nx, ny)


@pytest.mark.parametrize("cell, max_cells", [(0.15, 10 ** 6), (0.05, 10 ** 6), (0.15, 50)])
def test_grid_index_buckets_every_point_once_in_its_cell(cell, max_cells):
    rng = np.random.default_rng(3)
    pts = rng.uniform(-4.0, 6.0, size=(500, 2))
    lo_x, lo_y, used, nx, ny, start, order = grid_index(pts, cell, max_cells)
    assert nx * ny <= max_cells and used >= cell
    assert (lo_x, lo_y) == tuple(pts.min(axis=0))
    np.testing.assert_array_equal(np.sort(order), np.arange(500))
    key = np.minimum(np.floor((pts[:, 0] - lo_x) / used), nx - 1) * ny + np.minimum(np.floor((pts[:, 1] - lo_y) / used), ny - 1)
    np.testing.assert_array_equal(order, np.argsort(key, kind="stable"))
    np.testing.assert_array_equal(start, np.searchsorted(np.sort(key), np.arange(nx * ny + 1)))


@pytest.mark.parametrize("cell, gate", [(0.15, 0.3), (0.15, 0.15), (0.3, 0.15), (0.05, 0.2)])
def test_grid_nearest_is_the_brute_force_and_the_kdtree_answer(cell, gate):
    """Exact: the same points, the same squared distances compared with gate² (strictly,
    as cKDTree's distance_upper_bound), including queries exactly at the gate and far off."""
    rng = np.random.default_rng(4)
    pts = rng.uniform(-3.0, 3.0, size=(800, 2))
    queries = np.concatenate((rng.uniform(-3.5, 3.5, size=(2000, 2)), pts[:50] + [gate, 0.0],
                              pts[50:60], [[100.0, 100.0], [-50.0, 0.0]]))
    order, grid = _grid(pts, cell)
    xy = pts[order]
    got = np.array([_nearest(xy, *grid, qx, qy, gate) for qx, qy in queries])
    got = np.where(got >= 0, order[np.maximum(got, 0)], -1)
    d2 = (queries[:, None, 0] - pts[None, :, 0]) ** 2 + (queries[:, None, 1] - pts[None, :, 1]) ** 2
    near = d2.min(axis=1) < gate * gate
    np.testing.assert_array_equal(got >= 0, near)
    np.testing.assert_array_equal(got[near], np.argmin(d2, axis=1)[near])
    _, idx = cKDTree(pts, balanced_tree=False, compact_nodes=False).query(queries, distance_upper_bound=gate)
    np.testing.assert_array_equal(np.where(idx < pts.shape[0], idx, -1), got)


def test_point_to_line_is_the_numpy_form():
    """Bit-identical to the former numpy body of _linearise (cKDTree query, gather, einsum)."""
    rng = np.random.default_rng(6)
    pts = rng.uniform(-3.0, 3.0, size=(600, 2))
    ang = rng.uniform(0.0, np.pi, 600)
    qn = np.column_stack((pts, np.cos(ang), np.sin(ang)))
    scan = rng.uniform(-3.0, 3.0, size=(300, 2))
    x0, x1, x2, gate, huber = 0.1, -0.2, 0.3, 0.15, 0.03
    c, s = math.cos(x2), math.sin(x2)
    rotated = scan @ np.array(((c, s), (-s, c)))
    order, grid = _grid(pts, 0.15)
    Jr, w, found = point_to_line(rotated, x0, x1, gate, qn[order], *grid, huber)
    moved = rotated + (x0, x1)
    _, idx = cKDTree(pts).query(moved, distance_upper_bound=gate)
    hit = idx < pts.shape[0]
    np.testing.assert_array_equal(found, hit)
    idx, rotated, moved = idx[hit], rotated[hit], moved[hit]
    n = qn[idx, 2:]
    expected = np.empty((idx.shape[0], 4))
    expected[:, :2] = n
    expected[:, 2] = n[:, 1] * rotated[:, 0] - n[:, 0] * rotated[:, 1]
    np.einsum("ij,ij->i", n, moved - qn[idx, :2], out=expected[:, 3])
    np.testing.assert_array_equal(Jr, expected)
    np.testing.assert_array_equal(w, huber / np.maximum(np.abs(expected[:, 3]), huber))


def _voxel_thin_numpy(points, cell_m):
    """The numpy form voxel_thin had: one point per cell, the first, by a sort of the keys."""
    points = np.asarray(points, dtype=float)
    if points.shape[0] == 0:
        return np.zeros(0, dtype=np.intp)
    cells = np.floor(points / cell_m).astype(np.int64)
    cells -= cells.min(axis=0)
    key = cells[:, 0] * (int(cells[:, 1].max()) + 1) + cells[:, 1]
    _, first = np.unique(key, return_index=True)
    return np.sort(first)


@pytest.mark.parametrize("seed", range(4))
def test_first_per_cell_is_the_numpy_form(seed):
    """The same indices in the same order, on clouds from a few points to thousands, small
    and far from the origin, with points on cell borders and repeated points."""
    rng = np.random.default_rng(seed)
    for _ in range(50):
        n = int(rng.integers(1, 3000))
        scale = float(rng.choice([0.5, 5.0, 50.0, 1e4]))
        pts = rng.normal(size=(n, 2)) * scale + rng.normal(size=2) * 3 * scale
        if rng.uniform() < 0.3:
            pts = np.round(pts, 1)            # on cell borders, and repeated
        cell = float(rng.choice([0.05, 0.1, 0.3, 1.0]))
        got = first_per_cell(pts, cell)
        np.testing.assert_array_equal(got, _voxel_thin_numpy(pts, cell))
        assert got.dtype == np.intp
    assert first_per_cell(np.zeros((0, 2)), 0.1).shape == (0,)
    assert np.array_equal(voxel_thin(np.zeros((0, 2)), 0.1), np.zeros(0, dtype=np.intp))
