"""ROS 1 and ROS 2 bags (``.bag``, sqlite3 and MCAP) as a :class:`CarmenLog`.

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
frame, and unreadable bags raise :class:`DataFormatError` naming the bag, the topic
and the message index. With ``on_error="skip"`` a bad scan message is dropped and
counted instead (``stats["skipped_messages"]``, ``stats["skipped:<reason>"]``).
"""

from __future__ import annotations

import dataclasses
import math
import os
from fractions import Fraction
from pathlib import Path
from typing import Any

import numpy as np

from jaxslam.datasets.carmen import CarmenLog
from jaxslam.datasets.paths import DataFormatError

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

LASER_SCAN = "sensor_msgs/msg/LaserScan"
ODOMETRY = "nav_msgs/msg/Odometry"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"
_MAX_PROBLEMS = 100
_POLISH_ULPS = 4


def is_rosbag(path: os.PathLike | str) -> bool:
    """True for a ROS 1 ``.bag``, a ROS 2 ``.mcap``/``.db3`` file, or a ROS 2 bag folder."""
    path = Path(path)
    if path.is_dir():
        return (path / "metadata.yaml").exists()
    return path.suffix in (".bag", ".mcap", ".db3")


def ns_to_seconds(ns: int) -> float:
    """Integer nanoseconds as float64 seconds, rounded once (exact integer division)."""
    return int(ns) / 1_000_000_000


def seconds_to_ns(seconds: float) -> int:
    """The integer nanoseconds nearest a float64 time; :func:`ns_to_seconds` gives it back."""
    return round(Fraction(float(seconds)) * 1_000_000_000)


def quaternion_yaw(qx, qy, qz, qw) -> tuple[np.ndarray, np.ndarray]:
    """Heading of the body x axis and ``cos(tilt)`` of the body z axis, for (...,) arrays.

    ``yaw = atan2(2 (w z + x y), w^2 + x^2 - y^2 - z^2)`` (any scale);
    ``cos_tilt = (w^2 + z^2 - x^2 - y^2) / |q|^2``, negative for an upside-down body.
    Planar quaternions ``(0, 0, sin(t/2), cos(t/2))`` give back ``t`` to the ulp, or
    exactly (see the module docstring), wrapped into ``[-pi, pi]`` only when outside it.
    """
    shape = np.broadcast_shapes(*(np.shape(v) for v in (qx, qy, qz, qw)))
    qx, qy, qz, qw = (np.broadcast_to(np.asarray(v, dtype=np.float64), shape).reshape(-1) for v in (qx, qy, qz, qw))
    norm2 = qx * qx + qy * qy + qz * qz + qw * qw
    with np.errstate(invalid="ignore", divide="ignore"):
        cos_tilt = (qw * qw + qz * qz - qx * qx - qy * qy) / norm2
    yaw = np.arctan2(2.0 * (qw * qz + qx * qy), qw * qw + qx * qx - qy * qy - qz * qz)
    planar = (qx == 0.0) & (qy == 0.0)
    if np.any(planar):
        half = np.arctan2(qz, qw)
        # Candidates nearest first: 0, +1, -1, +2, -2 ... ulps from atan2's answer.
        candidates = [half]
        up = down = half
        for _ in range(_POLISH_ULPS):
            up, down = np.nextafter(up, np.inf), np.nextafter(down, -np.inf)
            candidates += [up, down]
        candidates = np.stack(candidates, axis=-1)
        hits = (np.sin(candidates) == qz[..., None]) & (np.cos(candidates) == qw[..., None])
        found = hits.any(axis=-1)
        best = np.take_along_axis(candidates, np.argmax(hits, axis=-1)[..., None], axis=-1)[..., 0]
        # Several float64 angles can share one (sin, cos) pair; prefer the shortest decimal
        # (a heading logged as text, e.g. from a CARMEN log, comes back unchanged).
        for where in zip(*np.nonzero(hits.sum(axis=-1) > 1)):
            options = candidates[where][hits[where]]
            best[where] = min(options, key=lambda value: len(repr(float(2.0 * value))))
        exact = 2.0 * best
        exact = np.where(exact > np.pi, exact - 2.0 * np.pi, exact)
        exact = np.where(exact < -np.pi, exact + 2.0 * np.pi, exact)
        yaw = np.where(planar & found, exact, yaw)
    return yaw.reshape(shape), cos_tilt.reshape(shape)


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


