"""The map figure of a run: walls or splines, scan points and trajectories, saved to files."""

from __future__ import annotations

import os
import textwrap
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np

from bsslam.errors import InputError
from bsslam.viz.figures import new_figure, save_figure
from bsslam.viz.map_plots import Curve, plot_points, plot_pose_ellipses, plot_splines, plot_trajectory, plot_walls


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

    Returns:
        The paths written.
    """
    if est_covariances is not None and est_poses is None:
        raise InputError("est_covariances given without est_poses")
    fig = new_figure()
    ax = fig.add_subplot()
    if points is not None:
        plot_points(ax, points)
    if walls is not None:
        plot_walls(ax, walls)
    plot_splines(ax, curves)
    if odom_poses is not None:
        plot_trajectory(ax, odom_poses, "odometry", color="tab:orange", linewidth=0.8)
    if true_poses is not None:
        plot_trajectory(ax, true_poses, "ground truth", color="tab:green", linewidth=1.0)
    if est_poses is not None:
        plot_trajectory(ax, est_poses, "estimate", color="tab:blue", linewidth=1.0)
        if est_covariances is not None:
            plot_pose_ellipses(ax, est_poses, est_covariances)
    _frame_map(ax, curves, walls, true_poses, est_poses)
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


def _frame_map(ax, curves, walls, true_poses, est_poses, margin: float = 0.05) -> None:
    """Limit the axes to the map and the estimated and true paths: raw odometry on a real
    log can drift tens of metres away and would shrink the map to a corner."""
    parts = [np.asarray(w, dtype=float).reshape(-1, 2) for w in (walls or [])]
    parts += [c.control_points for c in curves]
    parts += [np.asarray(p, dtype=float)[:, :2] for p in (true_poses, est_poses) if p is not None and len(p)]
    if not parts:
        return
    xy = np.vstack(parts)
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    pad = margin * max(float(np.max(hi - lo)), 1.0)
    ax.set_xlim(lo[0] - pad, hi[0] + pad)
    ax.set_ylim(lo[1] - pad, hi[1] + pad)
