"""Checkpoints of a run: the whole state written now and then, so that a run killed
midway (SIGKILL, a power cut, a job's time limit) continues where it was
(``bsslam run --resume RUN_DIR``) and ends with the same trajectory and map, bit for bit,
as a run that was never stopped.

A checkpoint is one file in the run folder, :data:`CHECKPOINT_FILE`, written atomically
(:func:`~bsslam.io.atomic_file.atomic_write`: a crash during a write leaves the previous
checkpoint). It holds two pickles one after the other:

1. the header (:class:`CheckpointHeader`): the log's path and SHA-256, the configuration,
   the command line's options and the reader position (the index of the next frame) —
   small, read first, so a resume refuses a changed log before loading anything else;
2. the state: the :class:`~bsslam.mapper.Mapper` (filter, front end, records of every
   scan so far, submap backend with its pose graph).

The log is not stored: a resume reads it again from the start and skips the frames
before the reader position (reading is a small fraction of a run's time), which also
rebuilds the reader's own counters exactly.

A checkpoint is a pickle: load only checkpoints you wrote yourself.
"""

from __future__ import annotations

import hashlib
import math
import os
import pickle
import re
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable

from bsslam import __version__
from bsslam.errors import ConfigError, InputError
from bsslam.io.atomic_file import TEMP_SUFFIX, atomic_write

CHECKPOINT_FILE = "checkpoint.pkl"
#: Bumped whenever the header or the state's layout changes: an older checkpoint is refused.
FORMAT = 12  # 2: the pose graph pickles its arguments by name (loop_outliers); 3: a submap shape carries its walls' σ;
#            4: the front end keeps its last trusted matches (frontend.odometry_gate_steps);
#            5: a loop closure keeps its match's rival alignment (the vote between matches);
#            6: the front end keeps its matches' disagreement with the odometry (odometry_learned_window);
#            7: … in heading too (frontend.fallback_learned);
#            8: the front end's motion compounds the fallbacks' wide covariance alongside (the walls' check);
#            9: the front end carries the fallbacks' error to the match after them;
#            10: … and gates that match with their error as given;
#            11: the two kept as one pair; 12: a loop closure says whether it is a slide (submaps.loop_slides)
_MAGIC = "bsslam-checkpoint"


@dataclass(frozen=True)
class CheckpointEvery:
    """How often a run writes a checkpoint: every ``scans`` frames, or every ``seconds`` of
    wall time, or never (both zero).

    A time interval only decides *when* the state is saved, never what the filter does, so
    it leaves the results unchanged; and a run shorter than it never writes one.
    """

    scans: int = 0
    seconds: float = 0.0

    @classmethod
    def parse(cls, text: str) -> "CheckpointEvery":
        """``"500"`` (frames), ``"60s"`` (seconds of wall time) or ``"0"`` (off).

        Raises:
            ConfigError: anything else (negative, fractional frames, other units).
        """
        value = str(text).strip().lower()
        match = re.fullmatch(r"(\d+)", value)
        if match:
            return cls(scans=int(match.group(1)))
        match = re.fullmatch(r"(\d+(?:\.\d*)?|\.\d+)\s*s", value)
        if match and math.isfinite(float(match.group(1))):
            return cls(seconds=float(match.group(1)))
        raise ConfigError(f"--checkpoint-every takes a number of scans (e.g. 500), seconds (e.g. 60s) or 0 "
                          f"(off), got {text!r}")

    @property
    def enabled(self) -> bool:
        return self.scans > 0 or self.seconds > 0

    def __str__(self) -> str:
        if self.scans:
            return str(self.scans)
        return f"{self.seconds:g}s" if self.seconds else "0"


