"""The map figure of a run: walls or splines, scan points and trajectories, saved to files."""

from __future__ import annotations

import os
import textwrap
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np

from bsslam.errors import InputError
from bsslam.viz.figures import new_figure, save_figure
from bsslam.viz.map_plots import (Curve, map_style, plot_points, plot_pose_ellipses, plot_splines, plot_trajectory,
                                  plot_walls)


def save_map_figure(
    paths: Sequence[str | os.PathLike],
    *,
    walls: Sequence[np.ndarray] | None = None,
    curves: Iterable[Curve] = (),
    true_poses: np.ndarray | None = None,
    est_poses: np.ndarray | None = None,
    est_covariances: np.ndarray | None = None,
    odom_poses: np.ndarray | None = None,
    points: np.ndarray | None = None,
    title: str = "",
    control_points: bool = False,
) -> list[Path]:
    """Draw one map figure and write it to every path (format from the suffix, e.g. PNG at
    150 dpi and SVG).

    Args:
        paths: files to write.
        walls: true walls as (k, 2) polylines (m), for simulated runs.
        curves: map splines (``.evaluate``, ``.domain``, ``.control_points``).
        true_poses, est_poses, odom_poses: (N, 3) trajectories (m, rad).
        est_covariances: (N, 3, 3) covariances of ``est_poses``: 2σ ellipses every 10 poses.
        points: (k, 2) scan points (m), drawn as faint dots under everything (thinned and
            rasterised when many).
        title: figure title.
        control_points: also draw the splines' control points and polygons.

    Line widths and marker sizes follow the map's extent (:func:`map_style`).

    Returns:
        The paths written.
    """
    if est_covariances is not None and est_poses is None:
        raise InputError("est_covariances given without est_poses")
    curves = list(curves)
    lo, hi = _map_bounds(curves, walls, true_poses, est_poses)
    style = map_style(float(np.max(hi - lo)))
    fig = new_figure()
    ax = fig.add_subplot()
    if points is not None:
        plot_points(ax, points)
    if walls is not None:
        plot_walls(ax, walls, linewidth=0.75 * style.spline_linewidth)
    plot_splines(ax, curves, control_points=control_points, style=style)
    if odom_poses is not None:
        plot_trajectory(ax, odom_poses, "odometry", color="tab:orange", linewidth=0.8 * style.trajectory_linewidth)
    if true_poses is not None:
        plot_trajectory(ax, true_poses, "ground truth", color="tab:green", linewidth=style.trajectory_linewidth)
    if est_poses is not None:
        plot_trajectory(ax, est_poses, "estimate", color="tab:blue", linewidth=style.trajectory_linewidth)
        if est_covariances is not None:
            plot_pose_ellipses(ax, est_poses, est_covariances, linewidth=style.ellipse_linewidth)
    if np.all(hi >= lo):
        pad = 0.05 * max(float(np.max(hi - lo)), 1.0)
        ax.set_xlim(lo[0] - pad, hi[0] + pad)
        ax.set_ylim(lo[1] - pad, hi[1] + pad)
    # Both limits are fixed by the frame, so the equal aspect must shrink the axes box:
    # with adjustable="datalim" matplotlib would override one of the limits (and log a
    # warning on every save).
    ax.set_aspect("equal", adjustable="box")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    if title:
        ax.set_title("\n".join(textwrap.wrap(title, 90)), fontsize="medium")
    handles, labels = ax.get_legend_handles_labels()
    if handles:
        # Outside the axes: never hides the map, and "best" placement is slow with many points.
        fig.legend(handles, labels, loc="outside right upper", fontsize="small")
    return save_figure(fig, paths)


def _map_bounds(curves, walls, true_poses, est_poses) -> tuple[np.ndarray, np.ndarray]:
    """(2,) lower and upper corners of the map and the estimated and true paths (m); empty
    (lo > hi) when there is nothing. Raw odometry is left out: on a real log it can drift
    tens of metres away and would shrink the map to a corner."""
    parts = [np.asarray(w, dtype=float).reshape(-1, 2) for w in (walls or [])]
    parts += [np.asarray(c.control_points, dtype=float) for c in curves]
    parts += [np.asarray(p, dtype=float)[:, :2] for p in (true_poses, est_poses) if p is not None and len(p)]
    parts = [p for p in parts if len(p)]
    if not parts:
        return np.full(2, np.inf), np.full(2, -np.inf)
    xy = np.vstack(parts)
    return xy.min(axis=0), xy.max(axis=0)
