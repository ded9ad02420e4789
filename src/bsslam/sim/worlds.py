"""The built-in simulated worlds: exact walls plus the path the robot drives.

The paper's synthetic experiments (§10 of the spec): a static sensor facing the curved wall
``z = 5 + 0.5 sin(5φ)`` (Figs. 2, 3, 11), and three environments mixing straight and curved
walls in which the robot drives a double loop (Figs. 9, 10, 12). Look a world up with
:func:`get_world`; :data:`WORLDS` lists them all.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from bsslam.errors import ConfigError
from bsslam.sim.geometry import Arc, PolarCurve, Segment, WallSet, ray_cast, rounded_rectangle_walls
from bsslam.sim.paths import LoopPath, StationaryPath, rounded_rectangle_loop


@dataclass(frozen=True)
class World:
    """A simulated environment.

    Attributes:
        name: registry key, e.g. ``"rounded-room"``.
        description: one line for listings.
        walls: the exact geometry the laser sees.
        path: where the robot is at each scan (a double loop, or a stationary pose).
    """

    name: str
    description: str
    walls: WallSet
    path: LoopPath | StationaryPath

    def polylines(self, step_m: float = 0.05) -> list[np.ndarray]:
        """One (k, 2) polyline per wall (m), points at most ~``step_m`` apart, for drawing."""
        return self.walls.polylines(step_m)

    def ray_cast(self, origin: np.ndarray, angles: np.ndarray, max_range: float) -> np.ndarray:
        """(m,) exact ranges (m) from ``origin`` (2,) or (m, 2) along world-frame ``angles``
        (m,) (rad); ``np.inf`` where nothing lies within ``max_range``. See
        :func:`bsslam.sim.geometry.ray_cast`."""
        return ray_cast(self.walls, origin, angles, max_range)


def _curved_wall() -> World:
    wall = PolarCurve(center=(0.0, 0.0), base_radius_m=5.0, amplitude_m=0.5, frequency=5.0,
                      phase_rad=0.0, phi_start_rad=0.0, phi_end_rad=math.pi)
    return World(
        name="curved-wall",
        description="the paper's curved wall z = 5 + 0.5 sin(5φ), φ ∈ [0, π], seen by a static sensor at its centre",
        walls=WallSet((wall,)),
        # Heading π/2 puts the 180° field of view exactly over φ ∈ [0, π].
        path=StationaryPath(pose=(0.0, 0.0, math.pi / 2)),
    )


def _rounded_room() -> World:
    # The paper's E2: a 14 × 10 m room with rounded corners of radii 4 m and 2 m; an island
    # concentric with the 4 m corners leaves a 3 m wide corridor for the loop.
    outer = rounded_rectangle_walls(0.0, 0.0, 14.0, 10.0, radii=(4.0, 2.0, 4.0, 2.0))
    island = rounded_rectangle_walls(3.0, 3.0, 11.0, 7.0, radii=(1.0, 0.5, 1.0, 0.5))
    return World(
        name="rounded-room",
        description="the paper's E2: 14 × 10 m room with 4 m and 2 m rounded corners around a rounded island",
        walls=WallSet(outer + island),
        path=rounded_rectangle_loop(1.5, 1.5, 12.5, 8.5, radii=(2.5, 1.0, 2.5, 1.0)),
    )


def _corridor_loop() -> World:
    # A 2.5 m wide corridor around an 18 × 12 m block; corners concentric (3 m outside,
    # 0.5 m inside), the robot on the corridor's centre line.
    outer = rounded_rectangle_walls(0.0, 0.0, 18.0, 12.0, radii=(3.0, 3.0, 3.0, 3.0))
    inner = rounded_rectangle_walls(2.5, 2.5, 15.5, 9.5, radii=(0.5, 0.5, 0.5, 0.5))
    return World(
        name="corridor-loop",
        description="a 2.5 m wide rectangular corridor loop (18 × 12 m) with rounded corners",
        walls=WallSet(outer + inner),
        path=rounded_rectangle_loop(1.25, 1.25, 16.75, 10.75, radii=(1.75, 1.75, 1.75, 1.75)),
    )


def _mixed() -> World:
    # Top wall: a wavy arc r(φ) = 32 + 0.35 sin(50φ) about a centre 20 m below the floor;
    # its ends, at φ = π/2 ± 0.08π, are where sin(50φ) = 0, so they sit exactly on the
    # big circle and the straight side walls meet them there.
    half = 0.08 * math.pi
    width = 2 * 32.0 * math.sin(half)
    y_end = -20.0 + 32.0 * math.cos(half)
    wavy = PolarCurve(center=(width / 2, -20.0), base_radius_m=32.0, amplitude_m=0.35, frequency=50.0,
                      phase_rad=0.0, phi_start_rad=math.pi / 2 - half, phi_end_rad=math.pi / 2 + half)
    corner = 3.0
    walls = (
        Segment((0.0, 0.0), (width - corner, 0.0)),
        Arc((width - corner, corner), corner, -math.pi / 2, math.pi / 2),
        Segment((width, corner), (width, y_end)),
        wavy,
        Segment((0.0, y_end), (0.0, 0.0)),
        Arc((width / 2, 5.5), 1.0, 0.0, 2 * math.pi),  # the round pillar
    )
    return World(
        name="mixed",
        description="straight walls, a rounded corner, a wavy top wall and a round pillar (16 × 12 m)",
        walls=WallSet(walls),
        path=rounded_rectangle_loop(2.5, 2.2, width - 2.5, 8.3, radii=(2.0, 2.0, 2.0, 2.0)),
    )


def large_corridor(width_m: float = 30.0, height_m: float = 20.0) -> World:
    """A 3 m wide corridor loop inside outer walls of width_m × height_m (m), corners rounded
    concentrically (3.5 m outside, 0.5 m inside), the robot on the centre line, starting
    on the straight stretch along the x axis. Not in :data:`WORLDS`: the benchmarks' long
    corridors (``bench_filter.py``, ``corridor_consistency.py``) and the tests of what a
    straight wall may tell the filter along itself."""
    w, h = width_m, height_m
    outer = rounded_rectangle_walls(0.0, 0.0, w, h, radii=(3.5, 3.5, 3.5, 3.5))
    inner = rounded_rectangle_walls(3.0, 3.0, w - 3.0, h - 3.0, radii=(0.5, 0.5, 0.5, 0.5))
    return World(name="large-corridor", description=f"3 m wide corridor loop, {w:g} × {h:g} m",
                 walls=WallSet(outer + inner),
                 path=rounded_rectangle_loop(1.5, 1.5, w - 1.5, h - 1.5, radii=(2.0, 2.0, 2.0, 2.0)))


WORLDS: dict[str, World] = {w.name: w for w in (_rounded_room(), _corridor_loop(), _mixed(), _curved_wall())}
"""Every built-in world by name; ``rounded-room`` is the default of the demos."""

DEFAULT_WORLD = "rounded-room"


def get_world(name: str) -> World:
    """The built-in world called ``name``; ConfigError listing the known names otherwise."""
    try:
        return WORLDS[name]
    except KeyError:
        raise ConfigError(f"unknown world {name!r}; known worlds: {', '.join(sorted(WORLDS))}") from None