@dataclass(frozen=True)
class CheckpointHeader:
    """What a checkpoint says about its run (the first pickle of the file).

    Attributes:
        log: the log's absolute path.
        log_sha256: its SHA-256 (:func:`source_digest`) when the run started.
        config: the run's configuration (``SLAMConfig.to_dict()``).
        options: the command line's options that shape the results (format, strict,
            steps, topics, reference, picture options), to run on with the same ones.
        next_frame: the reader position: the index of the first frame not yet processed.
        version: the bsslam version that wrote it; format: :data:`FORMAT`.
    """

    log: str
    log_sha256: str
    config: dict
    options: dict = field(default_factory=dict)
    next_frame: int = 0
    version: str = __version__
    format: int = FORMAT


def source_digest(path: str | os.PathLike) -> str:
    """SHA-256 (hex) of a log: a file's bytes, or for a folder (a ROS 2 bag) every file
    under it, by relative name and bytes in name order.

    Raises:
        InputError: the log cannot be read.
    """
    path = Path(path)
    digest = hashlib.sha256()
    try:
        if path.is_dir():
            for file in sorted(p for p in path.rglob("*") if p.is_file()):
                digest.update(file.relative_to(path).as_posix().encode() + b"\0")
                _hash_file(digest, file)
        else:
            _hash_file(digest, path)
    except OSError as exc:
        raise InputError(f"cannot read the log: {exc.strerror or exc}", os.fspath(path)) from None
    return digest.hexdigest()


def _hash_file(digest, path: Path) -> None:
    with open(path, "rb") as f:
        while chunk := f.read(1 << 20):
            digest.update(chunk)


class Checkpointer:
    """Writes a run's checkpoint into its folder when one is due; the pipeline calls it
    after every frame (:func:`bsslam.pipeline.run_dataset`, ``checkpoint=``).

    Args:
        run_dir: the run folder (the file is ``run_dir/checkpoint.pkl``).
        every: when (:class:`CheckpointEvery`); off writes nothing.
        header: the run's header; ``next_frame`` is filled in at each write, and an empty
            ``log_sha256`` at the first (a run that never writes one never hashes its log).
        start_frame: the frame the run starts at (a resumed run's reader position).
        clock: seconds, monotonic (for tests).

    Attributes:
        writes: checkpoints written; last_bytes: size of the last; write_seconds: the
        slowest write (pickling, fsync and rename).
    """

    def __init__(self, run_dir: str | os.PathLike, every: CheckpointEvery, header: CheckpointHeader, *,
                 start_frame: int = 0, clock: Callable[[], float] = time.monotonic) -> None:
        self.path = Path(run_dir) / CHECKPOINT_FILE
        # a run killed while writing leaves its temporary (atomic_write's naming); this
        # run is the folder's only writer now
        for stale in self.path.parent.glob(f".{CHECKPOINT_FILE}.*{TEMP_SUFFIX}"):
            stale.unlink(missing_ok=True)
        self.every = every
        self.header = header
        self._clock = clock
        self._last_frame = start_frame
        self._last_time = clock()
        self.writes = 0
        self.last_bytes = 0
        self.write_seconds = 0.0

    def due(self, next_frame: int) -> bool:
        """Whether a checkpoint is due after the frames before ``next_frame``."""
        if self.every.scans:
            return next_frame - self._last_frame >= self.every.scans
        if self.every.seconds:
            return self._clock() - self._last_time >= self.every.seconds
        return False

    def __call__(self, next_frame: int, state: Any) -> None:
        """Write a checkpoint of ``state`` (the mapper) if one is due."""
        if self.due(next_frame):
            self.write(next_frame, state)

    def write(self, next_frame: int, state: Any) -> None:
        """Write a checkpoint now: ``state`` with the frames before ``next_frame`` processed.

        Raises:
            InputError: the file cannot be written (the previous checkpoint stays).
        """
        if not self.header.log_sha256:
            self.header = CheckpointHeader(**{**asdict(self.header), "log_sha256": source_digest(self.header.log)})
        t0 = time.perf_counter()
        header = CheckpointHeader(**{**asdict(self.header), "next_frame": int(next_frame)})
        with atomic_write(self.path, "wb") as f:
            pickle.dump({"magic": _MAGIC, **asdict(header)}, f, protocol=pickle.HIGHEST_PROTOCOL)
            pickle.dump(state, f, protocol=pickle.HIGHEST_PROTOCOL)
            self.last_bytes = f.tell()
        self.write_seconds = max(self.write_seconds, time.perf_counter() - t0)
        self.writes += 1
        self._last_frame = next_frame
        self._last_time = self._clock()   # after the write: a slow write does not make the next one due at once

    def remove(self) -> None:
        """Delete the checkpoint (a run that completed needs none)."""
        try:
            self.path.unlink()
        except FileNotFoundError:
            pass
        except OSError as exc:
            raise InputError(f"cannot remove the checkpoint: {exc.strerror or exc}", os.fspath(self.path)) from None

    def figures(self) -> dict[str, Any]:
        """The checkpoints' figures for a run's summary (empty when none was written)."""
        if not self.writes:
            return {}
        return {"checkpoints": self.writes, "checkpoint_mb": round(self.last_bytes / 2 ** 20, 2),
                "checkpoint_write_s": round(self.write_seconds, 3)}


