"""CARMEN laser logs (plain or gzipped) as fixed-shape NumPy arrays.

A CARMEN log is line-oriented text; every message ends with
``ipc_timestamp ipc_hostname logger_timestamp``. This reader understands:

* ``FLASER n r_1 .. r_n x y theta odom_x odom_y odom_theta ipc_ts host logger_ts``:
  ``(x, y, theta)`` is the laser pose, ``odom_*`` the robot odometry pose.
* ``ROBOTLASER1 type start fov res max_range accuracy remission_mode n r_1 .. r_n
  m e_1 .. e_m laser_x laser_y laser_theta robot_x robot_y robot_theta tv rv
  forward_safety side_safety turn_axis ipc_ts host logger_ts``.
* ``ODOM x y theta tv rv accel ipc_ts host logger_ts``: the dense odometry stream.
* ``PARAM name value .. [ipc_ts] host logger_ts``: the laser mounting
  (``robot_frontlaser_offset``, ``robot_frontlaser_side_offset``,
  ``robot_frontlaser_angular_offset``), the beam geometry
  (``laser_front_laser_resolution`` in degrees, ``laser_front_laser_fov``,
  ``laser_front_laser_flipped``) and the range limit (``robot_front_laser_max``, which
  is also what GMapping's CARMEN wrapper uses as ``maxrange``).

Every other message type (``NEFF``, ``TRUEPOS``, ``RAWLASER1`` ...) is counted in
``stats`` and skipped.

Geometry. FLASER lines carry no angles: the beams start at -pi/2 (right) and step by
``laser_front_laser_resolution`` if logged, else by CARMEN's guess from the beam count
(1 deg for 180/181 beams, 0.5 deg for 360/361, 0.25 deg for 720/721, else
``pi / (n - 1)`` for odd and ``pi / n`` for even ``n``). ROBOTLASER1 lines carry
their own start angle and resolution. The laser sits at ``laser_offset`` in the
robot frame, so ``laser_pose = odom_pose (+) laser_offset`` (SE(2) composition).

Range policy (``valid`` and ``max_range_mask`` never overlap):

* NaN, +-inf and ``r <= 0``: invalid, counted in ``stats``.
* ``r >= max_range``: "no return". Not a hit, so ``valid`` is False, but the beam
  saw free space out to ``max_range``: ``max_range_mask`` marks these for callers
  that clear free space along max-range beams (GMapping's ``maxUrange`` logic).
* A "no return" sentinel, a pile of readings just above the laser's real range
  with no PARAM saying so (MIT Killian: about 40,000 readings at 51.05-51.22 m; Orebro:
  32.76 m), is found by :func:`~jaxslam.datasets.no_return.detect_no_return` when ``max_range`` is not given;
  ``max_range`` then becomes the pile's start, so its readings are "no return" too.
* otherwise: a hit, ``valid`` is True.

Error policy. Malformed lines (a beam count that does not match the number of
fields, non-numeric or non-finite numbers where numbers belong, truncated lines),
scan timestamps that go back by more than ``max_backstep`` seconds, logs with no
scans and truncated or corrupt gzip streams raise :class:`~jaxslam.datasets.paths.DataFormatError` naming the
file, the line and the problem. With ``on_error="skip"`` a bad line is dropped instead
and counted in ``stats`` (``"skipped_lines"`` and ``"skipped:<reason>"``), and its
message is kept in ``problems``. Backward steps shorter than ``max_backstep`` are
kept (the Intel log has 631 of them, up to 0.9 s, in the original) and counted in
``stats["backwards_timestamps"]``. A change of beam geometry (beam count, start
angle, resolution, range limit) within one log is an error unless
``mixed_geometry="pad"``.

Layout: the per-line parsers are in :mod:`jaxslam.datasets.carmen_parse`, the bulk and
line-by-line readers in :mod:`jaxslam.datasets.carmen_read`; :func:`~jaxslam.datasets.no_return.detect_no_return`
(:mod:`jaxslam.datasets.no_return`) and :func:`~jaxslam.datasets.keyframes.select_keyframes`
(:mod:`jaxslam.datasets.keyframes`) are re-exported here.

One module of about 400 lines: the format's description, the :class:`CarmenLog` type
every laser loader returns and its one loader; the parsing and reading are in
:mod:`jaxslam.datasets.carmen_parse` and :mod:`jaxslam.datasets.carmen_read`.
"""

