"""Pictures of a trajectory evaluation: the estimate aligned onto its reference, the
position error of the matched poses over time, and, given covariances, their NEES."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from matplotlib.axes import Axes

from bsslam.eval.pose_nees import NeesReport
from bsslam.viz.consistency_plots import plot_nees_over_time
from bsslam.viz.figures import as_poses, new_figure, save_figure
from bsslam.viz.map_plots import plot_trajectory


def plot_aligned_trajectories(ax: Axes, estimate_poses: np.ndarray, reference_poses: np.ndarray) -> Axes:
    """The reference and the (already aligned) estimate, (N, 3) and (M, 3) poses (m), to scale."""
    plot_trajectory(ax, as_poses(reference_poses, "reference_poses"), "reference", color="tab:green", linewidth=1.0)
    plot_trajectory(ax, as_poses(estimate_poses, "estimate_poses"), "estimate", color="tab:blue", linewidth=1.0)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.legend(loc="best", fontsize="small")
    return ax


def plot_error_over_time(ax: Axes, stamps: np.ndarray, position_error_m: np.ndarray) -> Axes:
    """The position error (m) of each matched pose against its time (s since the first)."""
    stamps = np.asarray(stamps, dtype=float)
    t = stamps - stamps[0] if stamps.size else stamps
    ax.plot(t, np.asarray(position_error_m, dtype=float), color="tab:red", linewidth=1.0)
    ax.set_xlabel("time since the first pose [s]")
    ax.set_ylabel("position error [m]")
    ax.set_ylim(bottom=0.0)
    ax.grid(True, alpha=0.3)
    return ax


def save_evaluation_figure(path: str | os.PathLike, estimate_poses: np.ndarray, reference_poses: np.ndarray,
                           stamps: np.ndarray, position_error_m: np.ndarray, title: str = "",
                           nees: NeesReport | None = None) -> Path:
    """Both plots side by side, written to ``path`` (format from its suffix); with ``nees``
    its NEES over time under the position error, on the same clock."""
    if nees is None:
        fig = new_figure(12.0, 5.0)
        ax_map, ax_error = fig.subplots(1, 2, width_ratios=(1.2, 1))
    else:
        fig = new_figure(13.0, 8.0)
        grid = fig.add_gridspec(2, 2, width_ratios=(1.2, 1))
        ax_map, ax_error = fig.add_subplot(grid[:, 0]), fig.add_subplot(grid[0, 1])
        ax_nees = fig.add_subplot(grid[1, 1], sharex=ax_error)
        t0 = float(np.asarray(stamps, dtype=float)[0]) if len(stamps) else None
        plot_nees_over_time(ax_nees, nees.stamps, nees.nees, nees.band_95, nees.upper_95, t0=t0,
                            title=f"NEES: mean {nees.mean:.3g}, median {nees.median:.3g}, "
                                  f"{100 * nees.fraction_outside_95:.1f} % above {nees.upper_95:.3g} "
                                  f"({len(nees.nees)} poses)")
    plot_aligned_trajectories(ax_map, estimate_poses, reference_poses)
    plot_error_over_time(ax_error, stamps, position_error_m)
    if title:
        fig.suptitle(title, fontsize="medium")
    return save_figure(fig, [path])[0]