def _stamp_ns(msg) -> int:
    return int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)


def _snap_increment(increment: float) -> float:
    """``pi / k`` when it rounds to the float32 ``increment``; else ``increment``."""
    if not (math.isfinite(increment) and increment != 0.0):
        return increment
    k = round(math.pi / abs(increment))
    if k >= 1 and np.float32(math.pi / k) == np.float32(abs(increment)):
        return math.copysign(math.pi / k, increment)
    return increment


def _snap_start(start: float, increment: float, snapped: float) -> float:
    """``pi p / q`` for a multiple of half a snapped step that rounds to ``start``."""
    if snapped == increment or not math.isfinite(start):
        return start
    k = round(math.pi / abs(snapped))
    half_steps = round(start / (0.5 * abs(snapped)))
    ratio = Fraction(half_steps, 2 * k)
    value = math.pi * ratio.numerator / ratio.denominator
    return value if np.float32(value) == np.float32(start) else start


def _describe(geometry: tuple) -> str:
    n, start, step, low, high = geometry
    return f"{n} beams from {start:.7g} rad every {step:.7g} rad, ranges {low:.7g}..{high:.7g} m"


def _read_scans(reader, path, topic, collector, max_backstep):
    connections = reader.topics[topic].connections
    records = []
    first_geometry = None
    for index, (conn, record_ns, raw) in enumerate(reader.messages(connections=connections)):
        try:
            msg = reader.deserialize(raw, conn.msgtype)
        except Exception as error:  # noqa: BLE001 - any decoding failure is a bad message
            collector.bad_message(topic, index, "undecodable", f"cannot decode ({error})")
            continue
        stamp = _stamp_ns(msg)
        ranges = np.asarray(msg.ranges, dtype=np.float32)
        geometry = (int(ranges.shape[0]), float(msg.angle_min), float(msg.angle_increment),
                    float(msg.range_min), float(msg.range_max))
        if stamp == 0:
            collector.bad_message(topic, index, "zero_stamp", "header stamp is zero (the driver did not set it)")
            continue
        if geometry[0] == 0:
            collector.bad_message(topic, index, "empty_scan", "the scan has no ranges")
            continue
        if not (math.isfinite(geometry[1]) and math.isfinite(geometry[2]) and geometry[2] != 0.0):
            collector.bad_message(topic, index, "bad_geometry",
                                  f"angle_min {geometry[1]!r} / angle_increment {geometry[2]!r} unusable")
            continue
        if not geometry[4] > 0.0:
            collector.bad_message(topic, index, "bad_geometry", f"range_max {geometry[4]!r} is not positive")
            continue
        if first_geometry is not None and geometry != first_geometry[0]:
            what = "beam count changes" if geometry[0] != first_geometry[0][0] else "scan geometry changes"
            collector.bad_message(
                topic, index, "geometry_change",
                f"{what}: {_describe(geometry)} here, but {_describe(first_geometry[0])} in message "
                f"{first_geometry[1]}",
            )
            continue
        if records:
            step = (stamp - records[-1]["stamp"]) / 1e9
            if step < -max_backstep:
                collector.bad_message(
                    topic, index, "backwards_timestamp",
                    f"header stamp {ns_to_seconds(stamp)!r} goes back {-step:.6g} s from the previous scan "
                    f"(message {records[-1]['index']}); more than max_backstep={max_backstep} s",
                )
                continue
            if step < 0:
                collector.count("backwards_timestamps")
        if first_geometry is None:
            first_geometry = (geometry, index)
        records.append({"index": index, "stamp": stamp, "record": record_ns, "ranges": ranges,
                        "frame": msg.header.frame_id})
    if not records:
        skipped = collector.stats.get("skipped_messages", 0)
        raise DataFormatError(path, None, f"topic {topic} holds no usable LaserScan messages"
                              + (f"; {skipped} bad messages were skipped" if skipped else ""))
    frames = sorted({r["frame"] for r in records})
    if len(frames) > 1:
        raise DataFormatError(path, None, f"topic {topic}: scans come in several frames {frames}; "
                              "a single laser is expected")
    return records, first_geometry[0]


