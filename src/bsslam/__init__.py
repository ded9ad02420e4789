"""bsslam — EKF SLAM with B-spline map features for 2D laser range finders.

The package follows Pedraza et al., *Extending the Limits of Feature-Based SLAM With
B-Splines* (IEEE T-RO 2009). Layers, lowest first: ``spline`` (B-spline maths),
``scan`` (segmentation), ``slam`` (the filter), then ``sim``, ``io``, ``eval``, ``viz``,
``pipeline`` and the ``cli``.
"""

import logging

__version__ = "0.1.0"

logging.getLogger(__name__).addHandler(logging.NullHandler())
