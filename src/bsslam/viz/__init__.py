"""Plotting: functions that take an ``ax`` first and return it, and ``save_*`` helpers that
are the only ones writing files.

The figures are built without pyplot (``matplotlib.figure.Figure`` and its own canvas),
so they need no display and the package never switches matplotlib's backend: importing
bsslam leaves a notebook's inline plots alone.
"""

import importlib

# name -> the module that defines it; imported on first use (PEP 562), so that importing
# one light module of the package (the null viewer, which the mapper uses) does not import
# matplotlib, which takes most of a second
_WHERE = {
    "plot_errors_with_bounds": "consistency_plots", "plot_nees": "consistency_plots",
    "plot_nees_over_time": "consistency_plots", "plot_sigma_over_updates": "consistency_plots",
    "new_figure": "figures", "save_figure": "figures", "save_map_figure": "map_figure",
    "MapStyle": "map_plots", "map_style": "map_plots", "plot_points": "map_plots",
    "plot_pose_ellipses": "map_plots", "plot_splines": "map_plots", "plot_trajectory": "map_plots",
    "plot_walls": "map_plots",
}


def __getattr__(name: str):
    if name in _WHERE:
        return getattr(importlib.import_module(f"bsslam.viz.{_WHERE[name]}"), name)
    raise AttributeError(f"module 'bsslam.viz' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(list(globals()) + list(_WHERE))


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
