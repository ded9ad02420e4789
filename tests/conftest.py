"""Test-wide settings.

Property tests draw the same hypothesis examples on every run by default, so the README's
test command gives the same answer on every machine and a red CI is reproducible from the
commit alone. ``BSSLAM_EXPLORE=1`` draws new examples each run instead (and keeps the
failing ones in ``.hypothesis/``): how the corner cases of the spline searches' tests were
found. Run it when changing spline/.
"""

import os

from hypothesis import settings

settings.register_profile("fixed", derandomize=True, print_blob=True)
settings.register_profile("explore", derandomize=False)
settings.load_profile("explore" if os.environ.get("BSSLAM_EXPLORE") else "fixed")
