"""Filter consistency plots (paper Figs. 10–12): NEES against its χ² band (averaged over
runs, or one run's per-pose NEES over time), pose errors against their ±2σ bounds, and
heading σ over repeated updates.

Every function takes the axes first, draws, and returns the axes.
"""

from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np
from matplotlib.axes import Axes

from bsslam.errors import InputError

_POSE_COMPONENTS = (("x", "m"), ("y", "m"), ("φ", "rad"))


def plot_nees(ax: Axes, steps: np.ndarray, mean_nees: np.ndarray, lower: float | np.ndarray,
              upper: float | np.ndarray, title: str = "") -> Axes:
    """Mean NEES (N,) over ``steps`` (N,), with the probability band [lower, upper]
    (scalars or (N,) arrays) shaded."""
    steps = np.asarray(steps, dtype=float)
    nees = np.asarray(mean_nees, dtype=float)
    if nees.shape != steps.shape:
        raise InputError(f"mean_nees {nees.shape} and steps {steps.shape} differ in shape")
    ax.fill_between(steps, np.broadcast_to(lower, steps.shape), np.broadcast_to(upper, steps.shape),
                    color="tab:green", alpha=0.2, label="95% band")
    ax.plot(steps, nees, color="tab:blue", label="mean NEES")
    ax.set_xlabel("step")
    ax.set_ylabel("NEES")
    if title:
        ax.set_title(title)
    ax.legend(loc="best", fontsize="small")
    return ax


def plot_nees_over_time(ax: Axes, stamps: np.ndarray, nees: np.ndarray, band: tuple[float, float],
                        upper_95: float, t0: float | None = None, title: str = "") -> Axes:
    """Per-pose NEES (N,) against time (s since ``t0``, default the first of ``stamps`` (N,))
    on a log scale — a filter's NEES spans decades — with the two-sided band
    (lower, upper) shaded and the one-sided 95 % quantile ``upper_95`` drawn."""
    stamps = np.asarray(stamps, dtype=float)
    values = np.asarray(nees, dtype=float)
    if values.shape != stamps.shape:
        raise InputError(f"nees {values.shape} and stamps {stamps.shape} differ in shape")
    if t0 is None:
        t0 = float(stamps[0]) if stamps.size else 0.0
    t = stamps - t0
    ax.axhspan(band[0], band[1], color="tab:green", alpha=0.2,
               label=f"χ²(3) 2.5–97.5 % [{band[0]:.3g}, {band[1]:.3g}]")
    ax.axhline(upper_95, color="tab:red", linestyle="--", linewidth=1.0, label=f"χ²(3) 95 % = {upper_95:.3g}")
    ax.plot(t, values, color="tab:blue", linewidth=0.8, marker=".", markersize=2, label="NEES")
    ax.set_yscale("log")
    ax.set_xlabel("time since the first pose [s]")
    ax.set_ylabel("NEES")
    ax.grid(True, which="major", alpha=0.3)
    if title:
        ax.set_title(title, fontsize="medium")
    ax.legend(loc="best", fontsize="small")
    return ax


def plot_errors_with_bounds(axes: Sequence[Axes], steps: np.ndarray, errors: np.ndarray,
                            sigmas: np.ndarray) -> Sequence[Axes]:
    """Pose errors (N, 3) (x m, y m, φ rad) over ``steps`` (N,), each on its own axes with the
    ±2σ bounds from ``sigmas`` (N, 3)."""
    steps = np.asarray(steps, dtype=float)
    err = np.asarray(errors, dtype=float)
    sig = np.asarray(sigmas, dtype=float)
    if len(axes) != 3 or err.shape != (steps.shape[0], 3) or sig.shape != err.shape:
        raise InputError(f"need 3 axes and errors/sigmas of shape ({steps.shape[0]}, 3), "
                         f"got {len(axes)} axes, {err.shape}, {sig.shape}")
    for i, (ax, (name, unit)) in enumerate(zip(axes, _POSE_COMPONENTS)):
        ax.plot(steps, err[:, i], color="tab:blue", label="error")
        ax.plot(steps, 2 * sig[:, i], color="tab:red", linestyle="--", label="±2σ")
        ax.plot(steps, -2 * sig[:, i], color="tab:red", linestyle="--")
        ax.set_ylabel(f"{name} [{unit}]")
    axes[-1].set_xlabel("step")
    axes[0].legend(loc="best", fontsize="small")
    return axes


def plot_sigma_over_updates(ax: Axes, updates: np.ndarray, sigma_by_initial: Mapping[float, np.ndarray]) -> Axes:
    """Estimated heading σ (rad) over ``updates`` (N,), one line per initial σ (rad), on a
    log scale so very different starting values stay readable (paper Fig. 11)."""
    updates = np.asarray(updates, dtype=float)
    for initial in sorted(sigma_by_initial):
        sigma = np.asarray(sigma_by_initial[initial], dtype=float)
        if sigma.shape != updates.shape:
            raise InputError(f"σ series for initial {initial:g} has shape {sigma.shape}, expected {updates.shape}")
        ax.plot(updates, sigma, label=f"σφ(0) = {initial:g} rad")
    ax.set_yscale("log")
    ax.set_xlabel("update")
    ax.set_ylabel("σφ [rad]")
    ax.legend(loc="best", fontsize="small")
    return ax
