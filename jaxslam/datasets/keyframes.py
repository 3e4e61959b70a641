"""GMapping's keyframe rule: which scans a filter processes (:func:`~jaxslam.datasets.keyframes.select_keyframes`)."""

from __future__ import annotations

import numpy as np

from jaxslam.datasets.geometry import se2_between

def select_keyframes(
    odom_poses: np.ndarray,
    linear: float = 1.0,
    angular: float = 0.5,
    temporal: float = -1.0,
    times: np.ndarray | None = None,
) -> np.ndarray:
    """Indices of the scans GMapping would process (its linear/angular/temporal update).

    As in GMapping's ``GridSlamProcessor::processScan``: between consecutive scans the
    odometric motion ``d = odom_{k-1}^-1 (+) odom_k`` adds ``|d_xy|`` to a linear and
    ``|wrap(d_theta)|`` to an angular accumulator. A scan is a keyframe when it is the
    first one, or an accumulator reaches its threshold (``>=``), or ``temporal >= 0``
    and more than ``temporal`` seconds passed since the last keyframe; the
    accumulators then restart from zero.

    Args:
        odom_poses: (S, 3) odometry poses ``(x, y, theta)``.
        linear: GMapping ``linearUpdate`` (m).
        angular: GMapping ``angularUpdate`` (rad).
        temporal: GMapping ``temporalUpdate`` (s); negative disables it.
        times: (S,) scan times, needed only when ``temporal >= 0``.

    Returns:
        (K,) int64 increasing indices into the scans; ``0`` is always first.
    """
    poses = np.asarray(odom_poses, dtype=np.float64)
    if poses.ndim != 2 or poses.shape[1] != 3:
        raise ValueError(f"odom_poses must have shape (S, 3), got {poses.shape}")
    if poses.shape[0] == 0:
        return np.zeros(0, dtype=np.int64)
    if temporal >= 0 and times is None:
        raise ValueError("temporal >= 0 needs the scan times")
    steps = se2_between(poses[:-1], poses[1:])
    step_linear = np.hypot(steps[:, 0], steps[:, 1])
    step_angular = np.abs(steps[:, 2])
    stamps = None if times is None else np.asarray(times, dtype=np.float64)
    keyframes = [0]
    linear_sum = angular_sum = 0.0
    last_time = None if stamps is None else stamps[0]
    for index in range(1, poses.shape[0]):
        linear_sum += step_linear[index - 1]
        angular_sum += step_angular[index - 1]
        due = temporal >= 0 and stamps[index] - last_time > temporal
        if linear_sum >= linear or angular_sum >= angular or due:
            keyframes.append(index)
            linear_sum = angular_sum = 0.0
            if stamps is not None:
                last_time = stamps[index]
    return np.array(keyframes, dtype=np.int64)
