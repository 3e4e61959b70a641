"""ROS 1 and ROS 2 bags (``.bag``, sqlite3 and MCAP) as a :class:`~jaxslam.datasets.carmen.CarmenLog`.

Built on ``rosbags`` (pure Python: no ROS installation needed). The reader takes

* laser scans from a ``sensor_msgs/msg/LaserScan`` topic,
* odometry from a ``nav_msgs/msg/Odometry`` topic, or from the ``odom -> base``
  transform on ``/tf`` (``tf2_msgs/msg/TFMessage``),
* the laser mount (base frame -> the scans' ``frame_id``) from ``/tf_static`` (or
  ``/tf``), or given explicitly,

and gives the same fixed-shape arrays as :func:`jaxslam.datasets.carmen.load_carmen`,
so the filters run on a bag unchanged. Topics are found automatically when the bag
holds exactly one of each type.

Time. Scans keep the bag's order (record time) and are stamped with their
``header.stamp``: ``scan_times`` is ``sec + nanosec / 1e9`` rounded once to float64
(exact integer arithmetic), so stamps are in the bag's own time base. The bag's
record time of each scan goes to ``logger_times``. The odometry is sorted by its
header stamps and interpolated to each scan stamp (``x``, ``y`` linearly, the
heading along the shorter arc); a scan stamped exactly at an odometry message takes
that pose unchanged. Scans stamped before the first or after the last odometry
message cannot be placed: they are dropped and counted in
``stats["scans_outside_odometry"]`` (their indices go to ``problems``).

Headings. A quaternion's yaw is ``atan2(2 (w z + x y), w^2 + x^2 - y^2 - z^2)``. For
a planar quaternion ``(0, 0, z, w)`` the reader returns the float64 angle ``t``
within a few ulps of ``2 atan2(z, w)`` for which ``(sin(t/2), cos(t/2)) == (z, w)``
exactly, when there is one: a heading written as ROS does (tf2 ``setRPY``) is read
back bit for bit.

Beam geometry. ``LaserScan`` stores ``angle_min`` and ``angle_increment`` in float32.
Laser scanners step by an integer fraction of a half turn (1, 0.5, 0.25 deg, 1/1024
or 1/1440 of a turn ...) and start at a multiple of half a step; when
``pi / k`` (integer ``k``) rounds to the stored increment in float32, the increment
is taken as ``pi / k`` in float64, and likewise ``angle_min`` as ``pi p / q`` when
it is a multiple of half that step. This recovers the float64 geometry exactly
(as the CARMEN reader's) without changing the float32 values; other values are
used as stored. Beam ``b`` points at ``angle_min + b * angle_increment``. A laser
mounted upside down (its z axis pointing down) has its angles negated.

Range policy (as the CARMEN reader, plus REP 117 for infinities):

* ``r >= range_max`` or ``+inf``: "no return" (``max_range_mask``, never a hit);
  counted in ``stats["max_range_readings"]`` and ``stats["inf_readings"]``.
* NaN and ``-inf`` (too close / error): invalid, counted in
  ``stats["nonfinite_readings"]``.
* ``r <= 0`` or ``r < range_min``: invalid, counted in
  ``stats["nonpositive_readings"]`` / ``stats["below_range_min_readings"]``.
* otherwise a hit (``valid``).

Errors. A missing topic, a topic of the wrong type, scan stamps that go back by more
than ``max_backstep`` seconds (shorter backward steps are counted in
``stats["backwards_timestamps"]``, as the CARMEN reader does), a change of the beam
count or geometry, a zero header stamp, a laser frame with no transform to the base
frame, and unreadable bags raise :class:`~jaxslam.datasets.paths.DataFormatError` naming the
bag, the topic and the message index. With ``on_error="skip"`` a bad scan message is dropped and
counted instead (``stats["skipped_messages"]``, ``stats["skipped:<reason>"]``).

Layout: the message readers and the time, heading and geometry helpers are in
:mod:`jaxslam.datasets.rosbag_messages`, :func:`~jaxslam.datasets.rosbag_write.write_rosbag` in
:mod:`jaxslam.datasets.rosbag_write`; both are re-exported here.

One module of about 400 lines: choosing the topics, decoding the scans and the
odometry and pairing them by stamp are one loader with one set of options; the
message layouts are in :mod:`jaxslam.datasets.rosbag_messages`.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path
from typing import Any

import numpy as np

from jaxslam.datasets.carmen import CarmenLog
from jaxslam.datasets.paths import DataFormatError
from jaxslam.datasets.rosbag_messages import (
    LASER_SCAN,
    ODOMETRY,
    TF_MESSAGE,
    interpolate_odometry,
    laser_mount,
    ns_to_seconds,
    odometry_at_scans,
    quaternion_yaw,
    read_odometry_topic,
    read_scans,
    read_transforms,
    seconds_to_ns,
    snap_increment,
    snap_start,
)
from jaxslam.datasets.rosbag_write import write_rosbag

__all__ = [
    "LASER_SCAN",
    "ODOMETRY",
    "TF_MESSAGE",
    "inspect_rosbag",
    "interpolate_odometry",
    "is_rosbag",
    "load_rosbag",
    "quaternion_yaw",
    "seconds_to_ns",
    "ns_to_seconds",
    "write_rosbag",
]

_MAX_PROBLEMS = 100


ROSBAG_SUFFIXES = (".bag", ".db3", ".mcap")
"""A ROS 1 bag (``.bag``) or the file of a ROS 2 bag (SQLite ``.db3``, MCAP ``.mcap``)."""


def is_rosbag(path: os.PathLike | str) -> bool:
    """True for a ROS 1 ``.bag``, a ROS 2 ``.mcap``/``.db3`` file, or a ROS 2 bag folder."""
    path = Path(path)
    if path.is_dir():
        return (path / "metadata.yaml").exists()
    return path.suffix in ROSBAG_SUFFIXES


@dataclasses.dataclass
class _Stats:
    path: Path
    on_error: str
    stats: dict[str, int] = dataclasses.field(default_factory=dict)
    problems: list[str] = dataclasses.field(default_factory=list)

    def count(self, key: str, amount: int = 1) -> None:
        if amount:
            self.stats[key] = self.stats.get(key, 0) + amount

    def note(self, text: str) -> None:
        if len(self.problems) < _MAX_PROBLEMS:
            self.problems.append(text)

    def bad_message(self, topic: str, index: int, reason: str, problem: str) -> None:
        text = f"topic {topic}, message {index}: {problem}"
        if self.on_error == "raise":
            raise DataFormatError(self.path, None, text)
        self.count("skipped_messages")
        self.count(f"skipped:{reason}")
        self.note(str(DataFormatError(self.path, None, text)))

def _open(path: Path):
    from rosbags.highlevel import AnyReader, AnyReaderError

    if not path.exists():
        raise FileNotFoundError(f"bag {str(path)!r} does not exist")
    if not is_rosbag(path):
        raise DataFormatError(
            path, None, "not a ROS bag (expected a .bag file, a .mcap/.db3 file, or a ROS 2 bag "
            "folder with metadata.yaml)"
        )
    try:
        reader = AnyReader([path])
        reader.open()
    except (AnyReaderError, OSError, ValueError, KeyError) as error:
        raise DataFormatError(path, None, f"cannot read the bag ({type(error).__name__}: {error})") from None
    return reader


def _topic_types(reader) -> dict[str, str]:
    return {name: info.msgtype or "(mixed types)" for name, info in reader.topics.items()}


def inspect_rosbag(path: os.PathLike | str) -> list[dict[str, Any]]:
    """One row per topic: ``topic``, ``type``, ``count``, ``first_s``, ``last_s``, ``rate_hz``.

    Times are the bag's record times in seconds; ``rate_hz`` is
    ``(count - 1) / (last - first)`` (None for fewer than two messages).
    """
    path = Path(path)
    reader = _open(path)
    try:
        rows = []
        for name, info in sorted(reader.topics.items()):
            stamps = [t for _, t, _ in reader.messages(connections=info.connections)]
            first = ns_to_seconds(min(stamps)) if stamps else None
            last = ns_to_seconds(max(stamps)) if stamps else None
            span = (last - first) if stamps else 0.0
            rows.append({
                "topic": name, "type": info.msgtype or "(mixed types)", "count": len(stamps),
                "first_s": first, "last_s": last,
                "rate_hz": (len(stamps) - 1) / span if len(stamps) > 1 and span > 0 else None,
            })
        return rows
    finally:
        reader.close()


def _pick_topic(path, types, wanted, given, what, option):
    if given is not None:
        if given not in types:
            raise DataFormatError(
                path, None, f"topic {given} is not in the bag; its topics: "
                + ", ".join(f"{t} ({m})" for t, m in sorted(types.items()))
            )
        if types[given] not in wanted:
            raise DataFormatError(
                path, None, f"topic {given} has type {types[given]}, but {what} needs "
                + " or ".join(wanted)
            )
        return given
    found = sorted(t for t, m in types.items() if m == wanted[0])
    if len(found) == 1:
        return found[0]
    if len(found) > 1:
        raise DataFormatError(
            path, None, f"{len(found)} {wanted[0]} topics ({', '.join(found)}); choose one with {option}"
        )
    return None

def load_rosbag(
    path: os.PathLike | str,
    *,
    scan_topic: str | None = None,
    odom_topic: str | None = None,
    odom_frame: str | None = None,
    base_frame: str | None = None,
    laser_offset: tuple[float, float, float] | np.ndarray | None = None,
    max_range: float | None = None,
    on_error: str = "raise",
    max_backstep: float = 1.0,
    max_tilt: float = 0.1,
) -> CarmenLog:
    """Read a ROS bag into a :class:`~jaxslam.datasets.carmen.CarmenLog` (see the module docstring).

    Args:
        path: a ROS 1 ``.bag``, a ROS 2 bag folder, or a ``.mcap``/``.db3`` file.
        scan_topic: the ``LaserScan`` topic; default: the only one in the bag.
        odom_topic: an ``Odometry`` topic or a ``TFMessage`` topic (``/tf``); default:
            the only ``Odometry`` topic, else ``/tf``.
        odom_frame, base_frame: with TF odometry, the transform ``odom_frame ->
            base_frame`` to use; default: the transform on ``/tf`` whose child is the
            laser frame or the nearest frame above it. With an ``Odometry`` topic,
            ``base_frame`` defaults to its ``child_frame_id``.
        laser_offset: ``(x, y, theta)`` of the laser in the base frame; default: from
            ``/tf_static`` (or constant transforms on ``/tf``).
        max_range: range limit in m; default: the scans' ``range_max``.
        on_error: ``"raise"`` or ``"skip"`` (drop bad scan messages and count them).
        max_backstep: scan stamps may go back by up to this many seconds (counted).
        max_tilt: largest tilt (rad) of the laser against the base frame.

    Returns:
        A :class:`~jaxslam.datasets.carmen.CarmenLog` with ``message="LaserScan"``; ``scan_lines`` holds each
        scan's message index on the scan topic (0-based, as in the error messages),
        ``logger_times`` the bag's record times, ``laser_poses`` is None, ``params``
        names the topics and frames used, ``stats`` / ``problems`` the recoveries.

    Raises:
        DataFormatError: a bad bag, naming the bag, topic and message.
        FileNotFoundError: ``path`` does not exist.
    """
    if on_error not in ("raise", "skip"):
        raise ValueError(f"on_error must be 'raise' or 'skip', got {on_error!r}")
    path = Path(path)
    reader = _open(path)
    collector = _Stats(path, on_error)
    try:
        types = _topic_types(reader)
        scan_topic = _pick_topic(path, types, (LASER_SCAN,), scan_topic, "the scan topic", "scan_topic")
        if scan_topic is None:
            raise DataFormatError(path, None, "no sensor_msgs/msg/LaserScan topic in the bag; its topics: "
                                  + ", ".join(f"{t} ({m})" for t, m in sorted(types.items())))
        odom_topic = _pick_topic(path, types, (ODOMETRY, TF_MESSAGE), odom_topic, "odometry", "odom_topic")
        if odom_topic is None:
            if types.get("/tf") == TF_MESSAGE:
                odom_topic = "/tf"
            else:
                raise DataFormatError(
                    path, None, "no odometry: neither a nav_msgs/msg/Odometry topic nor /tf in the bag; its "
                    "topics: " + ", ".join(f"{t} ({m})" for t, m in sorted(types.items())))
        records, geometry = read_scans(reader, path, scan_topic, collector, max_backstep)
        laser_frame = records[0]["frame"].lstrip("/")

        # Static transforms: /tf_static, then transforms on /tf that never change.
        static: dict[str, tuple[str, tuple]] = {}
        tf_topics = [t for t, m in types.items() if m == TF_MESSAGE]
        for topic in sorted(tf_topics, key=lambda t: t != "/tf_static"):
            seen_values: dict[str, set] = {}
            for _, parent, child, values in read_transforms(reader, topic):
                if topic == "/tf_static":
                    static.setdefault(child, (parent, values))
                else:
                    seen_values.setdefault(child, set()).add((parent, values))
            for child, values in seen_values.items():
                if len(values) == 1 and child not in static:
                    static[child] = next(iter(values))

        if types[odom_topic] == ODOMETRY:
            stamps, raw_poses, frames = read_odometry_topic(reader, odom_topic)
            if len(frames) > 1:
                raise DataFormatError(path, None, f"topic {odom_topic}: odometry in several frames "
                                      f"{sorted(frames)}")
            if frames:
                odom_frame_found, child = next(iter(frames))
                base_frame = base_frame or child.lstrip("/") or laser_frame
                odom_frame = odom_frame or odom_frame_found
        else:
            stamps, raw_poses = [], []
            wanted_child = base_frame
            if wanted_child is None:
                dynamic_children = {}
                for _, parent, child, _ in read_transforms(reader, odom_topic):
                    dynamic_children.setdefault(child, parent)
                frame, chain = laser_frame, [laser_frame]
                while frame in static:
                    frame = static[frame][0]
                    chain.append(frame)
                candidates = [f for f in chain if f in dynamic_children and f not in static]
                if not candidates:
                    raise DataFormatError(
                        path, None, f"topic {odom_topic}: no transform to the laser frame {laser_frame!r} or a "
                        f"frame above it (frames with transforms: {sorted(dynamic_children)}); pass "
                        "base_frame/odom_frame")
                wanted_child = candidates[0]
            for stamp, parent, child, values in read_transforms(reader, odom_topic):
                if child == wanted_child and (odom_frame is None or parent == odom_frame):
                    odom_frame = parent
                    stamps.append(stamp)
                    raw_poses.append((values[0], values[1], *values[3:]))
            base_frame = wanted_child
        if not stamps:
            raise DataFormatError(path, None, f"topic {odom_topic}: no odometry messages"
                                  + (f" for {odom_frame} -> {base_frame}" if types[odom_topic] == TF_MESSAGE else ""))
        values = np.array(raw_poses, dtype=np.float64).reshape(-1, 6)
        if not np.all(np.isfinite(values)):
            bad = int(np.nonzero(~np.all(np.isfinite(values), axis=1))[0][0])
            raise DataFormatError(path, None, f"topic {odom_topic}, message {bad}: odometry pose is not finite")
        yaw, _ = quaternion_yaw(values[:, 2], values[:, 3], values[:, 4], values[:, 5])
        odom_xyt = np.stack([values[:, 0], values[:, 1], yaw], axis=1)
        odom_ns = np.array(stamps, dtype=np.int64)

        if laser_offset is not None:
            offset = np.asarray(laser_offset, dtype=np.float64).reshape(3)
            flipped = False
        else:
            offset, flipped = laser_mount(path, static, base_frame, laser_frame, max_tilt)
    finally:
        reader.close()

    scan_ns = np.array([r["stamp"] for r in records], dtype=np.int64)
    odom_poses, inside, odom_sorted_ns, odom_sorted = odometry_at_scans(path, odom_ns, odom_xyt, scan_ns, collector)
    if not np.all(inside):
        dropped = np.nonzero(~inside)[0]
        collector.count("scans_outside_odometry", int(dropped.shape[0]))
        collector.note(
            f"{path}: topic {scan_topic}: {dropped.shape[0]} scans stamped outside the odometry "
            f"({ns_to_seconds(odom_sorted_ns[0])!r} .. {ns_to_seconds(odom_sorted_ns[-1])!r} s) were dropped, "
            f"messages {[records[i]['index'] for i in dropped[:20]]}"
            + (" ..." if dropped.shape[0] > 20 else ""))
        if not np.any(inside):
            raise DataFormatError(path, None, f"topic {scan_topic}: no scan is stamped within the odometry "
                                  f"on {odom_topic} ({ns_to_seconds(odom_sorted_ns[0])!r} .. "
                                  f"{ns_to_seconds(odom_sorted_ns[-1])!r} s)")
        records = [r for r, keep in zip(records, inside, strict=True) if keep]
        odom_poses = odom_poses[inside]

    num_beams, angle_min, increment, range_min, range_max = geometry
    snapped = snap_increment(increment)
    start = snap_start(angle_min, increment, snapped)
    angles = start + snapped * np.arange(num_beams)
    if flipped:
        angles = -angles
    limit = float(max_range) if max_range is not None else range_max

    ranges = np.stack([r["ranges"] for r in records]).astype(np.float32)
    wide = ranges.astype(np.float64)
    with np.errstate(invalid="ignore"):
        finite = np.isfinite(wide)
        plus_inf = np.isposinf(wide)
        at_max = (finite & (wide >= limit)) | plus_inf
        positive = wide > 0.0
        above_min = wide >= range_min
    valid = finite & positive & above_min & ~at_max
    collector.count("max_range_readings", int((finite & at_max).sum()))
    collector.count("inf_readings", int(plus_inf.sum()))
    collector.count("nonfinite_readings", int((~finite & ~plus_inf).sum()))
    collector.count("nonpositive_readings", int((finite & ~positive).sum()))
    collector.count("below_range_min_readings", int((finite & positive & ~above_min).sum()))
    num_scans = ranges.shape[0]
    collector.stats.setdefault("backwards_timestamps", 0)
    params = {"scan_topic": scan_topic, "odom_topic": odom_topic, "laser_frame": laser_frame,
              "base_frame": str(base_frame), "odom_frame": str(odom_frame),
              "laser_flipped": str(bool(flipped)).lower(), "range_min": repr(range_min)}
    log = CarmenLog(
        path=path,
        message="LaserScan",
        scan_times=np.array([ns_to_seconds(r["stamp"]) for r in records], dtype=np.float64),
        logger_times=np.array([ns_to_seconds(r["record"]) for r in records], dtype=np.float64),
        scan_lines=np.array([r["index"] for r in records], dtype=np.int64),
        ranges=ranges,
        valid=valid,
        max_range_mask=at_max,
        angles=angles.astype(np.float32),
        angle_offsets=np.zeros(num_scans, dtype=np.float32),
        angular_resolution=float(abs(snapped)),
        max_range=limit,
        laser_offset=offset,
        odom_poses=odom_poses,
        laser_poses=None,
        odom_times=np.array([ns_to_seconds(t) for t in odom_sorted_ns.tolist()], dtype=np.float64),
        odom_readings=odom_sorted,
        params=params,
        stats=dict(sorted(collector.stats.items())),
        problems=tuple(collector.problems),
    )
    for field in dataclasses.fields(log):
        value = getattr(log, field.name)
        if isinstance(value, np.ndarray):
            value.setflags(write=False)
    return log
