"""jaxslam.grid.laser_odometry: a turn in place that the wheel odometry misses (the
FR079 doorway case) is recovered from the scans."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from jaxslam.datasets.geometry import se2_between, se2_compose, wrap_angle
from jaxslam.datasets.laser_sim import office_world, raycast, simulate
from jaxslam.grid.laser_odometry import laser_corrected_log, laser_heading_increments


def _missed_turn_log(seen: float = 0.2, seed: int = 0):
    """Down the bottom corridor, a 90 deg turn in place at the corner, up the right
    corridor; the odometry sees only ``seen`` of each in-place rotation."""
    width, height, corridor = 16.0, 10.0, 2.0
    c = corridor / 2
    walls = office_world(width, height, corridor, 3, seed=seed)
    xs = np.arange(3.0, width - c + 1e-9, 0.1)
    leg1 = np.column_stack([xs, np.full_like(xs, c), np.zeros_like(xs)])
    turn = np.linspace(0, np.pi / 2, 13)[1:]
    leg2 = np.column_stack([np.full_like(turn, width - c), np.full_like(turn, c), turn])
    ys = np.arange(c + 0.1, height - 2.5, 0.1)
    leg3 = np.column_stack([np.full_like(ys, width - c), ys, np.full_like(ys, np.pi / 2)])
    true = np.concatenate([leg1, leg2, leg3])
    base = simulate(width=width, height=height, corridor=corridor, laps=0.2, num_beams=181, seed=seed)
    rng = np.random.default_rng(seed)
    headings = true[:, 2:3] + np.asarray(base.angles, np.float64)[None]
    ranges = raycast(walls, true[:, :2], headings, base.max_range)
    no_return = ~np.isfinite(ranges)
    ranges = np.where(no_return, base.max_range, ranges + rng.normal(0, 0.01, ranges.shape))
    steps = se2_between(true[:-1], true[1:])
    in_place = np.hypot(steps[:, 0], steps[:, 1]) < 1e-6
    steps[in_place, 2] *= seen
    odom = np.empty_like(true)
    odom[0] = true[0]
    for k, u in enumerate(steps):
        odom[k + 1] = se2_compose(odom[k], u)
    s = true.shape[0]
    times = 1000.0 + 0.2 * np.arange(s)
    log = dataclasses.replace(
        base, scan_times=times, logger_times=times - times[0], scan_lines=np.arange(1, s + 1),
        ranges=ranges.astype(np.float32), valid=~no_return, max_range_mask=no_return,
        angle_offsets=np.zeros(s, np.float32), odom_poses=odom, laser_poses=odom.copy(),
        odom_times=times.copy(), odom_readings=odom.copy(), true_poses=true, walls=walls,
    )
    return log


def test_missed_turn_in_place_is_recovered():
    log = _missed_turn_log()
    heading_error = np.degrees(np.abs(wrap_angle(log.odom_poses[-1, 2] - log.true_poses[-1, 2])))
    assert heading_error > 60  # the wheels miss 80 % of the 90 deg turn
    corrected = laser_corrected_log(log)
    error = np.degrees(np.abs(wrap_angle(corrected.odom_poses[:, 2] - log.true_poses[:, 2])))
    assert error.max() < 2.0
    assert corrected.stats["laser_odometry_accepted"] >= 10
    # Translation stays the odometry's: positions differ only through the heading.
    np.testing.assert_allclose(corrected.odom_poses[:50], log.true_poses[:50], atol=1e-3)


def test_featureless_scans_keep_the_odometry():
    log = _missed_turn_log()
    empty = dataclasses.replace(log, valid=np.zeros_like(log.valid))
    increments, info = laser_heading_increments(empty)
    assert not info["accepted"].any()
    np.testing.assert_allclose(increments, se2_between(log.odom_poses[:-1], log.odom_poses[1:]), atol=1e-9)


@pytest.mark.slow
def test_missed_turn_is_mapped_with_the_defaults():
    from jaxslam.grid.experiment import run_grid_slam

    log = _missed_turn_log()
    errors = {}
    for name, source in (("wheels", log), ("laser", laser_corrected_log(log))):
        result = run_grid_slam(source, "srupf-gm", particles=10, seed=0, progress=False)
        rel = se2_between(result.trajectory[:1], result.trajectory)
        truth = se2_between(log.true_poses[:1], log.true_poses)
        errors[name] = float(np.hypot(*(rel[:, :2] - truth[:, :2]).T).max())
    assert errors["laser"] < 0.3
    assert errors["wheels"] > 3 * errors["laser"]
