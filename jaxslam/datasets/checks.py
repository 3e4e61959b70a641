"""What a laser log must hold before a filter runs on it, and how odd stamps and
odometry are handled.

:func:`check_laser_log` runs on every log ``jaxslam run`` maps (CARMEN logs and ROS
bags alike, after the loader's own checks) and raises
:class:`~jaxslam.datasets.paths.DataFormatError` naming the file and the scan (its
line in a CARMEN log, its message index on the scan topic in a ROS bag) where a log
cannot give a true map:

* fewer than two scans (nothing to filter);
* no reading that is a return (every beam at or beyond the range limit, ``inf`` or
  NaN): no wall to match or map;
* an odometry step between two consecutive scans longer than ``max_odometry_step``
  (:data:`MAX_ODOMETRY_STEP`, 10 m by default): no robot that logs its laser moves so
  far between two scans (the registered logs' largest step is 3.3 m, at GMapping's
  corrected keyframes of ``orebro``; raw logs stay under 1 m), so the step is a
  fault of the odometry (a reset, a wrapped counter), and mapping it as motion
  stretches the map and the path by it;
* scan stamps that do not advance (all equal, or the last before the first) when the
  temporal keyframe rule is on (it counts seconds between scans).

Stamps that are repeated or go back are otherwise kept as logged (Intel's raw log
has 631 short backward steps; several GMapping-corrected logs print one stamp for
all scans): the filters use stamps only for the temporal keyframe rule (off by
default), and ``trajectory.tum`` carries the logged stamps. The counts are reported
(``summary.json`` ``log_checks``), so that a trajectory whose stamps cannot be
matched to a reference says so.
"""

from __future__ import annotations

import numpy as np

from jaxslam.datasets.geometry import se2_between
from jaxslam.datasets.paths import DataFormatError

__all__ = ["MAX_ODOMETRY_STEP", "check_laser_log"]

MAX_ODOMETRY_STEP = 10.0
"""Longest odometry step between two consecutive scans taken as motion (m); see the
module docstring. ``jaxslam run --max-odometry-step`` sets it."""


def _where(log, index: int) -> tuple[int | None, str]:
    """``(line, text)`` naming scan ``index`` of ``log``: a CARMEN line, or a bag's
    message index on the scan topic."""
    lines = getattr(log, "scan_lines", None)
    if lines is None or index >= len(lines):
        return None, f"scan {index}"
    if getattr(log, "message", "") == "LaserScan":
        return None, f"scan message {int(lines[index])}"
    return int(lines[index]), f"the scan on line {int(lines[index])}"


def check_laser_log(log, max_odometry_step: float = MAX_ODOMETRY_STEP, temporal: bool = False) -> dict:
    """Refuse a log that cannot give a true map (see the module docstring); return
    what was checked, for ``summary.json``.

    Args:
        log: a :class:`jaxslam.datasets.carmen.CarmenLog` (CARMEN log or ROS bag).
        max_odometry_step: longest odometry step between consecutive scans (m).
        temporal: whether the temporal keyframe rule is on (stamps must advance).

    Returns:
        ``scans``, ``stamp_steps_repeated``, ``stamp_steps_backward``, ``stamp_span_s``,
        ``stamps_advance``, ``max_odometry_step_m`` (the log's longest step) and
        ``odometry_step_bound_m``.

    Raises:
        DataFormatError: naming the file, the scan and the problem.
    """
    path = log.path
    scans = int(log.num_scans)
    if scans < 2:
        raise DataFormatError(path, None, f"holds {scans} scan(s); a run needs at least two")
    ranges = np.asarray(log.ranges, np.float64)
    valid = np.asarray(log.valid, bool) & np.isfinite(ranges)
    if not valid.any():
        raise DataFormatError(path, None, f"none of its {scans} scans has a return: every reading is at or beyond "
                                          f"the range limit ({float(log.max_range):g} m), inf or NaN")
    odom = np.asarray(log.odom_poses, np.float64)
    if not np.isfinite(odom).all():
        index = int(np.flatnonzero(~np.isfinite(odom).all(axis=1))[0])
        line, text = _where(log, index)
        raise DataFormatError(path, line, f"the odometry pose of {text} is not finite")
    steps = se2_between(odom[:-1], odom[1:])
    lengths = np.hypot(steps[:, 0], steps[:, 1])
    longest = int(np.argmax(lengths))
    if lengths[longest] > max_odometry_step:
        line, text = _where(log, longest + 1)
        raise DataFormatError(
            path, line, f"the odometry jumps {lengths[longest]:.3g} m between two scans at {text}, more than the "
                        f"{max_odometry_step:g} m a robot can move between two scans (--max-odometry-step); "
                        "a fault of the odometry, not motion")
    times = np.asarray(log.scan_times, np.float64)
    gaps = np.diff(times)
    span = float(times[-1] - times[0])
    advance = bool(span > 0)
    if temporal and not advance:
        raise DataFormatError(path, None, f"its scan stamps do not advance ({scans} scans over {span:g} s), and the "
                                          "temporal keyframe rule (--temporal-update) counts seconds")
    return {
        "scans": scans,
        "stamp_steps_repeated": int(np.sum(gaps == 0)),
        "stamp_steps_backward": int(np.sum(gaps < 0)),
        "stamp_span_s": span,
        "stamps_advance": advance,
        "max_odometry_step_m": float(lengths[longest]),
        "odometry_step_bound_m": float(max_odometry_step),
    }
