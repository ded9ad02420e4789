"""Laser and odometry simulation in a :class:`~bsslam.sim.worlds.World`.

The robot follows the world's path exactly (the ground truth). Odometry reports the true
increment in the robot frame plus Gaussian noise with the paper's σ = a + b·|Δ| per
component (the same :class:`~bsslam.config.MotionNoiseConfig` the filter uses), integrated
into a dead-reckoned pose. The laser ray-casts the exact walls from the true pose and adds
Gaussian range noise; beams with no wall within range report ``max_range`` (no return).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Iterator

import numpy as np

from bsslam.config import MotionNoiseConfig
from bsslam.dataset import Frame, SkipCounter
from bsslam.errors import ConfigError
from bsslam.scan.laser_scan import LaserScan
from bsslam.sim.worlds import World
from bsslam.slam.motion import motion_sigmas   # the filter's own odometry noise model
from bsslam.trajectory import Trajectory, wrap_angle


@dataclass(frozen=True)
class SimConfig:
    """Simulated sensors and motion.

    Attributes:
        fov_rad: laser field of view, centred on the robot's heading (rad); ≤ 2π.
        resolution_rad: angle between consecutive beams (rad).
        max_range_m: laser maximum range (m); farther walls give no return.
        sigma_range_m: σ of the Gaussian range noise (m).
        step_m: distance travelled along the path between scans (m; adjusted slightly so a
            lap is a whole number of steps).
        scan_period_s: time between scans (s), for the stamps.
        motion: odometry noise σ = a + b·|Δ| per component of the increment.
    """

    fov_rad: float = math.pi
    resolution_rad: float = math.radians(1.0)
    max_range_m: float = 8.0
    sigma_range_m: float = 0.005
    step_m: float = 0.25
    scan_period_s: float = 0.5
    motion: MotionNoiseConfig = field(default_factory=MotionNoiseConfig)

    def __post_init__(self) -> None:
        if not 0 < self.fov_rad <= 2 * math.pi:
            raise ConfigError(f"fov_rad must be in (0, 2π], got {self.fov_rad}")
        if not 0 < self.resolution_rad <= self.fov_rad:
            raise ConfigError(f"resolution_rad must be in (0, fov_rad], got {self.resolution_rad}")
        for name in ("max_range_m", "step_m", "scan_period_s"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"{name} must be > 0, got {getattr(self, name)}")
        if not self.sigma_range_m >= 0:
            raise ConfigError(f"sigma_range_m must be ≥ 0, got {self.sigma_range_m}")

    def beam_angles(self) -> np.ndarray:
        """(m,) beam bearings in the robot frame (rad), from −fov/2 to +fov/2 inclusive
        (a full turn leaves out the duplicate last beam)."""
        full_turn = self.fov_rad >= 2 * math.pi - 1e-12
        n = round(self.fov_rad / self.resolution_rad) + (0 if full_turn else 1)
        return np.linspace(-self.fov_rad / 2, self.fov_rad / 2, n, endpoint=not full_turn)


def relative_increments(poses: np.ndarray) -> np.ndarray:
    """(N, 3) increments between consecutive poses (N, 3) in the frame of the earlier one
    (Δx m, Δy m, Δφ rad wrapped); the first row is zero."""
    poses = np.asarray(poses, dtype=float).reshape(-1, 3)
    inc = np.zeros_like(poses)
    delta = poses[1:, :2] - poses[:-1, :2]
    c, s = np.cos(poses[:-1, 2]), np.sin(poses[:-1, 2])
    inc[1:, 0] = c * delta[:, 0] + s * delta[:, 1]
    inc[1:, 1] = -s * delta[:, 0] + c * delta[:, 1]
    inc[1:, 2] = wrap_angle(poses[1:, 2] - poses[:-1, 2])
    return inc


def compose_increments(start: np.ndarray, increments: np.ndarray) -> np.ndarray:
    """(N, 3) poses from ``start`` (3,) by composing robot-frame increments (N, 3) (the
    first is applied to ``start``): the motion model of spec §5, vectorised with cumulative
    sums since each heading depends only on earlier Δφ."""
    inc = np.asarray(increments, dtype=float).reshape(-1, 3)
    heading = start[2] + np.cumsum(inc[:, 2])
    before = np.concatenate([[start[2]], heading[:-1]])  # heading each increment starts from
    c, s = np.cos(before), np.sin(before)
    poses = np.empty_like(inc)
    poses[:, 0] = start[0] + np.cumsum(c * inc[:, 0] - s * inc[:, 1])
    poses[:, 1] = start[1] + np.cumsum(s * inc[:, 0] + c * inc[:, 1])
    poses[:, 2] = wrap_angle(heading)
    return poses


@dataclass(frozen=True)
class SimulatedDataset:
    """A simulated run; implements :class:`bsslam.dataset.Dataset`.

    Attributes:
        name: ``"sim:<world>:seed<seed>"``.
        world: the world simulated.
        config: the simulation settings.
        seed: the random seed.
        ground_truth: exact poses (N, 3) with stamps.
        true_increments: (N, 3) exact robot-frame increments (Δx m, Δy m, Δφ rad); row 0 is 0.
        odometry_increments: (N, 3) the noisy increments odometry reported; row 0 is 0.
        odometry_poses: (N, 3) dead-reckoned poses, starting at the true first pose.
        beam_angles: (m,) beam bearings in the robot frame (rad).
        ranges: (N, m) noisy ranges (m); ``max_range_m`` where there is no return.
        skipped: always empty (nothing is skipped in simulation).
    """

    name: str
    world: World
    config: SimConfig
    seed: int
    ground_truth: Trajectory
    true_increments: np.ndarray
    odometry_increments: np.ndarray
    odometry_poses: np.ndarray
    beam_angles: np.ndarray
    ranges: np.ndarray
    skipped: SkipCounter = field(default_factory=SkipCounter)

    def __len__(self) -> int:
        return self.ranges.shape[0]

    def __iter__(self) -> Iterator[Frame]:
        for k, stamp in enumerate(self.ground_truth.stamps):
            scan = LaserScan(float(stamp), self.beam_angles, self.ranges[k], self.config.max_range_m)
            yield Frame(float(stamp), self.odometry_poses[k].copy(), scan)


def simulate(world: World, sim_config: SimConfig | None = None, seed: int = 0, steps: int | None = None) -> SimulatedDataset:
    """Simulate the robot driving ``world``'s path with noisy odometry and laser.

    Args:
        world: the world (walls and path).
        sim_config: sensor and motion settings; defaults to :class:`SimConfig()`.
        seed: seed of ``numpy.random.default_rng``; the same seed gives the same run, and a
            shorter run (smaller ``steps``) is a prefix of a longer one.
        steps: number of scans; None = the path's natural length (the full double loop).

    Returns:
        The dataset, all scans precomputed.
    """
    cfg = sim_config if sim_config is not None else SimConfig()
    if steps is not None and steps < 1:
        raise ConfigError(f"steps must be ≥ 1, got {steps}")
    true_poses = world.path.sample(cfg.step_m, steps)
    n = true_poses.shape[0]
    # Independent streams for odometry and range noise, so each is a prefix-stable sequence.
    odo_rng, range_rng = (np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(2))

    true_inc = relative_increments(true_poses)
    odo_inc = true_inc + motion_sigmas(true_inc, cfg.motion) * odo_rng.standard_normal((n, 3))
    odo_inc[0] = 0.0  # the first frame is the starting point, not a motion
    odo_poses = np.vstack([true_poses[:1], compose_increments(true_poses[0], odo_inc[1:])])

    angles = cfg.beam_angles()
    world_angles = true_poses[:, 2:3] + angles[None, :]  # (N, m)
    origins = np.repeat(true_poses[:, :2], angles.shape[0], axis=0)
    exact = world.ray_cast(origins, world_angles.reshape(-1), cfg.max_range_m).reshape(n, -1)
    noisy = exact + cfg.sigma_range_m * range_rng.standard_normal(exact.shape)
    ranges = np.where(np.isfinite(exact), noisy, cfg.max_range_m)

    stamps = np.arange(n) * cfg.scan_period_s
    return SimulatedDataset(
        name=f"sim:{world.name}:seed{seed}",
        world=world,
        config=cfg,
        seed=seed,
        ground_truth=Trajectory(stamps, true_poses),
        true_increments=true_inc,
        odometry_increments=odo_inc,
        odometry_poses=odo_poses,
        beam_angles=angles,
        ranges=ranges,
    )
