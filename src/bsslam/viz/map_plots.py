"""Map drawing: walls, spline features, scan points, trajectories and pose uncertainty.

Every function takes the axes first, draws, and returns the axes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any, Iterable, Protocol, Sequence

import numpy as np
from matplotlib.axes import Axes
from matplotlib.collections import EllipseCollection, LineCollection

from bsslam.errors import InputError
from bsslam.viz.figures import as_poses

# Above this many scan points, draw an even subsample: a map needs density, not every point.
MAX_DRAWN_POINTS = 200_000

# Line widths and marker sizes are in points, the map in metres: the sizes below suit a
# map up to this size (a building floor like Intel's, ~40 m, in the default figure, where
# a metre is ~10 pt); larger maps scale them down in proportion, to a floor.
_FULL_SIZE_EXTENT_M = 40.0
_SMALLEST_SCALE = 0.15


@dataclass(frozen=True)
class MapStyle:
    """Sizes (points) of what a map figure draws.

    Attributes:
        spline_linewidth: the spline curves.
        control_point_size: marker size of the control points; their polygon is drawn at
            a third of ``spline_linewidth``.
        trajectory_linewidth: the estimated and true paths (odometry at 0.8 of it).
        ellipse_linewidth: the pose uncertainty ellipses.
    """

    spline_linewidth: float = 1.6
    control_point_size: float = 2.5
    trajectory_linewidth: float = 1.0
    ellipse_linewidth: float = 0.8


def map_style(extent_m: float) -> MapStyle:
    """The sizes for a map whose larger side is ``extent_m`` (m): full size up to 40 m,
    then in proportion 40 m / extent (never below 0.15 of full size), so a 1.5 km building
    keeps thin lines and dots instead of a smear of markers 1 m apart."""
    if not extent_m > 0:
        extent_m = _FULL_SIZE_EXTENT_M
    scale = float(np.clip(_FULL_SIZE_EXTENT_M / extent_m, _SMALLEST_SCALE, 1.0))
    full = MapStyle()
    return MapStyle(*(scale * getattr(full, f.name) for f in fields(MapStyle)))


class Curve(Protocol):
    """What :func:`plot_splines` needs of a spline (e.g. ``bsslam.spline.BSplineCurve``)."""

    @property
    def domain(self) -> tuple[float, float]: ...

    @property
    def control_points(self) -> np.ndarray: ...

    def evaluate(self, t: np.ndarray) -> np.ndarray: ...


def plot_walls(ax: Axes, polylines: Sequence[np.ndarray], color: str = "black", linewidth: float = 1.2,
               label: str | None = "walls") -> Axes:
    """Draw walls given as (k, 2) polylines (m), in one collection."""
    lines = [np.asarray(p, dtype=float).reshape(-1, 2) for p in polylines]
    ax.add_collection(LineCollection(lines, colors=color, linewidths=linewidth, label=label, zorder=2))
    ax.autoscale_view()
    return ax


def plot_splines(ax: Axes, curves: Iterable[Curve], control_points: bool = True, color: str = "tab:red",
                 samples_per_curve: int = 200, style: MapStyle = MapStyle()) -> Axes:
    """Draw spline curves sampled evenly over their domains, and optionally their control
    polygons and control points (m), at the sizes of ``style``."""
    curves = list(curves)
    if not curves:
        return ax
    lines = []
    for curve in curves:
        lo, hi = curve.domain
        lines.append(np.asarray(curve.evaluate(np.linspace(lo, hi, samples_per_curve)), dtype=float))
    ax.add_collection(LineCollection(lines, colors=color, linewidths=style.spline_linewidth, label="splines",
                                     zorder=4))
    if control_points:
        polygons = [np.asarray(c.control_points, dtype=float) for c in curves]
        ax.add_collection(LineCollection(polygons, colors=color, linewidths=style.spline_linewidth / 3,
                                         linestyles="dotted", alpha=0.7, zorder=4))
        stacked = np.vstack(polygons)
        ax.plot(stacked[:, 0], stacked[:, 1], "o", color=color, markersize=style.control_point_size,
                markeredgewidth=min(1.0, style.control_point_size / 2.5), markerfacecolor="none",
                label="control points", zorder=5)
    ax.autoscale_view()
    return ax


def plot_points(ax: Axes, points: np.ndarray, max_points: int = MAX_DRAWN_POINTS, color: str = "0.6",
                label: str | None = "scan points") -> Axes:
    """Draw (k, 2) points (m) as tiny dots under everything else. Many points are thinned
    to ``max_points`` by an even stride and rasterised, so vector output (SVG/PDF) stays small."""
    pts = np.asarray(points, dtype=float).reshape(-1, 2)
    if pts.shape[0] > max_points:
        pts = pts[:: math.ceil(pts.shape[0] / max_points)]
    ax.scatter(pts[:, 0], pts[:, 1], s=0.3, c=color, marker=".", linewidths=0, rasterized=True, zorder=0)
    if label is not None:  # a legend-sized stand-in: the real dots are too small to see there
        ax.plot([], [], ".", color=color, markersize=5, label=label)
    return ax


def plot_trajectory(ax: Axes, poses: np.ndarray, label: str, **style: Any) -> Axes:
    """Draw the path of (N, 3) poses (m); ``style`` goes to ``Axes.plot`` (which rejects
    unknown keywords)."""
    p = as_poses(poses)
    ax.plot(p[:, 0], p[:, 1], label=label, **style)
    return ax


def plot_pose_ellipses(ax: Axes, poses: np.ndarray, covariances: np.ndarray, every: int = 10, nsigma: float = 2.0,
                       color: str = "tab:blue", linewidth: float = 0.8) -> Axes:
    """Draw the position uncertainty of every ``every``-th pose: the ellipse whose semi-axes
    are ``nsigma`` standard deviations along the principal axes of the (x, y) block of each
    (3, 3) covariance (m²)."""
    p = as_poses(poses)
    cov = np.asarray(covariances, dtype=float)
    if cov.shape != (p.shape[0], 3, 3):
        raise InputError(f"covariances must have shape ({p.shape[0]}, 3, 3), got {cov.shape}")
    if every < 1:
        raise InputError(f"every must be ≥ 1, got {every}")
    idx = np.arange(0, p.shape[0], every)
    variances, axes = np.linalg.eigh(cov[idx, :2, :2])  # ascending eigenvalues
    variances = np.maximum(variances, 0.0)
    major = axes[:, :, 1]
    angles_deg = np.degrees(np.arctan2(major[:, 1], major[:, 0]))
    # EllipseCollection takes full axis lengths.
    widths = 2 * nsigma * np.sqrt(variances[:, 1])
    heights = 2 * nsigma * np.sqrt(variances[:, 0])
    ax.add_collection(EllipseCollection(widths, heights, angles_deg, units="xy", offsets=p[idx, :2],
                                        offset_transform=ax.transData, facecolors="none", edgecolors=color,
                                        linewidths=linewidth, zorder=3))
    # Legends cannot draw an EllipseCollection: an empty line stands in for it.
    ax.plot([], [], color=color, linewidth=0.8, label=f"{nsigma:g}σ position")
    return ax
