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

The log's poses are declared sign-less when at least ``MIN_LOST`` increments
are lost and they are at least ``MIN_FRACTION`` of the reversing ones
(:math:`\text{lost} / (\text{lost} + \text{signed})`): a log whose poses reverse
correctly, or whose velocities are only noisy around zero, is left alone. The repair
negates the translation of each lost increment, :math:`(u_x, u_y, u_\theta) \to
(-u_x, -u_y, u_\theta)` (an arc driven backwards with the same turn has the mirrored
chord), and composes the increments again from the first pose. Logs without
velocities (no ODOM lines, FLASER-only logs) are reported as unchecked.

**Stale odometry** (:func:`repair_stale_odometry`). A CARMEN laser message carries the
odometry pose of the last odometry reading the logger had. Where odometry readings
stop arriving for a while (a dropped connection, a busy base), the scans of that
stretch repeat one pose exactly and the first scan after it carries the whole motion
of the stretch at once. MIT CSAIL (``carmen_raw/mit-csail.clf.gz``) has three such
stretches, four scans (0.84 s) each, during turns: the pose stands still, then jumps
0.86 m and 50 deg, 0.95 m and 8 deg, 0.47 m and 86 deg in one scan. A filter that
processes keyframes only sees the right motion over the keyframe interval. One that
follows every scan (:mod:`jaxslam.grid.tracking`) matches the scans of the stretch,
so it already turns with the robot there, and then adds the catch-up on top: 40-50
deg beyond the matcher's reach, and the map breaks at these places. A ROS bag does not have this problem: the reader interpolates the
odometry at each scan's stamp (:mod:`jaxslam.datasets.rosbag`).

For a stretch of scans :math:`i .. j-1` whose pose equals :math:`o_{i-1}` exactly,
followed by a new pose at :math:`j`, the catch-up is :math:`c = o_{i-1}^{-1} \oplus
o_j`. The steps around it are :math:`u_b = o_{i-2}^{-1} \oplus o_{i-1}` and
:math:`u_a = o_j^{-1} \oplus o_{j+1}`. The stretch is stale when the catch-up is
larger than ``STALE_RATIO`` times the mean of the two steps and larger than what
any matcher reaches anyway (``STALE_MIN_STEP``, ``STALE_MIN_TURN``), in
translation or in rotation:

.. math::
    |c_{xy}| > \max\big(R\,\tfrac{1}{2}(|u_{b,xy}| + |u_{a,xy}|),\ \texttt{STALE\_MIN\_STEP}\big)
    \ \vee\ |c_\theta| > \max\big(R\,\tfrac{1}{2}(|u_{b,\theta}| + |u_{a,\theta}|),
    \ \texttt{STALE\_MIN\_TURN}\big)

Steps per scan, not speeds: some logs' stamps are out of order (Intel's run backwards
by up to 0.9 s), while laser scans come at a steady rate. A robot that really stood
still and drives off takes a first step no larger than the ones after it, and is left
alone. A stale stretch gets the catch-up spread over its time, :math:`o_k = o_{i-1}
\oplus \exp(\alpha_k \log c)` with :math:`\alpha_k = (t_k - t_{i-1}) / (t_j -
t_{i-1})` (by scan count where the stamps are out of order), :math:`\exp, \log` of
SE(2) (:func:`jaxslam.datasets.geometry.se2_exp`): the pose of a steady arc from
:math:`o_{i-1}` to :math:`o_j`, what the odometry would have reported had its readings
kept coming. Stretches at the end of the
log (no new pose after them) are left alone.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from jaxslam.datasets.geometry import se2_between, se2_compose, se2_exp, se2_log

MIN_STEP = 0.005  # m: increments shorter than this are not counted
MIN_SPEED = 0.02  # m/s: |tv| under this is standing still
MIN_LOST = 10
MIN_FRACTION = 0.9
STALE_RATIO = 2.0  # a catch-up this many times the steps around it is stale odometry
STALE_MIN_STEP = 0.05  # m: a smaller catch-up is within any matcher's reach, left alone
STALE_MIN_TURN = 0.05  # rad: the same for turns


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


