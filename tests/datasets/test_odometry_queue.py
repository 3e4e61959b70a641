"""Scans waiting for odometry: order, waiting, interpolation and the counts."""

from __future__ import annotations

import numpy as np

from jaxslam.datasets.odometry_queue import OdometryQueue


def test_scans_wait_for_odometry_and_take_the_interpolated_pose():
    counts = {"scans_before_odometry": 0, "odometry_out_of_order": 0}
    queue = OdometryQueue(counts)
    queue.add_scan(0.5, ("early",))
    queue.add_odometry(1.0, (0.0, 0.0, 0.0))
    assert list(queue.ready()) == [] and counts["scans_before_odometry"] == 1  # older than any odometry
    queue.add_scan(1.5, ("a",))
    queue.add_scan(2.25, ("b",))
    assert list(queue.ready()) == []  # no odometry at or after 1.5 yet
    queue.add_odometry(3.0, (2.0, 4.0, 0.4))
    queue.add_odometry(2.0, (1.0, 2.0, 0.2))  # late: inserted in time order
    assert counts["odometry_out_of_order"] == 1
    out = list(queue.ready())
    assert [(stamp, payload) for stamp, payload, _ in out] == [(1.5, ("a",)), (2.25, ("b",))]
    np.testing.assert_allclose(out[0][2], [0.5, 1.0, 0.1], atol=1e-12)
    np.testing.assert_allclose(out[1][2], [1.25, 2.5, 0.25], atol=1e-12)
    assert queue.pending == []