def _read_odometry_topic(reader, topic):
    stamps, poses, frames = [], [], set()
    for conn, _, raw in reader.messages(connections=reader.topics[topic].connections):
        msg = reader.deserialize(raw, conn.msgtype)
        p = msg.pose.pose
        stamps.append(_stamp_ns(msg))
        poses.append((p.position.x, p.position.y, p.orientation.x, p.orientation.y,
                      p.orientation.z, p.orientation.w))
        frames.add((msg.header.frame_id, msg.child_frame_id))
    return stamps, poses, frames


def _transforms(reader, topic):
    """Every ``(stamp_ns, parent, child, (tx, ty, tz, qx, qy, qz, qw))`` on a TF topic."""
    for conn, _, raw in reader.messages(connections=reader.topics[topic].connections):
        msg = reader.deserialize(raw, conn.msgtype)
        for tf in msg.transforms:
            t, q = tf.transform.translation, tf.transform.rotation
            yield (_stamp_ns(tf), tf.header.frame_id.lstrip("/"), tf.child_frame_id.lstrip("/"),
                   (t.x, t.y, t.z, q.x, q.y, q.z, q.w))


def _rotation(q) -> np.ndarray:
    x, y, z, w = q
    n = x * x + y * y + z * z + w * w
    s = 2.0 / n if n > 0 else 0.0
    return np.array([
        [1 - s * (y * y + z * z), s * (x * y - z * w), s * (x * z + y * w)],
        [s * (x * y + z * w), 1 - s * (x * x + z * z), s * (y * z - x * w)],
        [s * (x * z - y * w), s * (y * z + x * w), 1 - s * (x * x + y * y)],
    ])


def _mount(path, static, base, laser, max_tilt):
    """``(x, y, yaw)`` of the laser in the base frame and whether it is upside down."""
    if laser.lstrip("/") == base:
        return np.zeros(3), False
    chain = []
    frame = laser.lstrip("/")
    seen = {frame}
    while frame != base:
        if frame not in static:
            known = ", ".join(f"{p} -> {c}" for c, (p, _) in sorted(static.items())) or "none"
            raise DataFormatError(
                path, None, f"no transform from the base frame {base!r} to the laser frame {laser!r} on "
                f"/tf_static or /tf (transforms: {known}); pass the laser mount explicitly (laser_offset)"
            )
        parent, values = static[frame]
        chain.append(values)
        frame = parent
        if frame in seen:
            raise DataFormatError(path, None, f"the transforms above {laser!r} form a cycle")
        seen.add(frame)
    chain.reverse()  # base -> ... -> laser
    if len(chain) == 1:
        tx, ty, _, qx, qy, qz, qw = chain[0]
        yaw, cos_tilt = quaternion_yaw(qx, qy, qz, qw)
        yaw, cos_tilt = float(yaw), float(cos_tilt)
    else:
        rotation, translation = np.eye(3), np.zeros(3)
        for tx, ty, tz, qx, qy, qz, qw in chain:
            translation = translation + rotation @ np.array([tx, ty, tz])
            rotation = rotation @ _rotation((qx, qy, qz, qw))
        tx, ty = float(translation[0]), float(translation[1])
        yaw, cos_tilt = math.atan2(rotation[1, 0], rotation[0, 0]), float(rotation[2, 2])
    tilt = math.acos(min(1.0, abs(cos_tilt)))
    if tilt > max_tilt:
        raise DataFormatError(
            path, None, f"the laser frame {laser!r} is tilted by {tilt:.3g} rad against {base!r} "
            f"(max_tilt={max_tilt}); a 2-D filter needs a level laser"
        )
    return np.array([tx, ty, yaw], dtype=np.float64), cos_tilt < 0.0


