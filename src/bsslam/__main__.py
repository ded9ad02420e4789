"""``python -m bsslam``: the ``bsslam`` command line."""

from bsslam.cli import app

app(prog_name="bsslam")
