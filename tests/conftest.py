"""Test-wide settings.

Under CI (``BSSLAM_CI=1``, set by ``.ci/run``) hypothesis draws the same examples on every
run, so a red CI is always reproducible from the commit alone; elsewhere it keeps exploring
new examples (that is how the C0-corner case of ``test_intersect`` was found).
"""

import os

from hypothesis import settings

settings.register_profile("ci", derandomize=True, print_blob=True)
if os.environ.get("BSSLAM_CI"):
    settings.load_profile("ci")
