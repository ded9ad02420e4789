"""Plotting: functions that take an ``ax`` first and return it, and ``save_*`` helpers that
are the only ones writing files.

The non-interactive Agg backend is selected here, once, so plotting works on machines
without a display; the figures themselves are built without pyplot.
"""

import matplotlib

matplotlib.use("Agg")

from bsslam.viz.consistency_plots import plot_errors_with_bounds, plot_nees, plot_sigma_over_updates  # noqa: E402
from bsslam.viz.figures import new_figure, save_figure  # noqa: E402
from bsslam.viz.map_figure import save_map_figure  # noqa: E402
from bsslam.viz.map_plots import (  # noqa: E402
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
    "plot_points",
    "plot_pose_ellipses",
    "plot_sigma_over_updates",
    "plot_splines",
    "plot_trajectory",
    "plot_walls",
    "save_figure",
    "save_map_figure",
]