from __future__ import annotations

import dataclasses
import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from jaxslam.datasets.carmen_parse import Collector, guess_angular_resolution, param_float
from jaxslam.datasets.carmen_read import read_lines_fast, read_lines_slow
from jaxslam.datasets.geometry import se2_between, wrap_angle
from jaxslam.datasets.keyframes import select_keyframes
from jaxslam.datasets.no_return import detect_no_return
from jaxslam.datasets.odometry_repair import repair_reverse_odometry, repair_stale_odometry
from jaxslam.datasets.paths import DataFormatError
from jaxslam.datasets.reader import read_bytes

__all__ = [
    "CarmenLog",
    "DEFAULT_FLASER_MAX_RANGE",
    "detect_no_return",
    "guess_angular_resolution",
    "PER_SCAN_FIELDS",
    "load_carmen",
    "scan_range",
    "select_keyframes",
]

DEFAULT_FLASER_MAX_RANGE = 80.0
"""Range limit of FLASER logs with no ``robot_front_laser_max`` PARAM (m).

The nominal range of the SICK LMS 2xx that recorded the Freiburg/Radish logs; its
"no return" codes (81.83, 81.87, 81.89, 81.91 m) all lie above it.
"""

_OFFSET_TOL = 1e-3  # m and rad: laser pose vs odom (+) offset


@dataclasses.dataclass(frozen=True, eq=False)
class CarmenLog:
    """One CARMEN log, scans in file order. ``S`` scans of ``B`` beams, ``N`` ODOMs.

    Attributes:
        path: the file read.
        message: the scan message used, ``"FLASER"`` or ``"ROBOTLASER1"``.
        scan_times: (S,) float64 ``ipc_timestamp`` of each scan, as logged (the clock
            of the benchmark ``.relations`` files); not sorted if the log is not.
        logger_times: (S,) float64 ``logger_timestamp`` of each scan.
        scan_lines: (S,) int64 1-based line number of each scan in the file.
        ranges: (S, B) float32 ranges in m as logged; beams a scan does not have
            (``mixed_geometry="pad"``) hold NaN. Mask with ``valid`` before use.
        valid: (S, B) bool, usable hits: finite, ``0 < r < max_range``.
        max_range_mask: (S, B) bool, finite ``r >= max_range`` ("no return"); these
            may clear free space up to ``max_range`` but are never hits.
        angles: (B,) float32 beam angles in the laser frame (rad, counter-clockwise,
            0 = laser forward). Beam ``b`` of scan ``s`` points at
            ``angles[b] + angle_offsets[s]``.
        angle_offsets: (S,) float32 per-scan shift of ``angles``; zero unless the
            log interleaves start angles (``mixed_geometry="pad"``).
        angular_resolution: angle between neighbouring beams (rad).
        max_range: range limit in m (the smallest one if padded scans differ); see
            :func:`load_carmen` for its source.
        laser_offset: (3,) float64 ``(x, y, theta)`` of the laser in the robot frame.
        odom_poses: (S, 3) float64 robot odometry pose at each scan; repaired where
            the log's poses lose the sign of reversing, and spread over their time
            where they are stale (``odometry_repair``).
        laser_poses: (S, 3) float64 laser pose logged with each scan (as logged, not
            repaired), or None.
        odom_times: (N,) float64 ``ipc_timestamp`` of the ODOM messages.
        odom_readings: (N, 3) float64 ODOM poses ``(x, y, theta)``, as logged.
        params: PARAM name -> value text (the last one logged wins).
        stats: counted oddities, e.g. ``max_range_readings``, ``nonfinite_readings``,
            ``nonpositive_readings``, ``padded_beams``, ``unknown_messages``,
            ``unknown:<TYPE>``, ``skipped_lines``, ``skipped:<reason>``,
            ``backwards_timestamps``, ``odom_backwards_timestamps``,
            ``other_scan_messages``, ``laser_offset_mismatch_scans``.
        problems: messages of the lines skipped under ``on_error="skip"`` (the first
            100).
        no_return: what the "no return" sentinel detection decided
            (:func:`~jaxslam.datasets.no_return.detect_no_return`'s result and ``source``); when a pile was found,
            ``max_range`` is its start and ``stats["no_return_sentinel_readings"]``
            counts the readings it turned from hits into "no return".
        odom_speeds: (N,) float64 logged translational velocity ``tv`` of the ODOM
            messages, or None.
        odometry_repair: what the reversing check decided
            (:func:`jaxslam.datasets.odometry_repair.repair_reverse_odometry`); under
            ``"stale"`` the stale stretches found and repaired
            (:func:`jaxslam.datasets.odometry_repair.repair_stale_odometry`).
    """

    path: Path
    message: str
    scan_times: np.ndarray
    logger_times: np.ndarray
    scan_lines: np.ndarray
    ranges: np.ndarray
    valid: np.ndarray
    max_range_mask: np.ndarray
    angles: np.ndarray
    angle_offsets: np.ndarray
    angular_resolution: float
    max_range: float
    laser_offset: np.ndarray
    odom_poses: np.ndarray
    laser_poses: np.ndarray | None
    odom_times: np.ndarray
    odom_readings: np.ndarray
    params: dict[str, str]
    stats: dict[str, int]
    problems: tuple[str, ...] = ()
    no_return: dict[str, Any] = dataclasses.field(default_factory=dict)
    odom_speeds: np.ndarray | None = None
    odometry_repair: dict[str, Any] = dataclasses.field(default_factory=dict)

    @property
    def num_scans(self) -> int:
        """``S``, the number of scans."""
        return int(self.ranges.shape[0])

    @property
    def num_beams(self) -> int:
        """``B``, the number of beams per scan."""
        return int(self.ranges.shape[1])

    def beam_angles(self) -> np.ndarray:
        """(S, B) float32 angle of every beam of every scan in the laser frame."""
        return self.angles[None, :] + self.angle_offsets[:, None]

