"""Plots of the fit-quality experiments (paper Figs. 2–3): range MSE against knot spacing
and against spline order, and one noisy scan with the splines fitted to it.

Every function takes the axes first, draws, and returns the axes.
"""

from __future__ import annotations

from typing import Protocol, Sequence

import numpy as np
from matplotlib.axes import Axes
from matplotlib.ticker import FixedFormatter, FixedLocator, NullFormatter

from bsslam.errors import InputError

_ORDER_NAMES = {2: "linear", 3: "quadratic", 4: "cubic", 5: "quartic"}


class Curve(Protocol):
    """What :func:`plot_fit_example` needs of a spline (e.g. ``bsslam.spline.BSplineCurve``)."""

    @property
    def domain(self) -> tuple[float, float]: ...

    def evaluate(self, t: np.ndarray) -> np.ndarray: ...


def plot_mse_vs_spacing(ax: Axes, spacings_m: Sequence[float], mse_m2: Sequence[float]) -> Axes:
    """Mean range MSE (m²) against knot spacing (m), both axes logarithmic (paper Fig. 2)."""
    x, y = _pair(spacings_m, mse_m2)
    order = np.argsort(x)
    ax.loglog(x[order], y[order], "o-", color="tab:blue")
    # Label the spacings tried, not the decades: they are what a reader looks up.
    ax.xaxis.set_major_locator(FixedLocator(x[order]))
    ax.xaxis.set_major_formatter(FixedFormatter([f"{v:g}" for v in x[order]]))
    ax.xaxis.set_minor_formatter(NullFormatter())
    ax.set_xlabel("knot spacing ρ [m]")
    ax.set_ylabel("mean range MSE [m²]")
    ax.set_title("cubic fit: error against knot spacing")
    ax.grid(True, which="both", alpha=0.3)
    return ax


def plot_mse_vs_order(ax: Axes, orders: Sequence[int], mse_m2: Sequence[float]) -> Axes:
    """Mean range MSE (m²) against spline order κ = degree + 1 (paper Fig. 3), log y axis."""
    x, y = _pair(orders, mse_m2)
    ax.semilogy(x, y, "o-", color="tab:blue")
    ax.set_xticks(x, [f"{int(k)}\n{_ORDER_NAMES.get(int(k), '')}" for k in x])
    ax.set_xlabel("order κ")
    ax.set_ylabel("mean range MSE [m²]")
    ax.set_title("error against spline order")
    ax.grid(True, which="both", alpha=0.3)
    return ax


def plot_fit_example(ax: Axes, true_points: np.ndarray, points: np.ndarray,
                     curves: Sequence[tuple[str, Curve]], samples_per_curve: int = 400) -> Axes:
    """The true wall (n, 2), the noisy scan points (k, 2) and the labelled fitted curves (m),
    with the sensor at the origin."""
    true_points = np.asarray(true_points, dtype=float)
    points = np.asarray(points, dtype=float)
    ax.plot(true_points[:, 0], true_points[:, 1], color="0.3", linewidth=1.0, label="true wall")
    ax.plot(points[:, 0], points[:, 1], ".", color="0.6", markersize=3, label="scan points")
    for label, curve in curves:
        lo, hi = curve.domain
        xy = np.asarray(curve.evaluate(np.linspace(lo, hi, samples_per_curve)), dtype=float)
        ax.plot(xy[:, 0], xy[:, 1], linewidth=1.3, label=label)
    ax.plot([0.0], [0.0], "k^", label="sensor")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.legend(loc="center", fontsize="small")  # the wall arches around an empty middle
    return ax


def _pair(x: Sequence[float], y: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    if x.ndim != 1 or x.shape != y.shape:
        raise InputError(f"x {x.shape} and y {y.shape} must be equal 1-D arrays")
    return x, y
