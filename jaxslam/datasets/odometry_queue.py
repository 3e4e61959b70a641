"""Scans waiting for odometry: a stream of scans paired with the odometry messages
around their stamps, for the streaming filters
(:class:`jaxslam.grid.stream.StreamingGridSlam`,
:class:`jaxslam.localization.stream.StreamingLocalizer`).

A scan waits until odometry at or after its stamp has arrived, then takes the pose
interpolated between the two messages around it
(:func:`jaxslam.datasets.rosbag_messages.interpolate_odometry`); a scan older than the
first odometry message is dropped and counted (``scans_before_odometry``), and a
message older than the newest one is inserted in time order and counted
(``odometry_out_of_order``).
"""

from __future__ import annotations

import bisect
from typing import Iterator

import numpy as np

from jaxslam.datasets.rosbag_messages import interpolate_odometry


class OdometryQueue:
    """Odometry messages in time order and the scans waiting for them.

    Args:
        counts: the dict whose ``scans_before_odometry`` and ``odometry_out_of_order``
            entries are incremented (the streaming filter's ``counts``).
    """

    def __init__(self, counts: dict):
        self.counts = counts
        self.times: list[float] = []
        self.poses: list[np.ndarray] = []
        self.pending: list[tuple[float, tuple]] = []

    def add_odometry(self, stamp: float, pose) -> None:
        """An odometry pose ``(x, y, theta)`` at ``stamp``."""
        pose = np.asarray(pose, np.float64).reshape(3)
        at = bisect.bisect_right(self.times, float(stamp))
        if at < len(self.times):
            self.counts["odometry_out_of_order"] += 1
        self.times.insert(at, float(stamp))
        self.poses.insert(at, pose)

    def add_scan(self, stamp: float, payload: tuple) -> None:
        """A scan at ``stamp`` (``payload``: whatever the filter needs of it) to wait."""
        self.pending.append((float(stamp), payload))

    def ready(self) -> Iterator[tuple[float, tuple, np.ndarray]]:
        """``(stamp, payload, odometry pose (3,))`` of each waiting scan, oldest first,
        as long as odometry at or after its stamp has arrived."""
        while self.pending and self.times:
            stamp, payload = self.pending[0]
            if stamp > self.times[-1]:
                return  # wait for newer odometry
            self.pending.pop(0)
            if stamp < self.times[0]:
                self.counts["scans_before_odometry"] += 1
                continue
            # the two messages around the stamp (O(log n) per scan on long runs)
            at = max(bisect.bisect_right(self.times, stamp) - 1, 0)
            pose, _ = interpolate_odometry(np.asarray(self.times[at: at + 2]), np.asarray(self.poses[at: at + 2]),
                                           [stamp])
            yield stamp, payload, pose[0]


__all__ = ["OdometryQueue"]
