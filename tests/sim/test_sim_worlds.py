"""The built-in worlds: registry, closed double loops, clearance from walls, smooth paths,
and scans that see long runs of wall."""

import math

import numpy as np
import pytest
from scipy.spatial import cKDTree

from bsslam.errors import ConfigError
from bsslam.sim.paths import LoopPath, StationaryPath, rounded_rectangle_loop
from bsslam.sim.worlds import DEFAULT_WORLD, WORLDS, get_world
from bsslam.trajectory import wrap_angle

LOOP_WORLDS = sorted(name for name, w in WORLDS.items() if isinstance(w.path, LoopPath))


def test_registry_has_the_paper_worlds_with_descriptions():
    assert {"curved-wall", "rounded-room", "corridor-loop", "mixed"} <= set(WORLDS)
    assert DEFAULT_WORLD == "rounded-room"
    for name, world in WORLDS.items():
        assert world.name == name and world.description and "\n" not in world.description
        assert get_world(name) is world


def test_unknown_world_lists_the_known_names():
    with pytest.raises(ConfigError) as err:
        get_world("atlantis")
    for name in WORLDS:
        assert name in str(err.value)


@pytest.mark.parametrize("name", LOOP_WORLDS)
def test_double_loop_returns_to_the_start_twice(name):
    poses = WORLDS[name].path.sample(0.25)
    half = (len(poses) - 1) // 2
    assert (len(poses) - 1) % 2 == 0
    for k in (half, len(poses) - 1):
        np.testing.assert_allclose(poses[k, :2], poses[0, :2], atol=1e-9)
        assert abs(wrap_angle(poses[k, 2] - poses[0, 2])) < 1e-9
    # Nowhere else on a lap is the robot back at the start.
    away = np.linalg.norm(poses[1:half, :2] - poses[0, :2], axis=1)
    assert away.min() > 0.2


@pytest.mark.parametrize("name", LOOP_WORLDS)
def test_path_is_smooth_heading_along_the_motion_and_clear_of_walls(name):
    world = WORLDS[name]
    poses = world.path.sample(0.25)
    steps = np.diff(poses[:, :2], axis=0)
    np.testing.assert_allclose(np.linalg.norm(steps, axis=1), 0.25, rtol=0.05)
    turn = wrap_angle(np.diff(poses[:, 2]))
    assert np.max(np.abs(turn)) < 0.3  # no spins on the spot
    # Within one straight or circular piece the chord points exactly along the mean of the
    # two headings; steps straddling a piece boundary are off by a little.
    off = np.abs(wrap_angle(np.arctan2(steps[:, 1], steps[:, 0]) - (poses[:-1, 2] + turn / 2)))
    assert np.median(off) < 1e-9 and off.max() < 0.05
    walls = cKDTree(np.vstack(world.polylines(0.01)))
    dense = world.path.poses_at(np.linspace(0.0, world.path.length_m, 4000))
    clearance, _ = walls.query(dense[:, :2])
    assert clearance.min() >= 0.8
    extent = np.ptp(np.vstack(world.polylines(0.1)), axis=0)
    assert 10.0 <= extent.min() and extent.max() <= 20.0


@pytest.mark.parametrize("name", sorted(WORLDS))
def test_every_scan_sees_a_run_of_at_least_ten_wall_points(name):
    world = WORLDS[name]
    poses = world.path.sample(0.25)
    tau = np.linspace(-math.pi / 2, math.pi / 2, 181)
    for pose in poses[::5]:
        hit = np.isfinite(world.ray_cast(pose[:2], pose[2] + tau, 8.0))
        # Longest run of consecutive hits.
        edges = np.diff(np.concatenate([[0], hit.astype(int), [0]]))
        longest = np.max(np.flatnonzero(edges == -1) - np.flatnonzero(edges == 1))
        assert longest >= 10


def test_curved_wall_is_seen_whole_from_the_stationary_pose():
    world = get_world("curved-wall")
    poses = world.path.sample(0.25)
    assert isinstance(world.path, StationaryPath) and np.all(poses == poses[0])
    np.testing.assert_allclose(poses[0], [0.0, 0.0, math.pi / 2])
    tau = np.linspace(-math.pi / 2, math.pi / 2, 181)
    r = world.ray_cast(poses[0, :2], poses[0, 2] + tau, 8.0)
    np.testing.assert_allclose(r, 5.0 + 0.5 * np.sin(5.0 * (tau + math.pi / 2)), atol=1e-9)


def test_loop_path_poses_are_exact_on_a_circle():
    radius = 2.0
    circle = LoopPath(start=(radius, 0.0, math.pi / 2), pieces=((2 * math.pi * radius, 1 / radius),))
    s = np.linspace(0.0, 3 * circle.length_m, 50)
    poses = circle.poses_at(s)
    angle = s / radius
    np.testing.assert_allclose(poses[:, 0], radius * np.cos(angle), atol=1e-12)
    np.testing.assert_allclose(poses[:, 1], radius * np.sin(angle), atol=1e-12)
    np.testing.assert_allclose(wrap_angle(poses[:, 2] - angle - math.pi / 2), 0.0, atol=1e-12)


def test_open_or_spinning_paths_are_refused():
    with pytest.raises(ConfigError):
        LoopPath(start=(0.0, 0.0, 0.0), pieces=((1.0, 0.0),))
    with pytest.raises(ConfigError):
        rounded_rectangle_loop(0.0, 0.0, 4.0, 3.0, radii=(0.0, 1.0, 1.0, 1.0))
    with pytest.raises(ConfigError):
        StationaryPath((0.0, 0.0, 0.0), scans=0)
