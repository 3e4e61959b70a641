"""GPS error: rigid alignment, known errors, jump rejection."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxslam.metrics.gps import align_rigid_2d, gps_error, gps_jump_mask


def rotation(angle: float) -> np.ndarray:
    return np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])


def drive(n: int = 400, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A smooth 2-D path sampled at 5 Hz, about 3 m/s: (times, xy)."""
    times = np.arange(n) * 0.2
    heading = 0.3 * np.sin(times / 7.0) + 0.02 * times
    rng = np.random.default_rng(seed)
    speed = 3.0 + 0.2 * rng.standard_normal(n).cumsum() / np.sqrt(n)
    xy = np.cumsum(0.2 * speed[:, None] * np.stack([np.cos(heading), np.sin(heading)], 1), axis=0)
    return times, xy


@settings(max_examples=30, deadline=None)
@given(angle=st.floats(-np.pi, np.pi), shift=st.tuples(st.floats(-500, 500), st.floats(-500, 500)))
def test_rotated_and_translated_gps_gives_zero_error(angle, shift):
    times, gps_xy = drive()
    # The estimate lives in its own frame: gps = R est + t.
    est = (gps_xy - np.asarray(shift)) @ rotation(angle)
    result = gps_error(times, est, times, gps_xy)
    assert result["gps_max_m"] < 1e-6
    assert result["n_used"] == times.size and result["n_skipped"] == 0
    np.testing.assert_allclose(result["rotation"], rotation(angle), atol=1e-9)
    np.testing.assert_allclose(result["translation"], shift, atol=1e-6)
    assert np.cos(result["rotation_rad"] - angle) == pytest.approx(1.0)


def test_known_radial_offset_gives_the_known_error():
    # Concentric circles: no rigid motion brings one closer to the other, so every fix
    # is exactly `offset` away after alignment.
    times = np.arange(500) * 0.2
    angles = 2 * np.pi * times / 100.0  # one full turn, evenly sampled
    gps_xy = 30.0 * np.stack([np.cos(angles), np.sin(angles)], 1)
    offset = 1.5
    est = (30.0 + offset) * np.stack([np.cos(angles), np.sin(angles)], 1)
    result = gps_error(times, est, times, gps_xy)
    assert result["gps_mean_m"] == pytest.approx(offset, abs=1e-6)
    assert result["gps_rms_m"] == pytest.approx(offset, abs=1e-6)
    assert result["gps_max_m"] == pytest.approx(offset, abs=1e-6)


def test_known_error_after_an_early_alignment():
    times, gps_xy = drive()
    est = gps_xy.copy()
    late = times > 40.0
    est[late] += np.array([0.0, 2.0])  # a 2 m jump in the estimate after 40 s
    result = gps_error(times, est, times, gps_xy, align_seconds=30.0)
    assert result["n_aligned"] == int((times <= 30.0).sum())
    np.testing.assert_allclose(result["errors_m"][~late], 0.0, atol=1e-6)
    np.testing.assert_allclose(result["errors_m"][late], 2.0, atol=1e-6)
    assert result["gps_max_m"] == pytest.approx(2.0)


def test_estimate_is_interpolated_at_gps_times():
    times, gps_xy = drive()
    est_times = times[::5]  # a coarser estimate on a straight-ish path
    result = gps_error(est_times, gps_xy[::5], times, gps_xy)
    assert result["gps_mean_m"] < 0.05
    fixes_inside = (times >= est_times[0]) & (times <= est_times[-1])
    assert result["n_used"] == fixes_inside.sum()
    assert result["n_skipped_outside"] == (~fixes_inside).sum()


def test_gps_spikes_and_steps_are_skipped():
    times, gps_xy = drive()
    est = gps_xy.copy()
    noisy = gps_xy.copy()
    noisy[50] += [40.0, 0.0]  # a spike: one fix 40 m off
    noisy[200:260] += [0.0, 25.0]  # a step: the receiver sits 25 m off for 12 s
    keep = gps_jump_mask(times, noisy)
    assert not keep[50] and keep[49] and keep[51]
    # The step is rejected until 10 m/s * dt + 1 m reaches its ~25 m (about 2.5 s at
    # 5 Hz), then the new track is taken up; the same happens when it ends.
    assert not keep[200:208].any() and keep[220:260].all()
    assert not keep[260:268].any() and keep[280:].all()
    result = gps_error(times, est, times, noisy)
    assert result["n_skipped_jumps"] == (~keep).sum()
    assert 1 + 2 * 8 <= result["n_skipped_jumps"] <= 1 + 2 * 20
    assert result["n_used"] + result["n_skipped"] == times.size
    assert np.isnan(result["errors_m"][50])


def test_jump_rule_thresholds():
    times = np.array([0.0, 1.0, 2.0, 2.2])
    xy = np.array([[0.0, 0.0], [10.9, 0.0], [22.0, 0.0], [22.0, 3.1]])
    # Fix 1: 10.9 m <= 10 * 1 + 1. Fix 2: 11.1 m > 11 from fix 1. Fix 3 is measured from
    # fix 1, the last kept: 11.5 m <= 10 * 1.2 + 1.
    keep = gps_jump_mask(times, xy, max_speed=10.0, noise_m=1.0)
    np.testing.assert_array_equal(keep, [True, True, False, True])


def test_align_rigid_2d_never_reflects():
    source = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    mirrored = source * [1.0, -1.0]
    rot, _ = align_rigid_2d(source, mirrored)
    assert np.linalg.det(rot) == pytest.approx(1.0)


def test_bad_inputs_are_refused():
    times, gps_xy = drive(20)
    with pytest.raises(ValueError, match="only 0 GPS fixes"):
        gps_error(times + 1000.0, gps_xy, times, gps_xy)
    with pytest.raises(ValueError, match="do not match"):
        gps_error(times[:-1], gps_xy, times, gps_xy)
    est = gps_xy.copy()
    est[3, 0] = np.nan
    with pytest.raises(ValueError, match="non-finite"):
        gps_error(times, est, times, gps_xy)