def _outlier(step: np.ndarray, near: list[int], step_xy: np.ndarray, step_th: np.ndarray) -> bool:
    """Whether ``step`` exceeds ``STALE_RATIO`` times the mean of the steps ``near``
    and the floor, in translation or in rotation (the module docstring's test)."""
    near_xy = float(np.mean(step_xy[near])) if near else 0.0
    near_th = float(np.mean(step_th[near])) if near else 0.0
    xy, th = math.hypot(step[0], step[1]), abs(step[2])
    return bool((xy > STALE_MIN_STEP and xy > STALE_RATIO * near_xy) or (th > STALE_MIN_TURN and th > STALE_RATIO * near_th))


def repair_stale_odometry(odom_poses: np.ndarray, scan_times: np.ndarray) -> tuple[np.ndarray, dict[str, Any]]:
    """``(poses, report)``: stale stretches of odometry spread over their time (see the
    module docstring), or ``odom_poses`` itself where there are none. The report has
    ``stale_stretches`` (repeated poses followed by a new one), ``repaired`` (how many
    were stale), ``repaired_scans`` (poses replaced), ``extended`` (of those, the
    fresh readings that still carried part of a catch-up) and ``scans`` (the first
    scan of each repaired stretch, up to 20)."""
    poses = np.asarray(odom_poses, np.float64)
    times = np.asarray(scan_times, np.float64)
    report: dict[str, Any] = {"stale_stretches": 0, "repaired": 0, "repaired_scans": 0, "extended": 0, "scans": []}
    n = poses.shape[0]
    if n < 3:
        return odom_poses, report
    same = np.all(poses[1:] == poses[:-1], axis=1)  # (n-1,): scan k+1 repeats scan k
    steps = se2_between(poses[:-1], poses[1:])
    step_xy, step_th = np.hypot(steps[:, 0], steps[:, 1]), np.abs(steps[:, 2])
    out = None
    k = 1
    while k < n:
        if not same[k - 1]:
            k += 1
            continue
        i = k  # scans i .. j-1 repeat scan i-1
        while k < n and same[k - 1]:
            k += 1
        j = k
        if j >= n:  # no new pose after the stretch
            break
        report["stale_stretches"] += 1
        catch = se2_between(poses[i - 1], poses[j])
        if not _outlier(catch, [s for s in (i - 2, j) if 0 <= s < n - 1], step_xy, step_th):
            continue
        # The catch-up may come over more than one reading: the next steps join it while
        # they are outliers too (at most as many as the stretch held).
        end = j
        while end - j < j - i and end + 1 < n - 1 and not same[end] and not same[end + 1] and _outlier(
            steps[end], [s for s in (i - 2, end + 1) if s >= 0], step_xy, step_th
        ):
            end += 1
        catch = se2_between(poses[i - 1], poses[end])
        if out is None:
            out = poses.copy()
        span = times[i - 1 : end + 1]
        if np.all(np.diff(span) > 0):  # spread by time
            alpha = (span[1:-1] - span[0]) / (span[-1] - span[0])
        else:  # stamps out of order: spread by scan
            alpha = np.arange(1, end - i + 1) / (end - i + 1)
        out[i:end] = se2_compose(poses[i - 1], se2_exp(alpha[:, None] * se2_log(catch)[None, :]))
        report["repaired"] += 1
        report["repaired_scans"] += end - i
        report["extended"] += end - j
        if len(report["scans"]) < 20:
            report["scans"].append(int(i))
    return (odom_poses if out is None else out), report


__all__ = [
    "MIN_FRACTION",
    "MIN_LOST",
    "MIN_SPEED",
    "MIN_STEP",
    "STALE_MIN_STEP",
    "STALE_MIN_TURN",
    "STALE_RATIO",
    "interval_speeds",
    "repair_reverse_odometry",
    "repair_stale_odometry",
]
