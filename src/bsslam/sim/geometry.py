"""Exact 2D wall geometry for simulated worlds, and ray casting against it.

Three wall primitives, each exact (no tessellation in the ray caster):

- :class:`Segment`: a straight wall between two points;
- :class:`Arc`: a counter-clockwise circular arc (a full circle is a round pillar);
- :class:`PolarCurve`: ``r(φ) = r₀ + a·sin(k·φ + ψ)`` about a centre over an angle interval,
  e.g. the paper's curved wall ``z = 5 + 0.5 sin(5φ)``, φ ∈ [0, π] (eq. 12).

:class:`WallSet` packs walls into arrays once; :func:`ray_cast` intersects many beams with
all walls at once: segments and arcs in closed form, polar curves by a bracketed,
safeguarded Newton solve, all vectorised over beams.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from typing import Sequence, Union

import numpy as np

from bsslam.errors import ConfigError

# A hit closer than this to the ray's origin is the wall the sensor stands on, not a return.
_MIN_HIT_M = 1e-9
# Segment ends overlap by this fraction so beams through a shared corner cannot leak out.
_SEGMENT_END_TOLERANCE = 1e-9
# Beams are cast in chunks so the (beams × grid) work arrays of the polar solver stay small.
_CHUNK_BEAMS = 8192


@dataclass(frozen=True)
class Segment:
    """A straight wall from ``start`` to ``end`` (m, world frame)."""

    start: tuple[float, float]
    end: tuple[float, float]

    def __post_init__(self) -> None:
        if math.dist(self.start, self.end) <= 0:
            raise ConfigError(f"segment {self.start}–{self.end} has zero length")

    @property
    def length_m(self) -> float:
        return math.dist(self.start, self.end)

    def points(self, step_m: float) -> np.ndarray:
        """(k, 2) points along the wall, at most ``step_m`` apart, ends included (m)."""
        k = max(2, math.ceil(self.length_m / step_m) + 1)
        s = np.linspace(0.0, 1.0, k)[:, None]
        return (1.0 - s) * np.asarray(self.start) + s * np.asarray(self.end)


@dataclass(frozen=True)
class Arc:
    """A circular wall: centre (m), radius (m), counter-clockwise from ``start_rad`` over
    ``span_rad`` ∈ (0, 2π] (rad); ``span_rad = 2π`` is a full circle (a pillar)."""

    center: tuple[float, float]
    radius_m: float
    start_rad: float
    span_rad: float

    def __post_init__(self) -> None:
        if not self.radius_m > 0:
            raise ConfigError(f"arc radius must be > 0, got {self.radius_m}")
        if not 0 < self.span_rad <= 2 * math.pi:
            raise ConfigError(f"arc span must be in (0, 2π], got {self.span_rad}")

    @property
    def length_m(self) -> float:
        return self.radius_m * self.span_rad

    def points(self, step_m: float) -> np.ndarray:
        """(k, 2) points along the arc, at most ``step_m`` apart (arc length), ends included."""
        k = max(2, math.ceil(self.length_m / step_m) + 1)
        phi = self.start_rad + np.linspace(0.0, self.span_rad, k)
        return np.asarray(self.center) + self.radius_m * np.column_stack([np.cos(phi), np.sin(phi)])


@dataclass(frozen=True)
class PolarCurve:
    """A wall ``c + r(φ)·(cos φ, sin φ)``, ``r(φ) = base_radius_m + amplitude_m·sin(frequency·φ
    + phase_rad)`` (m), for φ ∈ [phi_start_rad, phi_end_rad] (rad) about ``center`` (m)."""

    center: tuple[float, float]
    base_radius_m: float
    amplitude_m: float
    frequency: float
    phase_rad: float
    phi_start_rad: float
    phi_end_rad: float

    def __post_init__(self) -> None:
        if not self.base_radius_m > abs(self.amplitude_m):
            raise ConfigError("polar curve needs base_radius_m > |amplitude_m| so that r(φ) > 0")
        if not 0 < self.phi_end_rad - self.phi_start_rad <= 2 * math.pi:
            raise ConfigError("polar curve angle interval must have length in (0, 2π]")

    def radius(self, phi: np.ndarray) -> np.ndarray:
        """r(φ) (m) for angles φ (rad) of any shape."""
        return self.base_radius_m + self.amplitude_m * np.sin(self.frequency * phi + self.phase_rad)

    def radius_derivative(self, phi: np.ndarray) -> np.ndarray:
        """dr/dφ (m/rad)."""
        return self.amplitude_m * self.frequency * np.cos(self.frequency * phi + self.phase_rad)

    def point(self, phi: np.ndarray) -> np.ndarray:
        """(..., 2) points of the curve at angles φ (m)."""
        phi = np.asarray(phi, dtype=float)
        r = self.radius(phi)
        return np.asarray(self.center) + np.stack([r * np.cos(phi), r * np.sin(phi)], axis=-1)

    @property
    def bracket_grid_size(self) -> int:
        """Samples of φ used to bracket ray intersections: 24 per wave period and 128 per
        full turn, so that only near-grazing pairs of roots can fall between samples."""
        span = self.phi_end_rad - self.phi_start_rad
        return max(64, math.ceil(span / (2 * math.pi) * (24 * abs(self.frequency) + 128)))

    def points(self, step_m: float) -> np.ndarray:
        """(k, 2) points along the curve, about ``step_m`` apart (arc length), ends included."""
        fine = self.point(np.linspace(self.phi_start_rad, self.phi_end_rad, 40 * self.bracket_grid_size))
        length = float(np.sum(np.linalg.norm(np.diff(fine, axis=0), axis=1)))
        k = max(2, math.ceil(length / step_m) + 1)
        # Uniform in φ, refined until the largest chord is below the step (r varies slowly).
        while True:
            pts = self.point(np.linspace(self.phi_start_rad, self.phi_end_rad, k))
            if np.max(np.linalg.norm(np.diff(pts, axis=0), axis=1)) <= step_m:
                return pts
            k = math.ceil(k * 1.25)


Wall = Union[Segment, Arc, PolarCurve]


@dataclass(frozen=True)
class WallSet:
    """All walls of a world, packed into arrays for vectorised ray casting."""

    walls: tuple[Wall, ...]

    def __post_init__(self) -> None:
        object.__setattr__(self, "walls", tuple(self.walls))
        for wall in self.walls:
            if not isinstance(wall, (Segment, Arc, PolarCurve)):
                raise ConfigError(f"unknown wall type {type(wall).__name__}")

    @cached_property
    def _segments(self) -> tuple[np.ndarray, np.ndarray]:
        """Segment starts (S, 2) and start→end vectors (S, 2) (m)."""
        segs = [w for w in self.walls if isinstance(w, Segment)]
        starts = np.array([s.start for s in segs], dtype=float).reshape(-1, 2)
        ends = np.array([s.end for s in segs], dtype=float).reshape(-1, 2)
        return starts, ends - starts

    @cached_property
    def _arcs(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Arc centres (A, 2) (m), radii (A,) (m), start angles (A,) and spans (A,) (rad)."""
        arcs = [w for w in self.walls if isinstance(w, Arc)]
        return (
            np.array([a.center for a in arcs], dtype=float).reshape(-1, 2),
            np.array([a.radius_m for a in arcs], dtype=float),
            np.array([a.start_rad for a in arcs], dtype=float),
            np.array([a.span_rad for a in arcs], dtype=float),
        )

    @property
    def _polar_curves(self) -> list[PolarCurve]:
        return [w for w in self.walls if isinstance(w, PolarCurve)]

    def polylines(self, step_m: float = 0.05) -> list[np.ndarray]:
        """One (k, 2) polyline per wall, points at most ~``step_m`` apart (m), for drawing."""
        if not step_m > 0:
            raise ConfigError(f"polyline step must be > 0, got {step_m}")
        return [w.points(step_m) for w in self.walls]


