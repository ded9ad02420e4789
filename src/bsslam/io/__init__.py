"""Reading logs and writing results.

Readers (each a :class:`~bsslam.dataset.Dataset`): ``carmen`` (CARMEN ``.clf``/``.log``),
``rosbag`` (ROS 1/2 bags), chosen by :func:`open_dataset`. Result files, each taking a
path or an open file: ``trajectory_file`` (TUM), ``pose_covariance_file`` (CSV),
``map_file`` (spline map JSON), ``grid`` (map_server PGM + YAML), ``config_file`` (YAML),
``relations_file`` (Kümmerle relations); ``results`` makes run folders.
"""

from bsslam.io.open_dataset import open_dataset
from bsslam.io.reader_config import ReaderConfig

__all__ = ["open_dataset", "ReaderConfig"]
