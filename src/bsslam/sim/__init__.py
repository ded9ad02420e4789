"""Simulated worlds with exact geometry and a laser/odometry simulator.

Typical use::

    from bsslam.sim import get_world, simulate, SimConfig
    data = simulate(get_world("rounded-room"), SimConfig(), seed=3)
    for frame in data: ...          # Frame(stamp, odometry pose, scan)
    data.ground_truth.poses         # (N, 3) exact poses
"""

from bsslam.sim.geometry import Arc, PolarCurve, Segment, WallSet, ray_cast, rounded_rectangle_walls
from bsslam.sim.paths import LoopPath, StationaryPath, rounded_rectangle_loop
from bsslam.sim.simulator import (
    SimConfig,
    SimulatedDataset,
    compose_increments,
    relative_increments,
    simulate,
)
from bsslam.sim.worlds import DEFAULT_WORLD, WORLDS, World, get_world

__all__ = [
    "Arc",
    "DEFAULT_WORLD",
    "LoopPath",
    "PolarCurve",
    "Segment",
    "SimConfig",
    "SimulatedDataset",
    "StationaryPath",
    "WORLDS",
    "WallSet",
    "World",
    "compose_increments",
    "get_world",
    "relative_increments",
    "ray_cast",
    "rounded_rectangle_loop",
    "rounded_rectangle_walls",
    "simulate",
]
