"""Plotting: functions that take an ``ax`` first and return it, and ``save_*`` helpers that
are the only ones writing files.

The figures are built without pyplot (``matplotlib.figure.Figure`` and its own canvas),
so they need no display and the package never switches matplotlib's backend: importing
bsslam leaves a notebook's inline plots alone.
"""

from bsslam.viz.consistency_plots import (plot_errors_with_bounds, plot_nees, plot_nees_over_time,
                                          plot_sigma_over_updates)
from bsslam.viz.figures import new_figure, save_figure
from bsslam.viz.map_figure import save_map_figure
from bsslam.viz.map_plots import (
    MapStyle,
    map_style,
    plot_points,
    plot_pose_ellipses,
    plot_splines,
    plot_trajectory,
    plot_walls,
)

__all__ = [
    "MapStyle",
    "map_style",
    "new_figure",
    "plot_errors_with_bounds",
    "plot_nees",
    "plot_nees_over_time",
    "plot_points",
    "plot_pose_ellipses",
    "plot_sigma_over_updates",
    "plot_splines",
    "plot_trajectory",
    "plot_walls",
    "save_figure",
    "save_map_figure",
]
