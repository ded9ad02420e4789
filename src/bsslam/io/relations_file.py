"""Relations files (Kümmerle et al. 2009): ``t1 t2 dx dy dz droll dpitch dyaw`` per line.

Each line is the pose at ``t2`` seen from the pose at ``t1`` (m, rad), checked by hand.
The 2-D evaluation uses dx, dy and dyaw. Stamps are those of the original log (for Intel,
Unix times: 976052857.337 s ahead of the shipped CARMEN logs).
"""

from __future__ import annotations

import numpy as np

from bsslam.io.numeric_table import parse_numeric_table
from bsslam.io.path_or_file import PathOrFile, describe, open_path_or_file


def read_relations(source: PathOrFile) -> np.ndarray:
    """Read a relations file.

    Returns:
        (M, 5) array of ``t1 t2 dx dy dyaw`` (s, s, m, m, rad).

    Raises:
        InputError: unreadable file or a line without 8 numbers (with file and line).
    """
    with open_path_or_file(source) as f:
        table = parse_numeric_table(f, describe(source), (8,))
    return table[:, [0, 1, 2, 3, 7]]
