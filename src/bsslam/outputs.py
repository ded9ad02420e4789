"""Write a run's results folder: trajectory, covariances, map (JSON, metric SVG, GeoJSON),
occupancy grid, pictures, summary.

One function serves ``bsslam simulate`` and ``bsslam run``, so both produce the same files.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bsslam.config import SLAMConfig
from bsslam.eval import ate, pose_errors
from bsslam.helper_process import HelperProcess
from bsslam.io.atomic_file import atomic_write
from bsslam.io.config_file import write_config
from bsslam.io.grid import build_occupancy_grid, write_grid
from bsslam.io.map_file import write_map_json
from bsslam.io.pose_covariance_file import write_pose_covariance_csv
from bsslam.io.results import write_summary
from bsslam.io.trajectory_file import write_tum
from bsslam.io.vector_map import write_map_geojson, write_map_svg
from bsslam.pipeline import RunResult
from bsslam.trajectory import Trajectory


def sample_curves(curves, step_m: float = 0.02) -> list[np.ndarray]:
    """Polylines (k, 2) along each curve, about ``step_m`` apart."""
    out = []
    for c in curves:
        lo, hi = c.domain
        n = max(2, int(np.ceil((hi - lo) / step_m)) + 1)
        out.append(c.evaluate(np.linspace(lo, hi, n)))
    return out


def summarize(result: RunResult, reference: Trajectory | None = None, exact_reference: bool = False) -> dict:
    """The summary.json contents. ``reference`` (or the dataset's ground truth) adds ATE;
    an exact reference (simulation) also adds the final error and the mean pose NEES.

    ATE is that of the reported trajectory (relocalised when the run has a second pass),
    with the online filter's beside it; NEES is the online filter's, whose covariances are
    the joint ones (the second pass's are relative to the map)."""
    est = result.trajectory
    ref = reference if reference is not None else result.ground_truth
    n_cp = sum(m.curve.n_control for m in result.map)
    summary = {
        "name": result.name,
        "scans": result.steps,
        "wall_time_s": round(result.wall_time_s, 3),
        "relocalize_time_s": round(result.relocalize_time_s, 3),
        "loop_sweep_time_s": round(result.sweep_time_s, 3),
        "ms_per_step": round(1000.0 * result.wall_time_s / max(result.steps, 1), 3),
        "splines": len(result.map),
        "control_points": int(n_cp),
        "backend": "submaps" if getattr(result, "submaps", None) is not None else "ekf",
        "state_size": int(result.state_sizes[-1]) if result.steps else 3,
        "max_state_size": int(result.state_sizes.max()) if result.steps else 3,
        **{k: int(v) for k, v in sorted(result.totals.items())},
        "skipped_input": int(result.skipped.total),
        "skipped_input_by_reason": dict(result.skipped.counts),
        "ignored_input": dict(result.skipped.ignored),   # message types the reader does not use
    }
    if getattr(result, "submaps", None) is not None:
        # splines of two submaps on one wall are one surface: the map's walls counted once
        summary["surfaces"] = len({m.surface for m in result.map})
        rate, sigma = result.submaps.graph.drift_rate()
        if sigma > 0:    # the seams' shared heading drift, as the loop closures found it
            summary["drift_rate_deg_per_100m"] = round(float(np.degrees(rate) * 100.0), 4)
            summary["drift_rate_sigma_deg_per_100m"] = round(float(np.degrees(sigma) * 100.0), 4)
    # ATE aligns the trajectory rigidly, which takes two poses: a run of one scan (--steps 1,
    # or one interrupted at its first) has none to report
    if ref is not None and len(ref) and result.steps >= 2:
        rmse, matched, _ = ate(est, ref)
        summary["ate_m"] = round(float(rmse), 5)
        summary["ate_matched_poses"] = int(matched)
        if result.relocalized is not None:
            summary["online_ate_m"] = round(float(ate(result.estimate, ref)[0]), 5)
        odo_rmse, _, _ = ate(result.odometry, ref)
        summary["odometry_ate_m"] = round(float(odo_rmse), 5)
        if result.frontend is not None:
            summary["frontend_ate_m"] = round(float(ate(result.frontend, ref)[0]), 5)
        if exact_reference and len(ref) == len(est):
            err = pose_errors(result.estimate, ref)
            summary["final_position_error_m"] = round(float(np.hypot(*err.errors[-1, :2])), 5)
            summary["final_heading_error_rad"] = round(float(err.errors[-1, 2]), 6)
            # step 0 has zero covariance (it defines the map frame): NaN, left out
            summary["mean_nees"] = round(float(np.nanmean(err.nees)), 4) if len(est) > 1 else None
    return summary


def write_run_grid(result: RunResult, run_dir: Path, config: SLAMConfig) -> None:
    """``grid.pgm`` + ``grid.yaml``: every scan at its reported pose, the splines drawn in."""
    grid_config = config.grid
    curves = [m.curve for m in result.map]
    # a result without scans (built by other code) still gets the splines drawn in
    poses = result.trajectory.poses if result.scans else np.empty((0, 3))
    grid = build_occupancy_grid(result.scans, poses, grid_config,
                                sample_curves(curves, grid_config.resolution_m / 4))
    write_grid(run_dir / "grid.pgm", run_dir / "grid.yaml",
               grid.image(grid_config.occupied_thresh, grid_config.free_thresh), grid.origin, grid.resolution_m,
               grid_config.occupied_thresh, grid_config.free_thresh)


def write_vector_maps(run_dir: Path, splines) -> None:
    """``map_metric.svg`` (exact Bézier paths in metres) and ``map.geojson`` (line strings)."""
    write_map_svg(run_dir / "map_metric.svg", splines)
    write_map_geojson(run_dir / "map.geojson", splines)


def write_steps_csv(path: Path, result: RunResult) -> None:
    """``steps.csv``: one row per scan — stamp (s), the time spent on it (ms: front end and,
    where it ran, the filter; a submap's freeze and loop closure count on the scan that
    ended it; the front end not included where a helper process ran it), the state dimension after it, its submap (0 with ``backend: ekf``), the
    update's NIS and its degrees of freedom (0: no filter step)."""
    submap = getattr(result, "step_submaps", None)
    submap = np.zeros(result.steps, dtype=int) if submap is None else submap
    with atomic_write(path, "w", newline="") as f:
        f.write("stamp_s,time_ms,state_size,submap,nis,nis_dof\n")
        for row in zip(result.estimate.stamps, result.step_times_s, result.state_sizes, submap, result.nis,
                       result.nis_dof):
            f.write(f"{row[0]:.6f},{1000 * row[1]:.4f},{row[2]},{row[3]},{row[4]:.6g},{row[5]}\n")


def _save_map_figure(*args, **kwargs):
    """:func:`bsslam.viz.save_map_figure`, imported when called: a process whose picture a
    helper process draws never imports matplotlib (most of a second)."""
    from bsslam.viz.map_figure import save_map_figure

    return save_map_figure(*args, **kwargs)


def _now(fn, *args, **kwargs):
    """``fn(*args, **kwargs)`` called now, as :meth:`HelperProcess.call` would later: a
    function returning its result."""
    value = fn(*args, **kwargs)
    return lambda: value


def write_outputs(result: RunResult, run_dir: Path, config: SLAMConfig, *, walls=None,
                  reference: Trajectory | None = None, exact_reference: bool = False,
                  title: str = "", show_control_points: bool = False, extra: dict | None = None,
                  helper: HelperProcess | None = None) -> dict:
    """Write every output file into ``run_dir`` and return the summary; the pictures show
    the splines' control points when ``show_control_points``; ``extra`` entries are added
    to the summary (e.g. the checkpoints' figures). With a ``helper`` process, the map
    picture is drawn there while this process writes the other files.

    Each file is written atomically; ``summary.json`` comes last, so its presence with
    ``"status": "complete"`` says every other file is there and whole
    (:func:`bsslam.io.results.publish_run` relies on it). A result the pipeline marked
    ``interrupted`` (the scans before a Ctrl-C or SIGTERM) is written the same way with
    ``"status": "interrupted"``.
    """
    run_dir = Path(run_dir)
    ref = reference if reference is not None else result.ground_truth
    curves = [m.curve for m in result.map]
    figure = (helper.call if helper is not None else _now)(
        _save_map_figure, [run_dir / "map.png", run_dir / "map.svg"], walls=walls, curves=curves,
        true_poses=None if ref is None else ref.poses, est_poses=result.trajectory.poses,
        est_covariances=result.trajectory.covariances, odom_poses=result.odometry.poses,
        points=result.points if len(result.points) else None, title=title or result.name,
        control_points=show_control_points)
    write_config(run_dir / "config.yaml", config)
    write_tum(run_dir / "trajectory.tum", result.trajectory)
    write_pose_covariance_csv(run_dir / "pose_covariance.csv", result.trajectory)
    if result.relocalized is not None:
        write_tum(run_dir / "trajectory_online.tum", result.estimate)
        write_pose_covariance_csv(run_dir / "pose_covariance_online.csv", result.estimate)
    write_steps_csv(run_dir / "steps.csv", result)
    write_tum(run_dir / "odometry.tum", result.odometry)
    if result.frontend is not None:
        write_tum(run_dir / "frontend.tum", result.frontend)
    if result.ground_truth is not None:
        write_tum(run_dir / "ground_truth.tum", result.ground_truth)
    write_map_json(run_dir / "map.json", result.map)
    write_run_grid(result, run_dir, config)
    write_vector_maps(run_dir, result.map)
    figure()    # the picture is written (or its error raised) before the summary says complete
    summary = {**summarize(result, reference, exact_reference), **(extra or {})}
    if getattr(result, "interrupted", False):
        why = getattr(result, "stop_reason", None) or "interrupted"
        return write_summary(run_dir, summary, "interrupted",
                             f"{why}: stopped after {result.steps} scans; the files hold those scans")
    return write_summary(run_dir, summary, "complete")
