"""A live view of a run in rerun (https://rerun.io; the optional extra ``bsslam[viewer]``).

:class:`RerunViewer` is a viewer for :class:`bsslam.Mapper`: after every scan it logs, in
the map frame (m), on the timelines ``scan`` (index) and ``time`` (s since the first scan):

* ``world/scan``: the scan's points at its estimated pose,
* ``world/robot``: the pose as an arrow, ``world/robot/covariance`` its 2σ position ellipse,
* ``world/trajectory/online/<k>``: the online trajectory, in blocks of ``block`` scans
  (each block re-logged as it grows, so the data stays linear in the run's length),
* ``world/ellipses/<k>``: the 2σ ellipses of the filter steps, in the same blocks,
* ``world/map/splines`` and ``world/map/control_points``: the map after each filter step,

and at the end ``world/trajectory/relocalized`` (the second pass) and the final map.
Everything is logged in 3D at z = 0 under a z-up ``world``: rerun's 2D views draw y
downwards (image convention, rerun issue #1387), which would mirror the map; its 3D view
seen from above shows it the right way round.
rerun is imported only when a viewer is made; without it that is a
:class:`~bsslam.errors.MissingDependencyError` naming the extra.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from bsslam.errors import ConfigError, MissingDependencyError

VIEWER_MODES = ("spawn", "save")
RECORDING_FILE = "viewer.rrd"

_ONLINE = (230, 120, 30)       # the online trajectory and its ellipses
_RELOCALIZED = (40, 110, 220)
_SPLINES = (220, 40, 40)
_SCAN = (150, 150, 150)


def _rerun():
    try:
        import rerun
    except ImportError as exc:
        raise MissingDependencyError(f"the live viewer needs rerun-sdk ({exc}): pip install 'bsslam[viewer]'") from None
    return rerun


def open_viewer(mode: str, run_dir: Path | None = None) -> "RerunViewer":
    """A viewer for ``--viewer MODE``: ``spawn`` starts (or connects to) the rerun viewer
    app and streams to it; ``save`` writes ``run_dir/viewer.rrd`` (open it with
    ``rerun viewer.rrd``)."""
    if mode not in VIEWER_MODES:
        raise ConfigError(f"viewer must be one of {', '.join(VIEWER_MODES)}, got {mode!r}")
    if mode == "save":
        if run_dir is None:
            raise ConfigError("viewer 'save' needs a results folder")
        return RerunViewer.save(Path(run_dir) / RECORDING_FILE)
    return RerunViewer.spawn()


def ellipse_outline(center: np.ndarray, covariance: np.ndarray, nsigma: float = 2.0, n: int = 48) -> np.ndarray:
    """(n + 1, 2) closed outline of the ``nsigma`` ellipse of a 2D Gaussian with mean
    ``center`` (2,) and covariance (2, 2) (m²): ``center + nsigma · V √Λ (cos t, sin t)``."""
    variances, axes = np.linalg.eigh(np.asarray(covariance, dtype=float))
    t = np.linspace(0.0, 2.0 * math.pi, n + 1)
    circle = np.stack([np.cos(t), np.sin(t)])                       # (2, n + 1)
    return np.asarray(center, dtype=float) + (nsigma * axes * np.sqrt(np.maximum(variances, 0.0)) @ circle).T


def _xyz(points) -> np.ndarray:
    """(k, 3) float32 of (k, 2) points at z = 0."""
    xy = np.asarray(points, dtype=np.float32).reshape(-1, 2)
    return np.column_stack([xy, np.zeros(len(xy), dtype=np.float32)])


def sample_curve(curve, step_m: float) -> np.ndarray:
    """(k, 2) points along a spline curve, about ``step_m`` apart in its parameter (the
    curves' parameter is close to arc length)."""
    lo, hi = curve.domain
    return curve.evaluate(np.linspace(lo, hi, max(2, int(math.ceil((hi - lo) / step_m)) + 1)))


class RerunViewer:
    """Streams a run to a rerun recording (see the module docstring for what it logs).

    Args:
        recording: a ``rerun.RecordingStream`` with its sink set (see :meth:`save`, :meth:`spawn`).
        block: scans per trajectory block.
        spline_step_m: sampling step of the map splines (m).
        nsigma: size of the position ellipses.
        eye_height_m: height of the view's eye above the first pose (m).
    """

    def __init__(self, recording, *, block: int = 100, spline_step_m: float = 0.05, nsigma: float = 2.0,
                 eye_height_m: float = 40.0) -> None:
        self.rr = _rerun()
        self.recording = recording
        self.block = int(block)
        self.spline_step_m = float(spline_step_m)
        self.nsigma = float(nsigma)
        self.eye_height_m = float(eye_height_m)
        self._scans = 0
        self._t0: float | None = None
        self._trail: list[np.ndarray] = []        # the current block's positions (with the last of the previous)
        self._ellipses: list[np.ndarray] = []     # the current block's filter-step ellipses

    @classmethod
    def save(cls, path: Path, **options) -> "RerunViewer":
        """A viewer writing the recording to ``path`` (.rrd)."""
        rr = _rerun()
        recording = rr.RecordingStream("bsslam")
        recording.save(Path(path))
        return cls(recording, **options)

    @classmethod
    def spawn(cls, **options) -> "RerunViewer":
        """A viewer streaming to the rerun viewer app (started if it is not running)."""
        rr = _rerun()
        recording = rr.RecordingStream("bsslam")
        recording.spawn()
        return cls(recording, **options)

    def _blueprint(self, first_pose: np.ndarray):
        """One 3D view of ``world`` seen from straight above the first pose (y up on the
        screen, as on a map), the time panel on the scan index, following the newest data."""
        rrb = self.rr.blueprint
        x, y = float(first_pose[0]), float(first_pose[1])
        eye = rrb.EyeControls3D(kind=rrb.Eye3DKind.Orbital, position=(x, y, self.eye_height_m),
                                look_target=(x, y, 0.0), eye_up=(0.0, 1.0, 0.0))
        return rrb.Blueprint(rrb.Spatial3DView(origin="/world", name="map", eye_controls=eye, line_grid=False),
                             rrb.TimePanel(timeline="scan", play_state="following"), collapse_panels=False)

    def _log(self, path: str, archetype) -> None:
        self.recording.log(path, archetype)

    def update(self, estimate, points: np.ndarray, mapper) -> None:
        """One scan: its points, the pose with its ellipse, the trajectory and, after a
        filter step, the map."""
        rr = self.rr
        if self._t0 is None:
            self._t0 = estimate.stamp
            self.recording.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
            self.recording.send_blueprint(self._blueprint(estimate.pose))
        self.recording.set_time("scan", sequence=self._scans)
        self.recording.set_time("time", duration=float(estimate.stamp - self._t0))
        pose, cov = np.asarray(estimate.pose, dtype=float), np.asarray(estimate.covariance, dtype=float)
        self._log("world/scan", rr.Points3D(_xyz(points), colors=_SCAN, radii=0.02))
        heading = 0.4 * np.array([math.cos(pose[2]), math.sin(pose[2])])
        self._log("world/robot", rr.Arrows3D(origins=_xyz(pose[:2]), vectors=_xyz(heading), colors=_ONLINE))
        ellipse = _xyz(ellipse_outline(pose[:2], cov[:2, :2], self.nsigma))
        self._log("world/robot/covariance", rr.LineStrips3D([ellipse], colors=_ONLINE, radii=0.01))

        k = self._scans // self.block
        if self._scans % self.block == 0:       # a new block starts where the last one ended
            self._trail = self._trail[-1:]
            self._ellipses = []
        self._trail.append(pose[:2].copy())
        self._log(f"world/trajectory/online/{k}", rr.LineStrips3D([_xyz(self._trail)], colors=_ONLINE, radii=0.02))
        if estimate.filter_step:
            self._ellipses.append(ellipse)
            self._log(f"world/ellipses/{k}", rr.LineStrips3D(self._ellipses, colors=_ONLINE, radii=0.008))
            self._log_map(mapper.curves)
        self._scans += 1

    def _log_map(self, curves) -> None:
        rr = self.rr
        lines = [_xyz(sample_curve(c, self.spline_step_m)) for c in curves]
        self._log("world/map/splines", rr.LineStrips3D(lines, colors=_SPLINES, radii=0.025))
        control = np.vstack([c.control_points for c in curves]) if curves else np.empty((0, 2))
        self._log("world/map/control_points", rr.Points3D(_xyz(control), colors=_SPLINES, radii=0.04))

    def finish(self, result) -> None:
        """The run's end: the second pass's trajectory and the final map; then the
        recording is flushed and closed (the .rrd is complete once this returns)."""
        rr = self.rr
        self.recording.set_time("scan", sequence=max(self._scans - 1, 0))
        if result.relocalized is not None:
            xy = _xyz(result.relocalized.poses[:, :2])
            self._log("world/trajectory/relocalized", rr.LineStrips3D([xy], colors=_RELOCALIZED, radii=0.02))
        self._log_map([m.curve for m in result.map])
        self.recording.flush()
        self.recording.disconnect()     # closes the sink: the .rrd gets its footer