def interpolate_odometry(times, poses, query) -> tuple[np.ndarray, np.ndarray]:
    """Odometry ``poses (N, 3)`` at sorted ``times (N,)`` interpolated to ``query (M,)``.

    ``x``, ``y`` linearly and the heading along the shorter arc, between the last
    message at or before the query and the next; a query equal to a message's time
    takes its pose unchanged. Returns ``(poses (M, 3), inside (M,))``; ``inside`` is
    False for queries outside ``[times[0], times[-1]]`` (their poses are clamped).
    Times may be integers (ns) or floats (s).
    """
    times = np.asarray(times)
    poses = np.asarray(poses, np.float64).reshape(-1, 3)
    query = np.asarray(query)
    inside = (query >= times[0]) & (query <= times[-1])
    slot = np.clip(np.searchsorted(times, query, side="right") - 1, 0, times.shape[0] - 1)
    after = np.minimum(slot + 1, times.shape[0] - 1)
    span = (times[after] - times[slot]).astype(np.float64)
    elapsed = (query - times[slot]).astype(np.float64)
    alpha = np.where(span > 0, elapsed / np.where(span > 0, span, 1.0), 0.0)
    alpha = np.clip(alpha, 0.0, 1.0)
    start, end = poses[slot], poses[after]
    turn = (end[:, 2] - start[:, 2] + np.pi) % (2.0 * np.pi) - np.pi
    out = np.empty_like(start)
    out[:, :2] = start[:, :2] + alpha[:, None] * (end[:, :2] - start[:, :2])
    heading = start[:, 2] + alpha * turn
    heading = np.where(heading > np.pi, heading - 2.0 * np.pi, heading)
    out[:, 2] = np.where(heading < -np.pi, heading + 2.0 * np.pi, heading)
    return out, inside


def _interpolate(path, odom_ns, odom_xyt, scan_ns, collector):
    """Odometry at each scan stamp; ``(poses, placed mask, sorted stamps, sorted poses)``."""
    order = np.argsort(odom_ns, kind="stable")
    collector.count("odom_backwards_timestamps", int(np.sum(np.diff(odom_ns) < 0)))
    times = odom_ns[order]
    poses = odom_xyt[order]
    out, inside = interpolate_odometry(times, poses, scan_ns)
    return out, inside, times, poses


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
    """Read a ROS bag into a :class:`CarmenLog` (see the module docstring).

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
        A :class:`CarmenLog` with ``message="LaserScan"``; ``scan_lines`` holds each
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
        records, geometry = _read_scans(reader, path, scan_topic, collector, max_backstep)
        laser_frame = records[0]["frame"].lstrip("/")

        # Static transforms: /tf_static, then transforms on /tf that never change.
        static: dict[str, tuple[str, tuple]] = {}
        tf_topics = [t for t, m in types.items() if m == TF_MESSAGE]
        for topic in sorted(tf_topics, key=lambda t: t != "/tf_static"):
            seen_values: dict[str, set] = {}
            for _, parent, child, values in _transforms(reader, topic):
                if topic == "/tf_static":
                    static.setdefault(child, (parent, values))
                else:
                    seen_values.setdefault(child, set()).add((parent, values))
            for child, values in seen_values.items():
                if len(values) == 1 and child not in static:
                    static[child] = next(iter(values))

        if types[odom_topic] == ODOMETRY:
            stamps, raw_poses, frames = _read_odometry_topic(reader, odom_topic)
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
                for _, parent, child, _ in _transforms(reader, odom_topic):
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
            for stamp, parent, child, values in _transforms(reader, odom_topic):
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
            offset, flipped = _mount(path, static, base_frame, laser_frame, max_tilt)
    finally:
        reader.close()

    scan_ns = np.array([r["stamp"] for r in records], dtype=np.int64)
    odom_poses, inside, odom_sorted_ns, odom_sorted = _interpolate(path, odom_ns, odom_xyt, scan_ns, collector)
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
    snapped = _snap_increment(increment)
    start = _snap_start(angle_min, increment, snapped)
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
