"""chi2_quantile is scipy.stats.chi2.ppf (the oracle) to the bit, edges included."""

import math

import numpy as np
import pytest
from scipy.stats import chi2

from bsslam.chi2 import chi2_quantile


@pytest.mark.parametrize("dof", [1, 2, 3, 0.5, 1.5, 7, 100])
def test_bit_identical_to_scipy_stats(dof):
    probabilities = list(np.random.default_rng(int(dof * 10)).uniform(0, 1, 500)) + [
        0.0, 1.0, 0.5, 0.9, 0.95, 0.99, 0.999, 1e-300, 1 - 1e-16, -0.1, 1.1, math.nan]
    for p in probabilities:
        ours, theirs = chi2_quantile(p, dof), float(chi2.ppf(p, dof))
        assert ours == theirs or (math.isnan(ours) and math.isnan(theirs)), (p, dof, ours, theirs)


@pytest.mark.parametrize("dof", [0, -1, math.nan])
def test_bad_degrees_of_freedom_give_nan_as_scipy_does(dof):
    assert math.isnan(chi2_quantile(0.5, dof)) and math.isnan(float(chi2.ppf(0.5, dof)))


def test_the_gates_quantiles():
    assert chi2_quantile(0.99, 1) == pytest.approx(6.634897, abs=1e-6)
    assert chi2_quantile(0.99, 3) == pytest.approx(11.344867, abs=1e-6)
