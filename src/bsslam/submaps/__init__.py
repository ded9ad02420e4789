"""The submap backend: BS-SLAM in local submaps of bounded size, tied together by a pose
graph with loop closures between submaps (``backend: submaps``).

- :mod:`bsslam.submaps.pose_graph`: the global layer, a pose graph over the submaps'
  base poses solved by GTSAM's iSAM2, wrong loop closures set aside by graduated
  non-convexity (or down-weighted by a robust kernel).
- :mod:`bsslam.submaps.loop_closure`: a frozen submap matched against an old one (a wide
  correlative search on the old submap's spline points, then verification).
- :mod:`bsslam.submaps.backend`: the orchestration (local filter, freezing, loop closure,
  one global map and trajectory).
"""

from bsslam.submaps.backend import FrozenSubmap, SubmapSLAM

__all__ = ["FrozenSubmap", "SubmapSLAM"]
