"""Writing a :class:`~jaxslam.datasets.carmen.CarmenLog` as a ROS 1 or ROS 2 bag (laser
scans, odometry and the laser mount on ``/tf_static``), in the conventions that
:func:`jaxslam.datasets.rosbag.load_rosbag` reads back.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from jaxslam.datasets.carmen import CarmenLog
from jaxslam.datasets.rosbag_messages import LASER_SCAN, ODOMETRY, TF_MESSAGE, seconds_to_ns

def write_rosbag(
    log: CarmenLog,
    path: os.PathLike | str,
    *,
    version: int = 2,
    storage: str = "sqlite3",
    odometry: str = "topic",
    scans: slice | None = None,
) -> Path:
    """Write a CARMEN log as a ROS bag: ``/scan``, ``/odom`` or ``/tf``, ``/tf_static``.

    Each scan becomes a ``LaserScan`` in frame ``laser`` stamped with its
    ``scan_times`` and recorded at its ``logger_times`` (so the bag keeps the log's
    order); its odometry pose becomes an ``Odometry`` (``odom -> base_link``) with the
    same stamp, or with ``odometry="tf"`` a ``TFMessage`` on ``/tf``. ``/tf_static``
    holds the laser mount ``base_link -> laser``. ``max_range`` becomes
    ``range_max``; ``range_min`` is 0. Headings are written as ROS does,
    ``(0, 0, sin(t/2), cos(t/2))``.

    Args:
        log: the log (one beam geometry, no ``angle_offsets``).
        path: a ``.bag`` file (``version=1``) or a ROS 2 bag folder (``version=2``).
        version: 1 or 2.
        storage: ROS 2 storage, ``"sqlite3"`` or ``"mcap"``.
        odometry: ``"topic"`` (``/odom``) or ``"tf"``.
        scans: which scans to write (default all).
    """
    from rosbags.typesys import Stores, get_typestore

    if np.any(np.asarray(log.angle_offsets) != 0):
        raise ValueError("a LaserScan topic has one beam geometry; this log interleaves start angles")
    if odometry not in ("topic", "tf"):
        raise ValueError(f"odometry must be 'topic' or 'tf', got {odometry!r}")
    path = Path(path)
    index = np.arange(log.num_scans)[scans if scans is not None else slice(None)]
    store = get_typestore(Stores.ROS1_NOETIC if version == 1 else Stores.ROS2_HUMBLE)
    if TF_MESSAGE not in store.types:  # the ROS 1 store lacks tf2_msgs
        from rosbags.typesys import get_types_from_msg

        store.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms", TF_MESSAGE))
    types = store.types
    Time = types["builtin_interfaces/msg/Time"]
    Header = types["std_msgs/msg/Header"]
    Vector3 = types["geometry_msgs/msg/Vector3"]
    Quaternion = types["geometry_msgs/msg/Quaternion"]

    def header(ns: int, frame: str):
        stamp = Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)
        if version == 1:
            return Header(seq=0, stamp=stamp, frame_id=frame)
        return Header(stamp=stamp, frame_id=frame)

    def quaternion(theta: float):
        return Quaternion(x=0.0, y=0.0, z=float(np.sin(theta / 2.0)), w=float(np.cos(theta / 2.0)))

    def transform(ns, parent, child, pose):
        return types["geometry_msgs/msg/TransformStamped"](
            header=header(ns, parent), child_frame_id=child,
            transform=types["geometry_msgs/msg/Transform"](
                translation=Vector3(x=float(pose[0]), y=float(pose[1]), z=0.0), rotation=quaternion(pose[2])))

    def serialize(msg, msgtype):
        if version == 1:
            return store.serialize_ros1(msg, msgtype)
        return store.serialize_cdr(msg, msgtype)

    if version == 1:
        from rosbags.rosbag1 import Writer

        writer = Writer(path)
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer

        plugin = {"sqlite3": StoragePlugin.SQLITE3, "mcap": StoragePlugin.MCAP}[storage]
        writer = Writer(path, version=9, storage_plugin=plugin)
    angles = np.asarray(log.angles, dtype=np.float64)
    step = float(log.angular_resolution)
    stamps = [seconds_to_ns(t) for t in np.asarray(log.scan_times)[index]]
    records = []
    for t in np.asarray(log.logger_times)[index]:  # strictly increasing: the bag keeps the log's order
        records.append(max(seconds_to_ns(t), records[-1] + 1) if records else seconds_to_ns(t))
    first_record = min(records) if records else 0
    with writer:
        scan_conn = writer.add_connection("/scan", LASER_SCAN, typestore=store)
        if odometry == "topic":
            odom_conn = writer.add_connection("/odom", ODOMETRY, typestore=store)
        else:
            odom_conn = writer.add_connection("/tf", TF_MESSAGE, typestore=store)
        static_conn = writer.add_connection("/tf_static", TF_MESSAGE, typestore=store)
        start_ns = stamps[0] if stamps else 0
        static = types[TF_MESSAGE](transforms=[transform(start_ns, "base_link", "laser", log.laser_offset)])
        writer.write(static_conn, first_record, serialize(static, TF_MESSAGE))
        for scan, stamp, record in zip(index, stamps, records, strict=True):
            pose = np.asarray(log.odom_poses[scan], dtype=np.float64)
            if odometry == "topic":
                odom = types[ODOMETRY](
                    header=header(stamp, "odom"), child_frame_id="base_link",
                    pose=types["geometry_msgs/msg/PoseWithCovariance"](
                        pose=types["geometry_msgs/msg/Pose"](
                            position=types["geometry_msgs/msg/Point"](x=float(pose[0]), y=float(pose[1]), z=0.0),
                            orientation=quaternion(pose[2])),
                        covariance=np.zeros(36)),
                    twist=types["geometry_msgs/msg/TwistWithCovariance"](
                        twist=types["geometry_msgs/msg/Twist"](linear=Vector3(x=0.0, y=0.0, z=0.0),
                                                               angular=Vector3(x=0.0, y=0.0, z=0.0)),
                        covariance=np.zeros(36)))
                writer.write(odom_conn, record, serialize(odom, ODOMETRY))
            else:
                tf = types[TF_MESSAGE](transforms=[transform(stamp, "odom", "base_link", pose)])
                writer.write(odom_conn, record, serialize(tf, TF_MESSAGE))
            msg = types[LASER_SCAN](
                header=header(stamp, "laser"), angle_min=float(angles[0]),
                angle_max=float(angles[0] + step * (angles.shape[0] - 1)), angle_increment=step,
                time_increment=0.0, scan_time=0.0, range_min=0.0, range_max=float(log.max_range),
                ranges=np.asarray(log.ranges[scan], dtype=np.float32),
                intensities=np.zeros(0, dtype=np.float32))
            writer.write(scan_conn, record, serialize(msg, LASER_SCAN))
    return path
