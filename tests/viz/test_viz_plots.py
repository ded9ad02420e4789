"""viz: thin checks that files are written and axes hold the expected artists."""

import math

import numpy as np
import pytest
from matplotlib.collections import EllipseCollection, LineCollection

from bsslam.errors import InputError
from bsslam.viz import (
    map_style,
    new_figure,
    plot_errors_with_bounds,
    plot_nees,
    plot_pose_ellipses,
    plot_sigma_over_updates,
    plot_splines,
    plot_trajectory,
    plot_walls,
    save_map_figure,
)


class FakeCurve:
    """A straight 'spline' from (0, 0) to (2, 1) with three control points."""

    domain = (0.0, 1.0)
    control_points = np.array([[0.0, 0.0], [1.0, 0.5], [2.0, 1.0]])

    def evaluate(self, t):
        t = np.asarray(t, dtype=float)
        return np.column_stack([2.0 * t, t])


def circle_poses(n=40):
    a = np.linspace(0.0, 2 * math.pi, n)
    return np.column_stack([3 * np.cos(a), 3 * np.sin(a), a + math.pi / 2])


def test_walls_and_splines_become_collections_with_the_given_geometry():
    ax = new_figure().add_subplot()
    walls = [np.array([[0.0, 0.0], [4.0, 0.0]]), np.array([[4.0, 0.0], [4.0, 3.0], [0.0, 3.0]])]
    assert plot_walls(ax, walls) is ax
    assert plot_splines(ax, [FakeCurve(), FakeCurve()]) is ax
    collections = [c for c in ax.collections if isinstance(c, LineCollection)]
    wall_lines, spline_lines, polygons = collections
    assert len(wall_lines.get_segments()) == 2
    sampled = spline_lines.get_segments()[0]
    np.testing.assert_allclose(sampled[[0, -1]], [[0.0, 0.0], [2.0, 1.0]])
    np.testing.assert_allclose(polygons.get_segments()[1], FakeCurve.control_points)
    labels = ax.get_legend_handles_labels()[1]
    assert {"walls", "splines", "control points"} <= set(labels)


def test_splines_without_control_points_draw_only_curves():
    ax = new_figure().add_subplot()
    plot_splines(ax, [FakeCurve()], control_points=False)
    assert len(ax.collections) == 1 and not ax.lines


def test_sizes_shrink_with_the_map_extent_to_a_floor():
    small, building, block, campus, huge = (map_style(e) for e in (10.0, 40.0, 200.0, 1000.0, 1e6))
    assert small == building                           # full size up to 40 m
    assert campus.control_point_size < small.control_point_size
    assert campus.spline_linewidth < small.spline_linewidth
    assert block.control_point_size == pytest.approx(small.control_point_size * 40.0 / 200.0)
    assert block.trajectory_linewidth == pytest.approx(small.trajectory_linewidth * 40.0 / 200.0)
    assert huge == campus                              # the floor: still visible
    assert campus.spline_linewidth == pytest.approx(0.15 * small.spline_linewidth)
    assert map_style(0.0) == small and map_style(float("nan")) == small


def _map_figure_axes(tmp_path, monkeypatch, extent_m, **kwargs):
    """The axes of the figure save_map_figure writes for a straight spline ``extent_m`` wide."""
    import matplotlib.figure

    class Long(FakeCurve):
        control_points = FakeCurve.control_points * extent_m / 2.0

        def evaluate(self, t):
            return FakeCurve.evaluate(self, t) * extent_m / 2.0

    saved = []
    original = matplotlib.figure.Figure.savefig

    def keep_and_save(fig, *args, **kw):
        saved.append(fig)
        return original(fig, *args, **kw)

    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", keep_and_save)
    save_map_figure([tmp_path / "m.png"], curves=[Long()], **kwargs)
    (ax,) = saved[0].axes
    return ax


def test_map_figure_scales_sizes_and_draws_control_points_only_when_asked(tmp_path, monkeypatch):
    ax = _map_figure_axes(tmp_path, monkeypatch, 10.0)
    assert "control points" not in ax.get_legend_handles_labels()[1]
    assert not [line for line in ax.lines if line.get_marker() == "o"]
    (curves,) = [c for c in ax.collections if isinstance(c, LineCollection)]
    assert curves.get_linewidths()[0] == pytest.approx(map_style(10.0).spline_linewidth)

    small = _map_figure_axes(tmp_path, monkeypatch, 10.0, control_points=True)
    large = _map_figure_axes(tmp_path, monkeypatch, 1000.0, control_points=True)
    (small_dots,) = [line for line in small.lines if line.get_marker() == "o"]
    (large_dots,) = [line for line in large.lines if line.get_marker() == "o"]
    assert large_dots.get_markersize() < small_dots.get_markersize()
    assert large_dots.get_markersize() == pytest.approx(map_style(1000.0).control_point_size)
    # the extent is the map's: 2 × 1000/2 m wide
    assert large.get_xlim()[1] - large.get_xlim()[0] > 1000.0


