"""Reading small whitespace- or comma-separated numeric tables with located errors."""

from __future__ import annotations

from typing import Iterable

import numpy as np

from bsslam.errors import InputError


def parse_numeric_table(lines: Iterable[str], name: str, widths: tuple[int, ...], *,
                        sep: str | None = None, first_line: int = 1) -> np.ndarray:
    """Parse rows of numbers, skipping blank lines and ``#`` comments.

    The first data line fixes the column count, which must be one of ``widths``; every
    later line must have the same count.

    Args:
        lines: the text lines (e.g. an open file).
        name: the file name for error messages.
        widths: accepted column counts.
        sep: field separator; None splits on whitespace.
        first_line: 1-based number of the first line in ``lines`` (after a header).

    Returns:
        (N, width) float array; (0, widths[0]) when there is no data line.

    Raises:
        InputError: a wrong column count or a non-numeric value, naming file and line.
    """
    rows: list[list[float]] = []
    width = None
    for number, line in enumerate(lines, start=first_line):
        text = line.strip()
        if not text or text.startswith("#"):
            continue
        fields = text.split(sep)
        if width is None:
            if len(fields) not in widths:
                expected = " or ".join(map(str, widths))
                raise InputError(f"expected {expected} columns, got {len(fields)}", name, number)
            width = len(fields)
        elif len(fields) != width:
            raise InputError(f"expected {width} columns like the first line, got {len(fields)}",
                             name, number)
        try:
            rows.append([float(v) for v in fields])
        except ValueError:
            raise InputError(f"non-numeric value in {text!r}", name, number) from None
    return np.array(rows, dtype=float).reshape(-1, width or widths[0])
