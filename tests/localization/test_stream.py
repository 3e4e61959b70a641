"""The streaming localizer: scan by scan, in chunks, or from odometry messages, the batch run's result."""

from __future__ import annotations

import chex
import numpy as np
import pytest

from jaxslam.grid.mapfile import segment_map
from jaxslam.localization.experiment import localize
from jaxslam.localization.stream import StreamingLocalizer
from tests.localization.worlds import BOUNDS, crate_world, laser_log, ring_poses

SCANS = 40


@pytest.fixture(scope="module")
def world():
    walls = crate_world()
    grid = segment_map(walls, BOUNDS, 0.05)
    return grid, laser_log(walls, ring_poses()[:SCANS], seed=3)


def _localizer(grid, log, **kwargs):
    return StreamingLocalizer(grid, log.angles, log.max_range, log.laser_offset, **kwargs)


@pytest.mark.parametrize("start", ["tracking", "global"])
def test_scan_by_scan_is_the_batch_run(world, start):
    grid, log = world
    options = dict(particles=2000, seed=4, initial_pose=log.true_poses[0] if start == "tracking" else None)
    batch = localize(log, grid, chunk=16, **options)
    loc = _localizer(grid, log, **options)
    flags = [loc.add_scan(t, r, v, odom_pose=o)
             for t, r, v, o in zip(log.scan_times, log.ranges, log.valid, log.odom_poses)]
    assert all(len(f) == 1 for f in flags)
    chex.assert_trees_all_close(loc.trajectory(), batch.trajectory, atol=1e-5)
    info = loc.info()
    for name in ("particles", "injected", "updated", "resampled"):
        np.testing.assert_array_equal(info[name], batch.info[name], err_msg=name)
    chex.assert_trees_all_close(info["ess"], batch.info["ess"], rtol=1e-4)
    assert np.array_equal(np.concatenate(flags), batch.info["updated"])
    assert loc.ess() == pytest.approx(float(batch.info["ess"][-1]), rel=1e-4)
    assert loc.particles_in_use() == int(batch.info["particles"][-1])
    assert loc.injections() == int(np.sum(batch.info["injected"] > 0))
    np.testing.assert_allclose(loc.pose(), batch.trajectory[-1], atol=1e-5)


def test_other_chunks_are_the_same_program_per_length_and_the_same_result(world):
    grid, log = world
    options = dict(particles=2000, seed=4, initial_pose=log.true_poses[0])
    batch = localize(log, grid, chunk=16, **options)
    loc = _localizer(grid, log, **options)
    for lo, hi in [(0, 16), (16, 32), (32, SCANS)]:  # the batch run's chunks
        loc.add_scans(log.scan_times[lo:hi], log.ranges[lo:hi], log.valid[lo:hi], log.odom_poses[lo:hi])
    np.testing.assert_array_equal(loc.trajectory(), batch.trajectory)  # the same programs: bit for bit


def test_odometry_messages_give_the_poses_of_the_scans(world):
    """Scans without their odometry wait for the odometry messages after them; the
    poses interpolated at the scans' stamps (here the messages are at the stamps
    themselves) give the same run as poses given with the scans."""
    grid, log = world
    options = dict(particles=1000, seed=2, initial_pose=log.true_poses[0])
    given = _localizer(grid, log, **options)
    fed = _localizer(grid, log, **options)
    processed = []
    for t, r, v, o in zip(log.scan_times[:12], log.ranges[:12], log.valid[:12], log.odom_poses[:12]):
        given.add_scan(t, r, v, odom_pose=o)
        assert fed.add_scan(t, r, v) == []  # waits for odometry at or after its stamp
        processed += fed.add_odometry(t, o)
    assert len(processed) == 12 and fed.counts["scans"] == 12
    np.testing.assert_array_equal(fed.trajectory(), given.trajectory())


def test_a_scan_with_the_wrong_beam_count_is_refused(world):
    grid, log = world
    loc = _localizer(grid, log, particles=500, initial_pose=log.true_poses[0])
    with pytest.raises(ValueError, match="has 3 beams"):
        loc.add_scan(0.0, [1.0, 2.0, 3.0], odom_pose=(0, 0, 0))
