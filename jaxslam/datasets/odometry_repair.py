r"""Odometry whose poses lose the sign of reversing: detected from the log's own
velocities and repaired.

Some robots' logged odometry poses integrate the *speed* rather than the signed
velocity: when the robot backs up, the pose moves forward while the logged
translational velocity ``tv`` is negative. FR079 (``carmen_raw/fr079.clf.gz``) does
this at every one of its 202 reversing scan increments (the ODOM lines say
``tv = -0.5 m/s`` while ``x, y`` advance along the heading); the pose's heading is
right (``rv`` keeps its sign). A filter that trusts such odometry drives forward at
0.1 m per scan while the robot backs up, twice that away from the truth after each
scan: beyond the reach of scan matching (GMapping C++ and jaxslam's tracking lose
their way at these places). Nothing about this is specific to one log: a log that
carries velocities can be checked against its own poses.

For the increment between consecutive scans :math:`i, i+1` (robot frame,
:math:`u_i = o_i^{-1} \oplus o_{i+1}`) and the mean :math:`\bar v_i` of the logged
``tv`` of the odometry messages stamped in :math:`(t_i, t_{i+1}]`:

.. math::
    \text{moving}_i &= |u_{i,x}| > \texttt{MIN\_STEP} \ \wedge\
        |\bar v_i| > \texttt{MIN\_SPEED} \\
    \text{lost}_i &= \text{moving}_i \wedge \bar v_i < 0 \wedge u_{i,x} > 0
       \qquad \text{(backing up, pose moved forward)} \\
    \text{signed}_i &= \text{moving}_i \wedge \bar v_i < 0 \wedge u_{i,x} < 0

The log's poses are declared sign-less when at least :data:`MIN_LOST` increments
are lost and they are at least :data:`MIN_FRACTION` of the reversing ones
(:math:`\text{lost} / (\text{lost} + \text{signed})`): a log whose poses reverse
correctly, or whose velocities are only noisy around zero, is left alone. The repair
negates the translation of each lost increment, :math:`(u_x, u_y, u_\theta) \to
(-u_x, -u_y, u_\theta)` (an arc driven backwards with the same turn has the mirrored
chord), and composes the increments again from the first pose. Logs without
velocities (no ODOM lines, FLASER-only logs) are reported as unchecked.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from jaxslam.datasets.geometry import se2_between, se2_compose

MIN_STEP = 0.005  # m: increments shorter than this are not counted
MIN_SPEED = 0.02  # m/s: |tv| under this is standing still
MIN_LOST = 10
MIN_FRACTION = 0.9


def interval_speeds(scan_times: np.ndarray, odom_times: np.ndarray, odom_speeds: np.ndarray) -> np.ndarray:
    """``(S-1,)`` mean logged ``tv`` of the odometry messages stamped in each
    ``(t_i, t_{i+1}]``; NaN where no message falls in the interval."""
    order = np.argsort(odom_times, kind="stable")
    times, speeds = np.asarray(odom_times)[order], np.asarray(odom_speeds, np.float64)[order]
    edges = np.searchsorted(times, scan_times, side="right")
    sums = np.concatenate([[0.0], np.cumsum(speeds)])
    counts = edges[1:] - edges[:-1]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(counts > 0, (sums[edges[1:]] - sums[edges[:-1]]) / counts, np.nan)


def repair_reverse_odometry(
    odom_poses: np.ndarray, scan_times: np.ndarray, odom_times: np.ndarray, odom_speeds: np.ndarray | None
) -> tuple[np.ndarray, dict[str, Any]]:
    """``(poses, report)``: the odometry with lost reversing repaired (see the module
    docstring) or ``odom_poses`` itself, and what was decided: ``checked``,
    ``reversing_increments``, ``sign_lost``, ``repaired`` and, when repaired, the
    first scan indices of the repaired increments (``scans``, up to 20)."""
    poses = np.asarray(odom_poses, np.float64)
    if odom_speeds is None or len(odom_speeds) == 0 or poses.shape[0] < 2:
        return odom_poses, {"checked": False, "reason": "no odometry velocities in the log", "repaired": False}
    increments = se2_between(poses[:-1], poses[1:])
    speed = interval_speeds(scan_times, odom_times, odom_speeds)
    with np.errstate(invalid="ignore"):
        moving = (np.abs(increments[:, 0]) > MIN_STEP) & (np.abs(speed) > MIN_SPEED)
        backing = moving & (speed < 0)
    lost = backing & (increments[:, 0] > 0)
    signed = backing & (increments[:, 0] < 0)
    report: dict[str, Any] = {
        "checked": True,
        "reversing_increments": int(backing.sum()),
        "sign_lost": int(lost.sum()),
        "sign_kept": int(signed.sum()),
    }
    repair = lost.sum() >= MIN_LOST and lost.sum() >= MIN_FRACTION * backing.sum()
    report["repaired"] = bool(repair)
    if not repair:
        return odom_poses, report
    fixed = increments.copy()
    fixed[lost, :2] *= -1.0
    out = np.empty_like(poses)
    out[0] = poses[0]
    for i in range(fixed.shape[0]):  # host, once per log: a sequential composition
        out[i + 1] = se2_compose(out[i], fixed[i])
    report["scans"] = [int(i) + 1 for i in np.flatnonzero(lost)[:20]]
    return out, report


__all__ = ["MIN_FRACTION", "MIN_LOST", "MIN_SPEED", "MIN_STEP", "interval_speeds", "repair_reverse_odometry"]
