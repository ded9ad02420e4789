"""The front end's compiled loops (bsslam.frontend.kernels) against plain numpy forms."""

from __future__ import annotations

import numpy as np
import pytest

from bsslam.frontend.kernels import splat_max
from bsslam.frontend.scan_matcher import LikelihoodField


@pytest.mark.parametrize("seed", range(3))
def test_splat_max_is_numpys_maximum_at(seed):
    """Exact: a maximum does not round, whatever the order (cells repeat on purpose)."""
    rng = np.random.default_rng(seed)
    field = LikelihoodField.build(rng.uniform(-3.0, 3.0, size=(50, 2)), 0.05, 0.07, 0.4)
    nx, ny = field.shape
    r = field.radius + 1
    cells = rng.integers(r, nx - r, 300) * ny + rng.integers(r, ny - r, 300)
    cells = np.concatenate((cells, cells[:20]))
    expected = field.values.copy()
    np.maximum.at(expected, (cells[:, None] + field.kernel_offset[None, :]).ravel(),
                  np.tile(field.kernel_value, cells.shape[0]))
    got = field.values.copy()
    splat_max(got, cells, field.kernel_offset, field.kernel_value)
    np.testing.assert_array_equal(got, expected)
