"""The streaming mapper: Intel fed scan by scan equals the batch run bit for bit,
compiles its step once, and waits for odometry instead of dropping scans."""

from __future__ import annotations

import jax
import numpy as np
import pytest

from jaxslam.grid.stream import StreamingGridSlam

from tests.conftest import INTEL_GRID_OPTIONS


def _mapper(log):
    options = {k: v for k, v in INTEL_GRID_OPTIONS.items() if k not in ("max_keyframes", "progress")}
    return StreamingGridSlam(log.angles, log.laser_offset, **options)


class _Compiles:
    """Counts XLA compilations while active."""

    def __init__(self):
        self.count = 0
        self.active = False
        jax.monitoring.register_event_duration_secs_listener(self._listen)

    def _listen(self, event, duration, **kwargs):
        if self.active and "backend_compile" in event:
            self.count += 1


_COMPILES = _Compiles()


@pytest.mark.long
def test_scan_by_scan_equals_batch_run(intel_segment, intel_grid_reference):
    log, ref = intel_segment, intel_grid_reference
    last = int(ref.keyframes[-1])
    slam = _mapper(log)
    flags = []
    for i in range(last + 1):
        if len(slam.keyframes) == 2:
            _COMPILES.active = True  # after the first filter step: no compilation
        flags += slam.add_scan(log.scan_times[i], log.ranges[i], log.valid[i], odom_pose=log.odom_poses[i])
    _COMPILES.active = False
    assert _COMPILES.count == 0 and slam.step_versions() == 1
    np.testing.assert_array_equal(np.flatnonzero(flags), ref.keyframes)
    np.testing.assert_array_equal(slam.keyframe_poses(), ref.keyframe_poses)
    np.testing.assert_array_equal(slam.trajectory(), ref.trajectory[: last + 1])
    np.testing.assert_array_equal(slam.pose(), ref.trajectory[last])
    log_odds, resolution, origin = slam.map()
    np.testing.assert_array_equal(log_odds, ref.map_log_odds)
    assert resolution == ref.resolution and origin == ref.origin
    for name in ("ess", "resampled", "best_score"):
        np.testing.assert_array_equal(np.asarray(slam.info[name]), ref.info[name])

    # The same through add_odometry: each scan is interpolated at its own odometry's
    # stamp (exact), so the result is the same; the runner is reused, not recompiled.
    again = _mapper(log)
    _COMPILES.active = True
    for i in range(last + 1):
        again.add_odometry(log.scan_times[i], log.odom_poses[i])
        again.add_scan(log.scan_times[i], log.ranges[i], log.valid[i])
    _COMPILES.active = False
    np.testing.assert_array_equal(again.keyframe_poses(), ref.keyframe_poses)
    np.testing.assert_array_equal(again.map()[0], ref.map_log_odds)
    stamps = log.scan_times[: last + 1]
    older = int(np.sum(stamps[1:] < np.maximum.accumulate(stamps)[:-1]))  # older than the newest so far
    assert again.counts["odometry_out_of_order"] == older > 0


def test_scans_wait_for_odometry(intel_segment):
    log = intel_segment
    slam = _mapper(log)
    assert slam.add_scan(log.scan_times[0] - 1.0, log.ranges[0]) == []  # before any odometry: waits
    assert slam.add_scan(log.scan_times[0], log.ranges[0], log.valid[0]) == []
    assert slam.add_odometry(log.scan_times[0] - 0.5, log.odom_poses[0]) == []  # still older than the scans
    # Odometry at the second scan's stamp: the first scan was stamped before all odometry
    # (counted, not placed), the second is interpolated and becomes the first keyframe.
    assert slam.add_odometry(log.scan_times[0] + 0.5, log.odom_poses[0]) == [True]
    assert slam.counts["scans_before_odometry"] == 1 and slam.keyframes == [0]
    np.testing.assert_allclose(slam.pose(), log.odom_poses[0], rtol=0, atol=1e-12)
    with pytest.raises(ValueError, match="has 3 beams, the mapper was built for 180"):
        slam.add_scan(1.0, [1.0, 2.0, 3.0])
