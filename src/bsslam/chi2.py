"""χ² quantiles for the filter's and the pose graph's gates, without ``scipy.stats``.

``scipy.stats`` takes most of a second to import, on every start of every command, for
the one quantile the gates need. ``scipy.stats.chi2.ppf(p, k)`` is ``2·gammaincinv(k/2,
p)`` (scaled by 1 and shifted by 0) inside (0, 1), 0 at p = 0, ∞ at p = 1 and NaN
elsewhere; this is that computation, so the thresholds are the same to the bit
(tests/test_chi2.py checks it against scipy.stats).
"""

from __future__ import annotations

import math

from scipy.special import gammaincinv


def chi2_quantile(probability: float, dof: float) -> float:
    """The ``probability`` quantile of the χ² distribution with ``dof`` > 0 degrees of
    freedom (NaN for a probability outside [0, 1] or a dof ≤ 0)."""
    p, k = float(probability), float(dof)
    if not k > 0 or not 0.0 <= p <= 1.0:
        return math.nan
    if p == 0.0:
        return 0.0
    if p == 1.0:
        return math.inf
    return float(2 * gammaincinv(k / 2, p))
