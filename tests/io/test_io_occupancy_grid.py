"""The occupancy grid: the beam walk against a dense-sampling oracle, the log-odds rules on
hand-made scans, the map_server files read back as map_server reads them, and a simulated
run whose exact walls and poses must land on occupied and free cells."""

import dataclasses
from pathlib import Path

import numpy as np
import pytest
import yaml
from PIL import Image

from bsslam.config import GridConfig, SLAMConfig
from bsslam.errors import ConfigError, InputError
from bsslam.io.grid import FREE, OCCUPIED, UNKNOWN, build_occupancy_grid, write_grid
from bsslam.io.grid_kernels import integrate_scans
from bsslam.scan.laser_scan import LaserScan


def load_map_server(yaml_path: Path):
    """A map as map_server loads it (trinary mode): +1 occupied, 0 free, −1 unknown, with
    row 0 the image's top; origin and resolution from the YAML."""
    meta = yaml.safe_load(yaml_path.read_text())
    assert meta["mode"] == "trinary"
    value = np.asarray(Image.open(yaml_path.parent / meta["image"]).convert("L"), dtype=float)
    p = value / 255.0 if meta["negate"] else (255.0 - value) / 255.0
    classes = np.full(value.shape, -1, dtype=int)
    classes[p > meta["occupied_thresh"]] = 1
    classes[p < meta["free_thresh"]] = 0
    return classes, meta["origin"], meta["resolution"]


def cells_of(xy, origin, resolution, height):
    """(row, col) image cells of world points (k, 2) (m), map_server's convention."""
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    col = np.floor((xy[:, 0] - origin[0]) / resolution).astype(int)
    row = height - 1 - np.floor((xy[:, 1] - origin[1]) / resolution).astype(int)
    return row, col


# --- the beam walk --------------------------------------------------------------------

def _walked_cells(start, end, shape=(40, 40)):
    log_odds = np.zeros(shape, dtype=np.float32)
    stamp = np.full(shape, -1, dtype=np.int64)
    integrate_scans(log_odds, stamp, 0, np.array([start], float), np.array([0, 1]), np.array([end], float),
                    np.array([False]), np.float32(1.0), np.float32(-1.0), np.float32(10.0))
    return {tuple(rc) for rc in np.argwhere(log_odds < 0)}


