"""Pictures of a trajectory evaluation: the estimate aligned onto its reference, and the
position error of the matched poses over time."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from matplotlib.axes import Axes

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
                           stamps: np.ndarray, position_error_m: np.ndarray, title: str = "") -> Path:
    """Both plots side by side, written to ``path`` (format from its suffix)."""
    fig = new_figure(12.0, 5.0)
    ax_map, ax_error = fig.subplots(1, 2, width_ratios=(1.2, 1))
    plot_aligned_trajectories(ax_map, estimate_poses, reference_poses)
    plot_error_over_time(ax_error, stamps, position_error_m)
    if title:
        fig.suptitle(title, fontsize="medium")
    return save_figure(fig, [path])[0]
