"""The usable range chosen from the log's readings (jaxslam.grid.range_rule)."""

import dataclasses

import numpy as np
import pytest

from jaxslam.datasets.laser_sim import simulate
from jaxslam.grid.experiment import run_grid_slam
from jaxslam.grid.range_rule import FAR_FRACTION, FAR_RANGE, NEAR_RANGE, choose_range


def readings(far_fraction: float, n: int = 2000, far: float = 35.0, seed: int = 0):
    rng = np.random.default_rng(seed)
    ranges = rng.uniform(0.5, NEAR_RANGE, n)
    ranges[: int(round(far_fraction * n))] = far
    return rng.permutation(ranges).reshape(20, -1), np.ones((20, n // 20), bool)


def test_indoor_log_keeps_the_near_range():
    ranges, valid = readings(0.02)
    rule = choose_range(ranges, valid, 80.0)
    assert rule["usable_range"] == NEAR_RANGE and rule["score_range"] == NEAR_RANGE and not rule["far_field"]
    assert rule["far_fraction"] == pytest.approx(0.02)


@pytest.mark.parametrize("max_range,usable", [(80.0, FAR_RANGE), (120.0, FAR_RANGE), (50.0, 50.0), (None, FAR_RANGE)])
def test_far_field_log_uses_the_far_range(max_range, usable):
    ranges, valid = readings(0.25)
    rule = choose_range(ranges, valid, max_range)
    assert rule["far_field"] and rule["usable_range"] == usable and rule["score_range"] == usable


def test_threshold_and_invalid_readings():
    ranges, valid = readings(FAR_FRACTION)  # exactly at the threshold: not above it
    assert not choose_range(ranges, valid)["far_field"]
    ranges, valid = readings(0.3)
    valid &= ranges <= NEAR_RANGE  # far readings that are not valid hits do not count
    assert choose_range(ranges, valid)["far_fraction"] == 0.0
    # no valid reading at all: the near range, no division by zero
    rule = choose_range(np.zeros((3, 4)), np.zeros((3, 4), bool))
    assert rule["usable_range"] == NEAR_RANGE and rule["far_fraction"] == 0.0


NO_SEARCH = {"closure": False}


@pytest.mark.long
def test_run_grid_slam_applies_and_reports_the_rule():
    base = simulate(width=12.0, height=8.0, rooms_x=2, laps=0.3, num_beams=91, seed=2, max_range=60.0)
    # Readings stretched sixfold: a far field (the run is only a few keyframes long;
    # the wiring is under test, not the map).
    far = dataclasses.replace(base, ranges=base.ranges * 6.0)
    want = choose_range(far.ranges, far.valid, far.max_range)
    assert want["far_field"]
    # (The loop-closure search off: it is not under test, and it doubles the compilation.)
    result = run_grid_slam(far, "srupf-gm", particles=2, seed=0, progress=False, max_keyframes=3, config=NO_SEARCH)
    assert result.range_rule == {"source": "log", **want}
    assert result.summary()["range_rule"] == result.range_rule
    assert result.params["sensor.usable_range"] == want["usable_range"]
    assert result.params["sensor.score_range"] == want["usable_range"]
    assert result.config.window_range == 10.0 * np.ceil(want["usable_range"] / 10.0)
    # an explicit usable range turns the rule off
    own = run_grid_slam(far, "srupf-gm", particles=2, seed=0, progress=False, max_keyframes=3,
                        params={"sensor.usable_range": 15.0}, config=NO_SEARCH)
    assert own.range_rule == {"source": "params"} and own.params["sensor.usable_range"] == 15.0
