"""The messages of a ROS bag as arrays: laser scans with their beam geometry,
odometry (a topic or ``/tf``), transforms, the laser mount, headings from quaternions
and odometry interpolated to the scan stamps. The conventions (time base, headings,
beam geometry, range policy) are those of :mod:`jaxslam.datasets.rosbag`, which
builds a :class:`~jaxslam.datasets.carmen.CarmenLog` from them.
"""

from __future__ import annotations

import math
from fractions import Fraction

import numpy as np

from jaxslam.datasets.paths import DataFormatError

LASER_SCAN = "sensor_msgs/msg/LaserScan"
ODOMETRY = "nav_msgs/msg/Odometry"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"
_POLISH_ULPS = 4


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

def _stamp_ns(msg) -> int:
    return int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)


def snap_increment(increment: float) -> float:
    """``pi / k`` when it rounds to the float32 ``increment``; else ``increment``."""
    if not (math.isfinite(increment) and increment != 0.0):
        return increment
    k = round(math.pi / abs(increment))
    if k >= 1 and np.float32(math.pi / k) == np.float32(abs(increment)):
        return math.copysign(math.pi / k, increment)
    return increment


def snap_start(start: float, increment: float, snapped: float) -> float:
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


def read_scans(reader, path, topic, collector, max_backstep):
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


def read_odometry_topic(reader, topic):
    stamps, poses, frames = [], [], set()
    for conn, _, raw in reader.messages(connections=reader.topics[topic].connections):
        msg = reader.deserialize(raw, conn.msgtype)
        p = msg.pose.pose
        stamps.append(_stamp_ns(msg))
        poses.append((p.position.x, p.position.y, p.orientation.x, p.orientation.y,
                      p.orientation.z, p.orientation.w))
        frames.add((msg.header.frame_id, msg.child_frame_id))
    return stamps, poses, frames


def read_transforms(reader, topic):
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


def laser_mount(path, static, base, laser, max_tilt):
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


def odometry_at_scans(path, odom_ns, odom_xyt, scan_ns, collector):
    """Odometry at each scan stamp; ``(poses, placed mask, sorted stamps, sorted poses)``."""
    order = np.argsort(odom_ns, kind="stable")
    collector.count("odom_backwards_timestamps", int(np.sum(np.diff(odom_ns) < 0)))
    times = odom_ns[order]
    poses = odom_xyt[order]
    out, inside = interpolate_odometry(times, poses, scan_ns)
    return out, inside, times, poses
