"""bsslam — EKF SLAM with B-spline map features for 2D laser range finders.

The package follows Pedraza et al., *Extending the Limits of Feature-Based SLAM With
B-Splines* (IEEE T-RO 2009). Layers, lowest first: ``spline`` (B-spline maths),
``scan`` (segmentation), ``slam`` (the filter), then ``sim``, ``io``, ``eval``, ``viz``,
``mapper`` (the whole pipeline, fed scan by scan), ``pipeline`` and the ``cli``.

``from bsslam import Mapper`` is the entry point for your own data (see the README's
Python API); it is imported on first use, so ``import bsslam`` stays light.
"""

import logging

__version__ = "0.1.0"

__all__ = ["Mapper", "PoseEstimate", "RunResult"]

logging.getLogger(__name__).addHandler(logging.NullHandler())


def __getattr__(name: str):
    # The mapper pulls in the filter and its compiled kernels: import it when asked for,
    # not whenever a submodule (the CLI's errors, a reader) is imported.
    if name in __all__:
        from bsslam import mapper

        return getattr(mapper, name)
    raise AttributeError(f"module 'bsslam' has no attribute {name!r}")