def _open_checkpoint(run_dir: str | os.PathLike):
    path = Path(run_dir) / CHECKPOINT_FILE
    if not Path(run_dir).is_dir():
        raise InputError("no such run folder", os.fspath(run_dir))
    try:
        return path, open(path, "rb")
    except FileNotFoundError:
        raise InputError("the run folder has no checkpoint (the run completed, or ran with "
                         "--checkpoint-every 0 or too briefly to write one)", os.fspath(run_dir)) from None
    except OSError as exc:
        raise InputError(f"cannot read the checkpoint: {exc.strerror or exc}", os.fspath(path)) from None


def _read_header(f, path: Path) -> CheckpointHeader:
    try:
        document = pickle.load(f)
    except Exception:   # a pickle raises nearly anything on bad bytes
        raise InputError("not a readable bsslam checkpoint", os.fspath(path)) from None
    if not isinstance(document, dict) or document.pop("magic", None) != _MAGIC:
        raise InputError("not a bsslam checkpoint", os.fspath(path))
    if document.get("format") != FORMAT:
        raise InputError(f"a checkpoint of format {document.get('format')} (bsslam {document.get('version')}); "
                         f"this bsslam reads format {FORMAT}", os.fspath(path))
    return CheckpointHeader(**document)


def read_header(run_dir: str | os.PathLike) -> CheckpointHeader:
    """The header of ``run_dir``'s checkpoint (the state is not loaded).

    Raises:
        InputError: no run folder, no checkpoint in it, or not one this bsslam wrote.
    """
    path, f = _open_checkpoint(run_dir)
    with f:
        return _read_header(f, path)


def check_source(header: CheckpointHeader) -> None:
    """Refuse a log that is gone or changed since the checkpoint's run started.

    Raises:
        InputError: naming the log.
    """
    if not os.path.exists(header.log):
        raise InputError("the checkpoint's log is gone", header.log)
    if source_digest(header.log) != header.log_sha256:
        raise InputError("the log changed since the checkpoint was written (SHA-256 differs); "
                         "a resume needs the same log", header.log)


def load_checkpoint(run_dir: str | os.PathLike) -> tuple[CheckpointHeader, Any]:
    """The header and the state (the mapper) of ``run_dir``'s checkpoint.

    Raises:
        InputError: as :func:`read_header`, or the state cannot be unpickled.
    """
    path, f = _open_checkpoint(run_dir)
    with f:
        header = _read_header(f, path)
        try:
            state = pickle.load(f)
        except Exception as exc:
            raise InputError(f"cannot load the checkpoint's state: {exc}", os.fspath(path)) from None
    return header, state