def test_trajectory_line_has_the_poses():
    ax = new_figure().add_subplot()
    poses = circle_poses()
    plot_trajectory(ax, poses, "truth", color="k", linestyle="--")
    (line,) = ax.lines
    np.testing.assert_allclose(line.get_xydata(), poses[:, :2])
    assert line.get_label() == "truth" and line.get_linestyle() == "--"
    with pytest.raises(InputError):
        plot_trajectory(ax, poses[:, :2], "bad")


def test_pose_ellipses_have_nsigma_axes_along_the_covariance():
    ax = new_figure().add_subplot()
    poses = circle_poses(25)
    # σx = 0.3, σy = 0.1, rotated by 30°.
    c, s = math.cos(math.radians(30)), math.sin(math.radians(30))
    rot = np.array([[c, -s], [s, c]])
    cov = np.zeros((25, 3, 3))
    cov[:, :2, :2] = rot @ np.diag([0.09, 0.01]) @ rot.T
    cov[:, 2, 2] = 0.01
    plot_pose_ellipses(ax, poses, cov, every=10, nsigma=2)
    (ellipses,) = [c for c in ax.collections if isinstance(c, EllipseCollection)]
    np.testing.assert_allclose(ellipses.get_offsets(), poses[[0, 10, 20], :2])
    # Full axis lengths 2·nsigma·σ along the principal axes; angles in degrees.
    np.testing.assert_allclose(ellipses.get_widths(), 4 * 0.3)
    np.testing.assert_allclose(ellipses.get_heights(), 4 * 0.1)
    np.testing.assert_allclose(np.mod(ellipses.get_angles(), 180.0), 30.0)
    with pytest.raises(InputError):
        plot_pose_ellipses(ax, poses, cov[:3])


def test_map_figure_is_written_to_png_and_svg_and_many_points_stay_small(tmp_path):
    rng = np.random.default_rng(0)
    points = rng.uniform(-5, 5, size=(500_000, 2))
    poses = circle_poses()
    cov = np.tile(np.diag([0.01, 0.02, 0.001]), (len(poses), 1, 1))
    paths = [tmp_path / "map.png", tmp_path / "map.svg"]
    written = save_map_figure(paths, walls=[np.array([[-5.0, -5.0], [5.0, -5.0]])], curves=[FakeCurve()],
                              true_poses=poses, est_poses=poses + 0.05, est_covariances=cov, odom_poses=poses * 1.1,
                              points=points, title="test map")
    assert written == paths
    assert paths[0].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    svg = paths[1].read_text()
    assert svg.lstrip().startswith("<?xml") and "<svg" in svg
    assert "test map" in svg and "ground truth" in svg and "odometry" in svg
    # Rasterised and thinned: far less than one vector marker per point.
    assert paths[1].stat().st_size < 3_000_000


def test_map_figure_refuses_covariances_without_poses(tmp_path):
    with pytest.raises(InputError):
        save_map_figure([tmp_path / "x.png"], est_covariances=np.zeros((1, 3, 3)))


def test_nees_errors_and_sigma_plots_hold_their_lines():
    fig = new_figure()
    ax = fig.add_subplot()
    steps = np.arange(50)
    plot_nees(ax, steps, np.full(50, 3.0), 2.36, 3.72, "E2.A")
    assert ax.get_title() == "E2.A" and len(ax.lines) == 1 and len(ax.collections) == 1
    np.testing.assert_allclose(ax.lines[0].get_ydata(), 3.0)

    axes = new_figure().subplots(3, 1)
    errors = np.column_stack([np.sin(steps / 5), np.cos(steps / 5), 0.1 * np.ones(50)]) * 0.1
    sigmas = np.full((50, 3), 0.2)
    plot_errors_with_bounds(axes, steps, errors, sigmas)
    for i, a in enumerate(axes):
        err, up, down = a.lines
        np.testing.assert_allclose(err.get_ydata(), errors[:, i])
        np.testing.assert_allclose(up.get_ydata(), 0.4)
        np.testing.assert_allclose(down.get_ydata(), -0.4)
    with pytest.raises(InputError):
        plot_errors_with_bounds(axes[:2], steps, errors, sigmas)

    ax = new_figure().add_subplot()
    updates = np.arange(1, 21)
    plot_sigma_over_updates(ax, updates, {0.2: 0.2 / updates, 0.01: 0.01 / np.sqrt(updates)})
    assert [line.get_label() for line in ax.lines] == ["σφ(0) = 0.01 rad", "σφ(0) = 0.2 rad"]
    assert ax.get_yscale() == "log"
