"""Result folders: every verb that writes results writes to ``DIR/<timestamp>/`` and points
``DIR/latest`` at it."""

from __future__ import annotations

import datetime as _dt
import os
from pathlib import Path


def make_run_dir(out: str | os.PathLike) -> Path:
    """Create ``out/<UTC timestamp>/`` (unique even within one second) and repoint
    ``out/latest`` to it. Returns the new folder."""
    base = Path(out)
    base.mkdir(parents=True, exist_ok=True)
    stamp = _dt.datetime.now(_dt.timezone.utc).strftime("%Y%m%d-%H%M%S")
    run = base / stamp
    suffix = 1
    while True:
        try:
            run.mkdir()
            break
        except FileExistsError:
            suffix += 1
            run = base / f"{stamp}-{suffix}"
    latest = base / "latest"
    tmp = base / f".latest-{os.getpid()}"
    if tmp.is_symlink() or tmp.exists():
        tmp.unlink()
    tmp.symlink_to(run.name, target_is_directory=True)
    os.replace(tmp, latest)  # atomic: readers never see a missing `latest`
    return run