PER_SCAN_FIELDS = ("scan_times", "logger_times", "scan_lines", "ranges", "valid", "max_range_mask", "angle_offsets",
                   "odom_poses", "laser_poses", "true_poses")
"""The arrays of a laser log with one row per scan (``true_poses``: the simulator's);
the others are the log's (beam angles, laser mount) or its ODOM messages'."""


def scan_range(log: Any, start: int = 0, stop: int | None = None) -> Any:
    """The log's scans ``start:stop``: every per-scan array (:data:`PER_SCAN_FIELDS`)
    cut, the per-log arrays and the ODOM messages kept as they are."""
    cut = {f: getattr(log, f)[start:stop] for f in PER_SCAN_FIELDS if getattr(log, f, None) is not None}
    return dataclasses.replace(log, **cut)


def load_carmen(
    path: os.PathLike | str,
    *,
    on_error: str = "raise",
    max_range: float | None = None,
    laser_offset: tuple[float, float, float] | np.ndarray | None = None,
    mixed_geometry: str = "raise",
    max_backstep: float = 1.0,
    message: str | None = None,
    detect_sentinel: bool = True,
    repair_odometry: bool = True,
) -> CarmenLog:
    """Read a CARMEN log (plain or gzipped) into a :class:`CarmenLog`.

    Args:
        path: the log file; gzip is detected from its first bytes.
        on_error: ``"raise"`` (default) raises :class:`~jaxslam.datasets.paths.DataFormatError` on the first
            bad line; ``"skip"`` drops bad lines and counts them in ``stats``.
        max_range: range limit in m. Default: the ROBOTLASER1 line's own field, else
            PARAM ``robot_front_laser_max``, else :data:`DEFAULT_FLASER_MAX_RANGE`;
            lowered to the start of a "no return" sentinel pile if one is found
            below it (:func:`~jaxslam.datasets.no_return.detect_no_return`). An explicit value is used as is.
        laser_offset: ``(x, y, theta)`` of the laser in the robot frame. Default: for
            FLASER logs the ``robot_frontlaser_*offset`` PARAMs if logged; otherwise
            the median of ``odom_pose^-1 (+) laser_pose`` over the scans. Scans whose
            poses disagree with it by more than 1 mm / 1 mrad are counted in
            ``stats["laser_offset_mismatch_scans"]``.
        mixed_geometry: ``"raise"`` (default) if the beam geometry changes between
            scans; ``"pad"`` pads short scans with NaN (``valid`` False) to the
            longest and puts interleaved start angles in ``angle_offsets``.
        max_backstep: scan timestamps may go back by up to this many seconds
            (counted in ``stats["backwards_timestamps"]``); a larger step is a bad line.
        message: ``"FLASER"`` or ``"ROBOTLASER1"``; default: the first scan type in
            the file. Lines of the other type are counted in
            ``stats["other_scan_messages"]``.
        detect_sentinel: look for a "no return" sentinel pile when ``max_range`` is
            not given (see :func:`~jaxslam.datasets.no_return.detect_no_return`; the decision is in ``no_return``).
        repair_odometry: check the odometry poses against the logged velocities and
            repair increments that lose the sign of reversing, and spread stale
            stretches (a pose repeated while readings did not arrive, then the whole
            motion in one scan) over their time (:mod:`jaxslam.datasets.odometry_repair`;
            the decisions are in ``odometry_repair``, the counts in
            ``stats["odometry_sign_repaired"]`` and ``stats["odometry_stale_repaired"]``).

    Returns:
        The log's scans, poses, masks and counters.

    Raises:
        DataFormatError: malformed input, as described in the module docstring.
        FileNotFoundError: ``path`` does not exist.
    """
    if on_error not in ("raise", "skip"):
        raise ValueError(f"on_error must be 'raise' or 'skip', got {on_error!r}")
    if mixed_geometry not in ("raise", "pad"):
        raise ValueError(f"mixed_geometry must be 'raise' or 'pad', got {mixed_geometry!r}")
    if message not in (None, "FLASER", "ROBOTLASER1"):
        raise ValueError(f"message must be 'FLASER' or 'ROBOTLASER1', got {message!r}")
    path = Path(path)
    text = read_bytes(path, "CARMEN log")
    collector = Collector(path, on_error)
    scan_type = None if message is None else message.encode()

    lines = read_lines_fast(text, scan_type, max_backstep)
    if lines is None:
        lines = read_lines_slow(text, path, collector, scan_type, max_backstep, mixed_geometry)
    else:
        for key, amount in lines.stats.items():
            collector.count(key, amount)
    scan_type, params, geometries = lines.scan_type, lines.params, lines.geometries
    used = scan_type.decode()
    num_scans = lines.ranges.shape[0]
    counts = np.array([g[0] for g in geometries])
    num_beams = int(counts.max())

    # Beam geometry.
    if used == "FLASER":
        flipped = params.get("laser_front_laser_flipped", ("0", 0))[0].strip().lower()
        resolution_deg = param_float(params, "laser_front_laser_resolution", collector)
        fov = param_float(params, "laser_front_laser_fov", collector)
        if fov is not None and fov > 2.0 * math.pi + 1e-6:
            fov = math.radians(fov)  # logged in degrees
        guessed = {guess_angular_resolution(int(n)) for n in np.unique(counts)}
        if resolution_deg is not None and resolution_deg > 0:
            resolution = math.radians(resolution_deg)
        elif len(guessed) == 1:
            resolution = guessed.pop()
        else:
            raise DataFormatError(
                path, None, f"FLASER beam counts {sorted(set(counts.tolist()))} imply "
                "different angular resolutions; cannot pad them to one beam grid"
            )
        start = -0.5 * fov if fov is not None else -0.5 * math.pi
        angles = start + resolution * np.arange(num_beams)
        if flipped in ("1", "on", "yes", "true"):
            angles = -angles
        angle_offsets = np.zeros(num_scans)
        scan_max_range = np.full(num_scans, np.nan)
    else:
        starts = np.array([g[1] for g in geometries])
        resolutions = np.array([g[2] for g in geometries])
        if np.ptp(resolutions) > 1e-6:
            raise DataFormatError(
                path, None, f"ROBOTLASER1 angular resolution varies ({resolutions.min():.6g} .. "
                f"{resolutions.max():.6g} rad); cannot pad scans to one beam grid"
            )
        resolution = float(resolutions[0])
        start = float(starts.min())
        angles = start + resolution * np.arange(num_beams)
        angle_offsets = starts - start
        scan_max_range = np.array([g[3] for g in geometries])

    if max_range is not None:
        scan_max_range = np.full(num_scans, float(max_range))
    elif used == "FLASER":
        logged = param_float(params, "robot_front_laser_max", collector)
        limit = logged if logged is not None and logged > 0 else DEFAULT_FLASER_MAX_RANGE
        scan_max_range = np.full(num_scans, limit)

    # A "no return" sentinel below the limit (see detect_no_return).
    ranges = lines.ranges
    if max_range is not None:
        no_return: dict[str, Any] = {"detected": False, "source": "max_range argument"}
    elif not detect_sentinel:
        no_return = {"detected": False, "source": "detection off"}
    else:
        no_return = {**detect_no_return(ranges, scan_max_range), "source": "detected"}
        if no_return["detected"]:
            with np.errstate(invalid="ignore"):
                newly = np.isfinite(ranges) & (ranges >= no_return["range_m"]) & (ranges < scan_max_range[:, None])
            no_return["readings"] = int(newly.sum())
            collector.count("no_return_sentinel_readings", int(newly.sum()))
            scan_max_range = np.minimum(scan_max_range, no_return["range_m"])

    # Ranges and masks.
    present = np.arange(num_beams)[None, :] < counts[:, None]
    with np.errstate(invalid="ignore"):
        finite = np.isfinite(ranges)
        positive = ranges > 0.0
        at_max = ranges >= scan_max_range[:, None]
    valid = present & finite & positive & ~at_max
    max_range_mask = present & finite & at_max
    collector.count("max_range_readings", int(max_range_mask.sum()))
    collector.count("nonfinite_readings", int((present & ~finite).sum()))
    collector.count("nonpositive_readings", int((present & finite & ~positive).sum()))
    collector.count("padded_beams", int((~present).sum()))

    # Poses and the laser mounting.
    odom_poses = lines.robot
    laser_poses = lines.laser
    with np.errstate(all="ignore"):
        relative = se2_between(odom_poses, laser_poses)
    if laser_offset is not None:
        offset = np.asarray(laser_offset, dtype=np.float64).reshape(3)
    else:
        logged_offset = [
            param_float(params, f"robot_frontlaser_{name}", collector)
            for name in ("offset", "side_offset", "angular_offset")
        ]
        if used == "FLASER" and any(value is not None for value in logged_offset):
            offset = np.array([value or 0.0 for value in logged_offset])
        else:
            with np.errstate(all="ignore"):
                offset = np.median(relative, axis=0)
                offset[2] = math.atan2(
                    np.median(np.sin(relative[:, 2])), np.median(np.cos(relative[:, 2]))
                )
    with np.errstate(all="ignore"):
        mismatch = np.abs(relative[:, :2] - offset[:2]).max(axis=1) > _OFFSET_TOL
        mismatch |= np.abs(wrap_angle(relative[:, 2] - offset[2])) > _OFFSET_TOL
    collector.count("laser_offset_mismatch_scans", int(mismatch.sum()))
    # After the laser offset, which compares the logged poses with each other.
    if repair_odometry:
        odom_poses, repair = repair_reverse_odometry(odom_poses, lines.ipc, lines.odom_times, lines.odom_speeds)
        if repair["repaired"]:
            collector.count("odometry_sign_repaired", repair["sign_lost"])
        odom_poses, stale = repair_stale_odometry(odom_poses, lines.ipc)
        repair = {**repair, "stale": stale}
        if stale["repaired"]:
            collector.count("odometry_stale_repaired", stale["repaired_scans"])
    else:
        repair = {"checked": False, "reason": "repair off", "repaired": False}

    maxima = np.unique(scan_max_range)
    with np.errstate(over="ignore"):
        ranges_f32 = ranges.astype(np.float32)
    log = CarmenLog(
        path=path,
        message=used,
        scan_times=lines.ipc,
        logger_times=lines.logger,
        scan_lines=lines.lines,
        ranges=ranges_f32,
        valid=valid,
        max_range_mask=max_range_mask,
        angles=angles.astype(np.float32),
        angle_offsets=angle_offsets.astype(np.float32),
        angular_resolution=float(resolution),
        max_range=float(maxima.min()),
        laser_offset=offset,
        odom_poses=odom_poses,
        laser_poses=laser_poses,
        odom_times=lines.odom_times,
        odom_readings=lines.odom,
        params={name: value for name, (value, _) in params.items()},
        stats=dict(sorted(collector.stats.items())),
        problems=tuple(collector.problems),
        no_return=no_return,
        odom_speeds=lines.odom_speeds,
        odometry_repair=repair,
    )
    for field in dataclasses.fields(log):
        value = getattr(log, field.name)
        if isinstance(value, np.ndarray):
            value.setflags(write=False)
    return log

