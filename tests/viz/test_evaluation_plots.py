"""The evaluation picture: the drawn data are the data given, times from the first pose."""

import numpy as np

from bsslam.viz import new_figure
from bsslam.viz.evaluation_plots import plot_aligned_trajectories, plot_error_over_time


def test_error_over_time_draws_the_errors_against_seconds_since_the_first_pose():
    ax = new_figure().add_subplot()
    stamps = 1e9 + np.array([0.5, 1.5, 4.0])
    errors = np.array([0.1, 0.0, 0.3])
    plot_error_over_time(ax, stamps, errors)
    (line,) = ax.lines
    np.testing.assert_array_equal(line.get_xdata(), [0.0, 1.0, 3.5])
    np.testing.assert_array_equal(line.get_ydata(), errors)


def test_aligned_trajectories_draw_both_paths_labelled():
    ax = new_figure().add_subplot()
    ref = np.column_stack([np.arange(5.0), np.zeros(5), np.zeros(5)])
    est = ref + [0.0, 0.1, 0.0]
    plot_aligned_trajectories(ax, est, ref)
    drawn = {line.get_label(): np.column_stack([line.get_xdata(), line.get_ydata()]) for line in ax.lines}
    np.testing.assert_array_equal(drawn["reference"], ref[:, :2])
    np.testing.assert_array_equal(drawn["estimate"], est[:, :2])
