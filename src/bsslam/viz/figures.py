"""Figure creation and saving, without pyplot (no global figure registry to leak into)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Iterable

import numpy as np
from matplotlib.figure import Figure

from bsslam.errors import InputError
from bsslam.io.atomic_file import atomic_write

SAVE_DPI = 150


def new_figure(width_in: float = 8.0, height_in: float = 6.5) -> Figure:
    """A standalone figure (size in inches) with constrained layout."""
    return Figure(figsize=(width_in, height_in), layout="constrained")


def save_figure(fig: Figure, paths: Iterable[str | os.PathLike], dpi: int = SAVE_DPI) -> list[Path]:
    """Write ``fig`` to every path, the format taken from each suffix (``.png``, ``.svg``,
    ``.pdf``); raster parts at ``dpi``. Each file is written atomically (a temporary in the
    same folder, renamed when complete). Returns the paths written.

    Raises:
        InputError: a path cannot be written (naming it).
    """
    written = []
    for path in paths:
        path = Path(path)
        # savefig into the open temporary: the format must be named, there is no file name
        with atomic_write(path, "wb") as f:
            fig.savefig(f, format=path.suffix.lstrip(".").lower() or None, dpi=dpi)
        written.append(path)
    return written


def as_poses(poses: object, name: str = "poses") -> np.ndarray:
    """``poses`` as an (N, 3) float array (x m, y m, φ rad); InputError otherwise."""
    arr = np.asarray(poses, dtype=float)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise InputError(f"{name} must have shape (N, 3), got {arr.shape}")
    return arr