def ray_cast(walls: WallSet | Sequence[Wall], origin: np.ndarray, angles: np.ndarray, max_range: float) -> np.ndarray:
    """Exact distance along each beam to the nearest wall.

    Args:
        walls: a :class:`WallSet` (or a sequence of walls, packed on the fly).
        origin: (2,) common origin of the beams, or (m, 2) one origin per beam (m).
        angles: (m,) beam directions in the world frame (rad).
        max_range: hits farther than this are ignored (m).

    Returns:
        (m,) ranges (m); ``np.inf`` where no wall lies within ``max_range``.
    """
    if not isinstance(walls, WallSet):
        walls = WallSet(tuple(walls))
    angles = np.asarray(angles, dtype=float).reshape(-1)
    origins = np.broadcast_to(np.asarray(origin, dtype=float), (angles.shape[0], 2))
    ranges = np.full(angles.shape[0], np.inf)
    for lo in range(0, angles.shape[0], _CHUNK_BEAMS):
        sl = slice(lo, lo + _CHUNK_BEAMS)
        dirs = np.column_stack([np.cos(angles[sl]), np.sin(angles[sl])])
        hit = np.minimum(_cast_segments(walls, origins[sl], dirs), _cast_arcs(walls, origins[sl], dirs))
        for curve in walls._polar_curves:
            hit = np.minimum(hit, _cast_polar_curve(curve, origins[sl], angles[sl], dirs, max_range))
        hit[hit > max_range] = np.inf
        ranges[sl] = hit
    return ranges


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """z component of the 2D cross product, broadcasting over leading axes."""
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def _cast_segments(walls: WallSet, origins: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """(m,) nearest segment hit per beam (m), inf if none. origins, dirs: (m, 2)."""
    starts, vecs = walls._segments
    if starts.shape[0] == 0:
        return np.full(origins.shape[0], np.inf)
    # o + t·u = p + s·v  ⇒  t = (w × v)/(u × v), s = (w × u)/(u × v) with w = p − o.
    w = starts[None, :, :] - origins[:, None, :]  # (m, S, 2)
    u = dirs[:, None, :]
    denom = _cross(u, vecs[None, :, :])  # (m, S)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = _cross(w, vecs[None, :, :]) / denom
        s = _cross(w, u) / denom
    ok = (denom != 0) & (t > _MIN_HIT_M) & (s >= -_SEGMENT_END_TOLERANCE) & (s <= 1 + _SEGMENT_END_TOLERANCE)
    return np.where(ok, t, np.inf).min(axis=1)


def _cast_arcs(walls: WallSet, origins: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """(m,) nearest arc hit per beam (m), inf if none. origins, dirs: (m, 2)."""
    centers, radii, starts, spans = walls._arcs
    if centers.shape[0] == 0:
        return np.full(origins.shape[0], np.inf)
    # |o + t·u − c|² = R²  ⇒  t² + 2 b t + c₀ = 0 with b = u·(o − c), c₀ = |o − c|² − R².
    oc = origins[:, None, :] - centers[None, :, :]  # (m, A, 2)
    b = np.einsum("mad,md->ma", oc, dirs)
    c0 = np.einsum("mad,mad->ma", oc, oc) - radii[None, :] ** 2
    disc = b * b - c0
    root = np.sqrt(np.maximum(disc, 0.0))
    best = np.full(origins.shape[0], np.inf)
    for t in (-b - root, -b + root):  # the two crossings of the full circle
        hit = oc + t[..., None] * dirs[:, None, :]
        rel = np.mod(np.arctan2(hit[..., 1], hit[..., 0]) - starts[None, :], 2 * np.pi)
        # A hit just before the start angle wraps to ≈2π: accept it only within tolerance.
        on_arc = (rel <= spans[None, :] + 1e-12) | (rel >= 2 * np.pi - 1e-12)
        ok = (disc >= 0) & (t > _MIN_HIT_M) & on_arc
        best = np.minimum(best, np.where(ok, t, np.inf).min(axis=1))
    return best


def _cast_polar_curve(
    curve: PolarCurve, origins: np.ndarray, angles: np.ndarray, dirs: np.ndarray, max_range: float
) -> np.ndarray:
    """(m,) nearest hit of each beam on one polar curve (m), inf if none.

    The curve point at angle φ lies on the beam's line where
    ``g(φ) = u × (c − o) + r(φ)·sin(φ − β) = 0`` (β the beam direction), a smooth function of
    φ. Roots are bracketed by sign changes on a grid of φ, refined by Newton's method kept
    inside its bracket (bisection when a step leaves it), and kept where the distance along
    the beam ``t = u·(c − o) + r(φ)·cos(φ − β)`` is positive.
    """
    m = origins.shape[0]
    best = np.full(m, np.inf)
    center = np.asarray(curve.center)
    w = center[None, :] - origins  # (m, 2)
    d = _cross(dirs, w)
    along = np.einsum("md,md->m", dirs, w)
    # Cull beams whose reachable segment [0, max_range] stays outside the curve's annulus.
    closest_t = np.clip(along, 0.0, max_range)
    gap = np.linalg.norm(w - closest_t[:, None] * dirs, axis=1)
    live = np.flatnonzero(gap <= curve.base_radius_m + abs(curve.amplitude_m))
    if live.size == 0:
        return best
    d, along, beta = d[live], along[live], angles[live]

    grid = np.linspace(curve.phi_start_rad, curve.phi_end_rad, curve.bracket_grid_size)
    r_grid = curve.radius(grid)
    # sin(φ − β) = sin φ cos β − cos φ sin β, as outer products over (beam, grid).
    g = d[:, None] + r_grid[None, :] * (np.sin(grid)[None, :] * np.cos(beta)[:, None] - np.cos(grid)[None, :] * np.sin(beta)[:, None])
    beam_idx, cell = np.nonzero(g[:, :-1] * g[:, 1:] <= 0)
    if beam_idx.size == 0:
        return best
    lo, hi = grid[cell], grid[cell + 1]
    g_lo = g[beam_idx, cell]
    d_b, beta_b = d[beam_idx], beta[beam_idx]

    def g_and_slope(phi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        r, dr = curve.radius(phi), curve.radius_derivative(phi)
        s, c = np.sin(phi - beta_b), np.cos(phi - beta_b)
        return d_b + r * s, dr * s + r * c

    phi = 0.5 * (lo + hi)
    for _ in range(100):
        val, slope = g_and_slope(phi)
        same_side = np.sign(val) == np.sign(g_lo)
        lo = np.where(same_side, phi, lo)
        g_lo = np.where(same_side, val, g_lo)
        hi = np.where(same_side, hi, phi)
        with np.errstate(divide="ignore", invalid="ignore"):
            newton = phi - val / slope
        inside = np.isfinite(newton) & (newton >= lo) & (newton <= hi)
        nxt = np.where(inside, newton, 0.5 * (lo + hi))
        nxt = np.where(val == 0, phi, nxt)
        converged = np.all(np.abs(nxt - phi) <= 4 * np.spacing(np.abs(phi) + 1.0))
        phi = nxt
        if converged:
            break
    phi = np.clip(phi, curve.phi_start_rad, curve.phi_end_rad)
    t = along[beam_idx] + curve.radius(phi) * np.cos(phi - beta_b)
    t = np.where(t > _MIN_HIT_M, t, np.inf)
    np.minimum.at(best, live[beam_idx], t)
    return best


def rounded_rectangle_walls(
    xmin: float, ymin: float, xmax: float, ymax: float, radii: tuple[float, float, float, float]
) -> tuple[Wall, ...]:
    """The walls of an axis-aligned rectangle (m) whose corners are quarter circles.

    Args:
        radii: corner radii (bottom-left, bottom-right, top-right, top-left) (m); 0 gives a
            sharp corner.

    Returns:
        Segments and arcs in counter-clockwise order, starting with the bottom edge.
    """
    bl, br, tr, tl = radii
    if min(radii) < 0 or bl + br > xmax - xmin or tl + tr > xmax - xmin or bl + tl > ymax - ymin or br + tr > ymax - ymin:
        raise ConfigError(f"corner radii {radii} do not fit a {xmax - xmin} × {ymax - ymin} m rectangle")
    edges = [
        ((xmin + bl, ymin), (xmax - br, ymin)),
        ((xmax, ymin + br), (xmax, ymax - tr)),
        ((xmax - tr, ymax), (xmin + tl, ymax)),
        ((xmin, ymax - tl), (xmin, ymin + bl)),
    ]
    corners = [  # (centre, radius, start angle), following each edge counter-clockwise
        ((xmax - br, ymin + br), br, -math.pi / 2),
        ((xmax - tr, ymax - tr), tr, 0.0),
        ((xmin + tl, ymax - tl), tl, math.pi / 2),
        ((xmin + bl, ymin + bl), bl, math.pi),
    ]
    walls: list[Wall] = []
    for (start, end), (center, radius, start_rad) in zip(edges, corners):
        if math.dist(start, end) > 0:
            walls.append(Segment(start, end))
        if radius > 0:
            walls.append(Arc(center, radius, start_rad, math.pi / 2))
    return tuple(walls)