def _sampled_cells(start, end, n=200_001):
    t = np.linspace(0.0, 1.0, n)[:, None]
    pts = np.asarray(start) + t * (np.asarray(end) - np.asarray(start))
    keys = np.unique(np.floor(pts[:, 1]).astype(int) * 1000 + np.floor(pts[:, 0]).astype(int))
    cells = {(int(k // 1000), int(k % 1000)) for k in keys}
    cells.discard((int(np.floor(end[1])), int(np.floor(end[0]))))
    return cells


def test_the_walk_visits_exactly_the_cells_a_dense_sampling_crosses_but_the_last():
    rng = np.random.default_rng(0)
    for _ in range(200):
        start, end = rng.uniform(0.5, 39.5, 2), rng.uniform(0.5, 39.5, 2)
        kind = rng.random()
        if kind < 0.1:                    # axis-parallel beams too
            end[1] = start[1]
        elif kind < 0.2:
            end[0] = start[0]
        assert _walked_cells(start, end) == _sampled_cells(start, end)


def test_a_beam_within_one_cell_clears_nothing():
    assert _walked_cells((3.2, 3.3), (3.8, 3.9)) == set()


# --- the log-odds rules on hand-made scans --------------------------------------------

CONFIG = GridConfig(resolution_m=0.1, margin_m=0.3, footprint_radius_m=0.0)


def _scan(ranges, angles, max_range=10.0):
    return LaserScan(0.0, np.asarray(angles, float), np.asarray(ranges, float), max_range)


def _log_odds_at(grid, xy):
    h = grid.log_odds.shape[0]
    row, col = cells_of(xy, grid.origin, grid.resolution_m, h)
    return grid.log_odds[row, col]


def test_beams_clear_their_path_mark_their_return_and_no_return_clears_a_fixed_reach():
    # the robot at (0.03, 0.04) facing +x, the laser 0.2 m ahead of it; a wall at x = 2.04
    pose = np.array([[0.03, 0.04, 0.0]])
    offset = np.array([0.2, 0.0, 0.0])
    scan = _scan([1.81, np.inf, 7.0, np.nan, 0.01], [0.0, np.pi / 2, -np.pi / 2, np.pi / 4, -np.pi / 4],
                 max_range=7.0)
    grid = build_occupancy_grid([(scan, offset)], pose, CONFIG)
    hit = (0.23 + 1.81, 0.04)
    assert _log_odds_at(grid, hit) == pytest.approx(CONFIG.log_odds_hit)
    path = np.column_stack([np.linspace(0.23, 1.95, 50), np.full(50, 0.04)])
    np.testing.assert_allclose(_log_odds_at(grid, path), CONFIG.log_odds_miss, rtol=1e-6)
    # +y: inf = no return; −y: 7.0 ≥ max_range = no return: both clear exactly 5 m
    up = np.column_stack([np.full(49, 0.23), 0.04 + np.linspace(0.0, 4.93, 49)])
    down = np.column_stack([np.full(49, 0.23), 0.04 - np.linspace(0.0, 4.93, 49)])
    np.testing.assert_allclose(_log_odds_at(grid, up), CONFIG.log_odds_miss, rtol=1e-6)
    np.testing.assert_allclose(_log_odds_at(grid, down), CONFIG.log_odds_miss, rtol=1e-6)
    assert _log_odds_at(grid, (0.23, 0.04 + 5.05)) == 0 and _log_odds_at(grid, (0.23, 0.04 - 5.05)) == 0
    # NaN and a range below min_range_m give nothing: the diagonals stay unobserved
    assert _log_odds_at(grid, (0.23 + 0.7, 0.04 + 0.7)) == 0
    assert _log_odds_at(grid, (0.23 + 0.7, 0.04 - 0.7)) == 0
    assert _log_odds_at(grid, (-0.5, 0.04)) == 0       # behind the laser
    # the grid holds everything: the laser, the hit and both 5 m clearings, plus the margin
    assert grid.origin[1] == pytest.approx(0.04 - 5.0 - 0.3)


def test_a_cell_takes_one_update_per_scan_and_a_return_wins_over_a_pass_through():
    # two beams of one scan through the same cells; the second stops short, in a cell the
    # first beam passes: that cell gets the hit only
    scan = _scan([3.0, 1.5], [0.0, 0.0])
    grid = build_occupancy_grid([(scan, np.zeros(3))], np.array([[0.05, 0.05, 0.0]]), CONFIG)
    assert _log_odds_at(grid, (0.5, 0.05)) == pytest.approx(CONFIG.log_odds_miss)      # not twice
    assert _log_odds_at(grid, (1.55, 0.05)) == pytest.approx(CONFIG.log_odds_hit)      # hit, no miss
    # the same scan three times: three updates, clamped at the limit
    grid = build_occupancy_grid([(scan, np.zeros(3))] * 3, np.tile([0.05, 0.05, 0.0], (3, 1)),
                                dataclasses.replace(CONFIG, log_odds_limit=1.5))
    assert _log_odds_at(grid, (0.5, 0.05)) == pytest.approx(3 * CONFIG.log_odds_miss)
    assert _log_odds_at(grid, (1.55, 0.05)) == pytest.approx(1.5)


def test_a_run_in_several_beam_batches_gives_the_grid_of_one_batch(monkeypatch):
    # the extent pass keeps the batch when there is one; in several, both passes make them
    import functools

    import bsslam.io.grid as grid_module

    rng = np.random.default_rng(3)
    angles = np.linspace(-1.5, 1.5, 7)
    scans = [(_scan(rng.uniform(0.5, 4.0, 7), angles), np.array([0.1, 0.0, 0.05])) for _ in range(9)]
    poses = np.column_stack([np.linspace(0.0, 2.0, 9), rng.uniform(-0.2, 0.2, 9), rng.uniform(-0.5, 0.5, 9)])
    one = build_occupancy_grid(scans, poses, CONFIG)
    monkeypatch.setattr(grid_module, "_beam_batches", functools.partial(grid_module._beam_batches, batch_beams=10))
    several = build_occupancy_grid(scans, poses, CONFIG)
    assert several.origin == one.origin
    np.testing.assert_array_equal(several.log_odds, one.log_odds)


def test_footprints_are_free_and_curves_occupied():
    config = dataclasses.replace(CONFIG, footprint_radius_m=0.25)
    wall = np.array([[1.0, -1.0], [1.0, 1.0]])
    poses = np.array([[0.03, 0.04, 0.0]])
    scan = _scan([np.nan], [0.0])
    grid = build_occupancy_grid([(scan, np.zeros(3))], poses, config, [wall])
    image = grid.image(config.occupied_thresh, config.free_thresh)
    h = image.shape[0]
    r, c = cells_of(np.column_stack([np.full(20, 1.0), np.linspace(-0.99, 0.99, 20)]), grid.origin, 0.1, h)
    assert np.all(image[r, c] == OCCUPIED)
    ring = 0.03 + 0.15 * np.cos(np.linspace(0, 2 * np.pi, 16)), 0.04 + 0.15 * np.sin(np.linspace(0, 2 * np.pi, 16))
    r, c = cells_of(np.column_stack(ring), grid.origin, 0.1, h)
    assert np.all(image[r, c] == FREE)
    r, c = cells_of([(0.03 + 0.5, 0.04)], grid.origin, 0.1, h)
    assert image[r, c] == UNKNOWN


def test_empty_input_gives_an_unknown_grid_around_the_origin():
    grid = build_occupancy_grid([], np.empty((0, 3)), GridConfig(resolution_m=0.1, margin_m=1.0))
    assert grid.log_odds.shape == (20, 20) and np.all(grid.image() == UNKNOWN)
    assert grid.origin == pytest.approx((-1.0, -1.0, 0.0))


def test_a_wild_range_is_an_error_naming_the_limit_not_an_allocation():
    scan = _scan([1e12], [0.0], max_range=1e13)   # a return a million km away, below its max_range
    with pytest.raises(InputError, match="grid.max_cells"):
        build_occupancy_grid([(scan, np.zeros(3))], np.zeros((1, 3)), GridConfig())
    with pytest.raises(InputError, match="grid.max_cells"):
        build_occupancy_grid([(_scan([1.0], [0.0]), np.zeros(3))] * 2, np.array([[0.0, 0.0, 0.0], [0.0, 1e9, 0.0]]),
                             GridConfig())
    with pytest.raises(InputError, match="2 scans but 1 poses"):
        build_occupancy_grid([(scan, np.zeros(3))] * 2, np.zeros((1, 3)), GridConfig())


@pytest.mark.parametrize("section", [{"resolution_m": 0.0}, {"free_thresh": 0.25}, {"occupied_thresh": 0.1},
                                     {"log_odds_miss": 0.4}, {"max_cells": 0}, {"no_return_clear_m": -1.0},
                                     {"resolution": 0.05}])
def test_bad_grid_configuration_is_refused(section):
    with pytest.raises(ConfigError):
        SLAMConfig.from_dict({"grid": section})


def test_write_grid_refuses_a_non_image(tmp_path):
    with pytest.raises(InputError, match="uint8"):
        write_grid(tmp_path / "a.pgm", tmp_path / "a.yaml", np.zeros((2, 2)), (0, 0, 0), 0.1)


# --- map_server files -----------------------------------------------------------------

def test_the_files_read_back_as_map_server_reads_them(tmp_path):
    wall = np.array([[0.0, 0.0], [4.04, 0.0], [4.04, 3.04]])
    scan = _scan([2.0], [np.pi / 2])
    config = GridConfig(resolution_m=0.1, margin_m=0.5, footprint_radius_m=0.0)
    grid = build_occupancy_grid([(scan, np.zeros(3))] * 6, np.tile([2.03, 0.54, 0.0], (6, 1)), config, [wall])
    image = grid.image(config.occupied_thresh, config.free_thresh)
    write_grid(tmp_path / "map.pgm", tmp_path / "map.yaml", image, grid.origin, 0.1)
    assert (tmp_path / "map.pgm").read_bytes()[:2] == b"P5"
    classes, origin, resolution = load_map_server(tmp_path / "map.yaml")
    np.testing.assert_array_equal(classes, np.select([image == OCCUPIED, image == FREE], [1, 0], -1))
    assert origin == pytest.approx([-0.5, -0.5, 0.0]) and resolution == 0.1
    h = classes.shape[0]
    assert classes.shape == (41, 51)     # (3.04 + 1) / 0.1 rows, (4.04 + 1) / 0.1 columns, rounded up
    # the wall's corner, the beam's path and its return, where the world says they are
    r, c = cells_of([(4.04, 3.04), (4.04, 1.5), (1.0, 0.0), (2.03, 2.54)], origin, resolution, h)
    assert np.all(classes[r, c] == 1)
    r, c = cells_of(np.column_stack([np.full(10, 2.03), np.linspace(0.54, 2.4, 10)]), origin, resolution, h)
    assert np.all(classes[r, c] == 0)
    assert np.count_nonzero(classes == 0) == 20      # cells 10 … 29 above y = −0.5: from 0.54 to the return


# --- a simulated run ------------------------------------------------------------------

@pytest.fixture(scope="module")
def simulated_run(tmp_path_factory):
    from bsslam.outputs import write_run_grid
    from bsslam.pipeline import run_dataset
    from bsslam.sim import SimConfig, get_world, simulate

    data = simulate(get_world("rounded-room"), SimConfig(), seed=1, steps=90)
    config = SLAMConfig()
    result = run_dataset(data, config, point_stride=0)
    folder = tmp_path_factory.mktemp("grid")
    write_run_grid(result, folder, config)
    return data, result, folder


def _observed_wall_points(data, tolerance_m=0.02):
    """Points of the exact walls that some beam of the run hit (true poses, exact walls)."""
    from scipy.spatial import cKDTree

    ends = []
    for frame, pose in zip(data, data.ground_truth.poses):
        ok = np.isfinite(frame.scan.ranges) & (frame.scan.ranges < frame.scan.max_range)
        b = pose[2] + frame.scan.angles[ok]
        ends.append(pose[:2] + frame.scan.ranges[ok, None] * np.column_stack([np.cos(b), np.sin(b)]))
    walls = np.vstack(data.world.polylines(0.01))
    near = cKDTree(np.vstack(ends)).query(walls, distance_upper_bound=tolerance_m)[0] < np.inf
    return walls[near]


def _within(classes, r, c, reach, value):
    """(k,) whether a cell within ``reach`` cells (Chebyshev) of each (r, c) has ``value``."""
    found = np.zeros(len(r), bool)
    for dr in range(-reach, reach + 1):
        for dc in range(-reach, reach + 1):
            found |= classes[np.clip(r + dr, 0, classes.shape[0] - 1), np.clip(c + dc, 0, classes.shape[1] - 1)] == value
    return found


def test_the_scans_at_the_true_poses_free_the_path_and_mark_the_exact_walls(simulated_run):
    """The evidence alone (no footprint, no splines), with the scans at their exact poses:
    the true walls the beams hit are occupied cells, the true path free ones."""
    data, result, _ = simulated_run
    config = dataclasses.replace(SLAMConfig().grid, footprint_radius_m=0.0)
    grid = build_occupancy_grid(result.scans, data.ground_truth.poses, config)
    image = grid.image(config.occupied_thresh, config.free_thresh)
    h = image.shape[0]
    walls = _observed_wall_points(data)
    assert len(walls) > 1000
    r, c = cells_of(walls, grid.origin, grid.resolution_m, h)
    assert np.mean(image[r, c] == OCCUPIED) > 0.95
    assert np.mean(image[r, c] == FREE) < 0.02
    assert np.mean(_within(image, r, c, 1, OCCUPIED)) > 0.99, np.mean(_within(image, r, c, 1, OCCUPIED))
    r, c = cells_of(data.ground_truth.poses[:, :2], grid.origin, grid.resolution_m, h)
    assert np.mean(image[r, c] == FREE) > 0.95     # all but the first few: no later scan looks back


def test_a_simulated_run_puts_its_poses_on_free_cells_and_the_true_walls_on_occupied_ones(simulated_run):
    """The files the run wrote, read as map_server reads them: scans at the estimated poses,
    the footprint and the splines drawn in."""
    data, result, folder = simulated_run
    classes, origin, resolution = load_map_server(folder / "grid.yaml")
    h = classes.shape[0]
    for poses in (result.trajectory.poses, data.ground_truth.poses):
        r, c = cells_of(poses[:, :2], origin, resolution, h)
        assert np.all(classes[r, c] == 0)
    for m in result.map:
        r, c = cells_of(m.curve.evaluate(np.linspace(*m.curve.domain, 200)), origin, resolution, h)
        assert np.all(classes[r, c] == 1)
    # the estimate is off the truth by up to ~0.1 m here, so the walls it maps are too
    r, c = cells_of(_observed_wall_points(data), origin, resolution, h)
    pose_error = np.max(np.hypot(*(result.trajectory.poses[:, :2] - data.ground_truth.poses[:, :2]).T))
    reach = int(np.ceil(pose_error / resolution)) + 1
    assert np.mean(_within(classes, r, c, reach, 1)) > 0.98


DATA = Path(__file__).resolve().parents[2] / ".." / "shared" / "data"
INTEL = DATA / "intel" / "intel-noisy.clf"


@pytest.mark.skipif(not INTEL.exists(), reason=f"shared data not found at {INTEL}")
def test_a_real_log_grid_is_navigable(tmp_path):
    """The first 100 scans of the Intel lab: every pose on a free cell of the files, and
    the splines (left out of the grid here) on the scans' occupied cells, within two cells
    (10 cm): the loop closure these scans end with moves the submaps' frames rigidly, so
    walls mapped twice in two submaps keep a few centimetres of its residual between them
    (5 cm: 83 %, 10 cm: 91 %, 15 cm: 94 % with the invariant EKF; the paper's EKF, closing
    no loop, 93 / 96 / 97 % at an ATE of 0.29 m against 0.09 m)."""
    from bsslam.io import open_dataset
    from bsslam.pipeline import run_dataset

    config = SLAMConfig()
    result = run_dataset(open_dataset(INTEL), config, steps=100, point_stride=0)
    grid = build_occupancy_grid(result.scans, result.trajectory.poses, config.grid)
    image = grid.image(config.grid.occupied_thresh, config.grid.free_thresh)
    write_grid(tmp_path / "grid.pgm", tmp_path / "grid.yaml", image, grid.origin, grid.resolution_m)
    classes, origin, resolution = load_map_server(tmp_path / "grid.yaml")
    h = classes.shape[0]
    r, c = cells_of(result.trajectory.poses[:, :2], origin, resolution, h)
    assert np.all(classes[r, c] == 0)
    points = np.vstack([m.curve.evaluate(np.linspace(*m.curve.domain, 100)) for m in result.map])
    r, c = cells_of(points, origin, resolution, h)
    assert np.mean(_within(classes, r, c, 2, 1)) > 0.9, np.mean(_within(classes, r, c, 2, 1))
