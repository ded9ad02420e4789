"""Small ROS 1 / ROS 2 bags written with rosbags' own writers, for the reader tests."""

import math

import numpy as np
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

LASER, ODOM, TF = "sensor_msgs/msg/LaserScan", "nav_msgs/msg/Odometry", "tf2_msgs/msg/TFMessage"
RANGES = np.array([1.0, 2.5, 30.0, np.inf, 0.05, 4.125], dtype=np.float32)


class Bag:
    """Builds messages with the right typestore and writes them as ROS 1 or ROS 2."""

    def __init__(self, kind):
        self.kind = kind
        self.store = get_typestore(Stores.ROS1_NOETIC if kind == "ros1" else Stores.ROS2_HUMBLE)
        if TF not in self.store.types:  # the Noetic store lacks tf2_msgs
            self.store.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms", TF))
        self.messages = []

    def _type(self, name):
        return self.store.types[name]

    def header(self, t, frame):
        time = self._type("builtin_interfaces/msg/Time")(sec=int(math.floor(t)), nanosec=int(round((t % 1) * 1e9)))
        fields = {"stamp": time, "frame_id": frame}
        if self.kind == "ros1":
            fields["seq"] = 0
        return self._type("std_msgs/msg/Header")(**fields)

    def scan(self, t, ranges=RANGES, topic="/scan", frame="laser", increment=0.25, angle_max=None, time_increment=0.0):
        # angle_max as drivers write it: the last beam's bearing (None); a value to corrupt it
        last = -1.5 + increment * (len(ranges) - 1)
        msg = self._type(LASER)(header=self.header(t, frame), angle_min=-1.5,
                                angle_max=last if angle_max is None else angle_max,
                                angle_increment=increment, time_increment=time_increment, scan_time=0.1,
                                range_min=0.1, range_max=30.0, ranges=np.asarray(ranges, dtype=np.float32),
                                intensities=np.zeros(0, dtype=np.float32))
        self.messages.append((topic, LASER, t, msg))

    def _pose(self, x, y, yaw):
        geo = "geometry_msgs/msg/"
        return (self._type(geo + "Vector3")(x=x, y=y, z=0.0), self._type(geo + "Point")(x=x, y=y, z=0.0),
                self._type(geo + "Quaternion")(x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2)))

    def odom(self, t, x, y, yaw, topic="/odom"):
        geo = "geometry_msgs/msg/"
        _, point, quat = self._pose(x, y, yaw)
        pose = self._type(geo + "PoseWithCovariance")(pose=self._type(geo + "Pose")(position=point, orientation=quat),
                                                      covariance=np.zeros(36))
        zero = self._type(geo + "Vector3")(x=0.0, y=0.0, z=0.0)
        twist = self._type(geo + "TwistWithCovariance")(twist=self._type(geo + "Twist")(linear=zero, angular=zero),
                                                        covariance=np.zeros(36))
        msg = self._type(ODOM)(header=self.header(t, "odom"), child_frame_id="base_link", pose=pose, twist=twist)
        self.messages.append((topic, ODOM, t, msg))

    def tf(self, t, parent, child, x, y, yaw, topic="/tf"):
        vec, _, quat = self._pose(x, y, yaw)
        transform = self._type("geometry_msgs/msg/Transform")(translation=vec, rotation=quat)
        stamped = self._type("geometry_msgs/msg/TransformStamped")(header=self.header(t, parent),
                                                                   child_frame_id=child, transform=transform)
        self.messages.append((topic, TF, t, self._type(TF)(transforms=[stamped])))

    def write(self, path):
        if self.kind == "ros1":
            writer, serialize = Writer1(path), self.store.serialize_ros1
        else:
            plugin = StoragePlugin.MCAP if self.kind == "ros2-mcap" else StoragePlugin.SQLITE3
            writer, serialize = Writer2(path, version=9, storage_plugin=plugin), self.store.serialize_cdr
        with writer:
            connections = {}
            for topic, msgtype, t, msg in sorted(self.messages, key=lambda m: m[2]):
                if topic not in connections:
                    connections[topic] = writer.add_connection(topic, msgtype, typestore=self.store)
                writer.write(connections[topic], int(round(t * 1e9)), serialize(msg, msgtype))
        return path


KINDS = ["ros1", "ros2-sqlite3", "ros2-mcap"]


def bag_path(tmp_path, kind):
    return tmp_path / ("run.bag" if kind == "ros1" else "run")


def standard_bag(kind):
    bag = Bag(kind)
    bag.tf(0.0, "base_link", "laser", 0.2, 0.05, 0.0, topic="/tf_static")
    bag.scan(1.0)                       # before the first odometry
    bag.odom(1.2, 0.0, 0.0, 0.0)
    bag.scan(1.5)
    bag.scan(2.0)
    bag.odom(2.2, 1.0, 0.0, 1.0)
    bag.scan(3.0)                       # after the last odometry
    return bag
