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
  32.76 m), is found by :func:`detect_no_return` when ``max_range`` is not given;
  ``max_range`` then becomes the pile's start, so its readings are "no return" too.
* otherwise: a hit, ``valid`` is True.

Error policy. Malformed lines (a beam count that does not match the number of
fields, non-numeric or non-finite numbers where numbers belong, truncated lines),
scan timestamps that go back by more than ``max_backstep`` seconds, logs with no
scans and truncated or corrupt gzip streams raise :class:`DataFormatError` naming the
file, the line and the problem. With ``on_error="skip"`` a bad line is dropped instead
and counted in ``stats`` (``"skipped_lines"`` and ``"skipped:<reason>"``), and its
message is kept in ``problems``. Backward steps shorter than ``max_backstep`` are
kept (the Intel log has 631 of them, up to 0.9 s, in the original) and counted in
``stats["backwards_timestamps"]``. A change of beam geometry (beam count, start
angle, resolution, range limit) within one log is an error unless
``mixed_geometry="pad"``.
"""

from __future__ import annotations

import dataclasses
import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from jaxslam.datasets.geometry import se2_between, wrap_angle
from jaxslam.datasets.paths import DataFormatError
from jaxslam.datasets.reader import read_bytes

__all__ = [
    "CarmenLog",
    "DEFAULT_FLASER_MAX_RANGE",
    "detect_no_return",
    "guess_angular_resolution",
    "load_carmen",
    "load_dataset_log",
    "select_keyframes",
]

DEFAULT_FLASER_MAX_RANGE = 80.0
"""Range limit of FLASER logs with no ``robot_front_laser_max`` PARAM (m).

The nominal range of the SICK LMS 2xx that recorded the Freiburg/Radish logs; its
"no return" codes (81.83, 81.87, 81.89, 81.91 m) all lie above it.
"""

_FLASER_TAIL = 9  # x y theta odom_x odom_y odom_theta ipc_ts host logger_ts
_ROBOTLASER1_TAIL = 14  # 6 poses, tv rv fwd side turn, ipc_ts host logger_ts
_ODOM_FIELDS = 10
_MAX_PROBLEMS = 100
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
        odom_poses: (S, 3) float64 robot odometry pose at each scan.
        laser_poses: (S, 3) float64 laser pose logged with each scan, or None.
        odom_times: (N,) float64 ``ipc_timestamp`` of the ODOM messages.
        odom_readings: (N, 3) float64 ODOM poses ``(x, y, theta)``.
        params: PARAM name -> value text (the last one logged wins).
        stats: counted oddities, e.g. ``max_range_readings``, ``nonfinite_readings``,
            ``nonpositive_readings``, ``padded_beams``, ``unknown_messages``,
            ``unknown:<TYPE>``, ``skipped_lines``, ``skipped:<reason>``,
            ``backwards_timestamps``, ``odom_backwards_timestamps``,
            ``other_scan_messages``, ``laser_offset_mismatch_scans``.
        problems: messages of the lines skipped under ``on_error="skip"`` (the first
            100).
        no_return: what the "no return" sentinel detection decided
            (:func:`detect_no_return`'s result and ``source``); when a pile was found,
            ``max_range`` is its start and ``stats["no_return_sentinel_readings"]``
            counts the readings it turned from hits into "no return".
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


class _LineError(Exception):
    """A problem with one line; becomes a DataFormatError or a skipped line."""

    def __init__(self, reason: str, problem: str):
        super().__init__(problem)
        self.reason = reason
        self.problem = problem


def guess_angular_resolution(num_beams: int) -> float:
    """CARMEN's angular resolution for a FLASER scan of ``num_beams`` beams (rad)."""
    known = {180: 1.0, 181: 1.0, 360: 0.5, 361: 0.5, 720: 0.25, 721: 0.25}
    if num_beams in known:
        return math.radians(known[num_beams])
    if num_beams % 2:
        return math.pi / max(num_beams - 1, 1)
    return math.pi / num_beams


def _float(token: bytes, what: str) -> float:
    try:
        value = float(token)
    except ValueError:
        raise _LineError("non_numeric", f"{what} is not a number: {token[:40]!r}") from None
    if not math.isfinite(value):
        raise _LineError("non_finite", f"{what} is not finite: {token[:40]!r}")
    return value


def _count(token: bytes, what: str) -> int:
    try:
        value = int(token)
    except ValueError:
        raise _LineError("non_numeric", f"{what} is not an integer: {token[:40]!r}") from None
    if value < 1:
        raise _LineError("bad_beam_count", f"{what} must be positive, got {value}")
    return value


def _numbers(tokens: list[bytes], what: str) -> np.ndarray:
    """Tokens as float64; NaN and inf pass (the caller decides about them)."""
    try:
        return np.array(tokens, dtype=np.float64)
    except ValueError:
        for token in tokens:
            try:
                float(token)
            except ValueError:
                raise _LineError(
                    "non_numeric", f"{what} is not a number: {token[:40]!r}"
                ) from None
        raise _LineError("non_numeric", f"{what} holds a non-number") from None


def _finite(values: np.ndarray, what: str) -> np.ndarray:
    if not np.all(np.isfinite(values)):
        raise _LineError("non_finite", f"{what} is not finite (NaN or inf)")
    return values


def _stamps(parts: list[bytes]) -> tuple[float, float]:
    return _float(parts[-3], "ipc_timestamp"), _float(parts[-1], "logger_timestamp")


def _parse_flaser(parts: list[bytes]) -> dict[str, Any]:
    if len(parts) < 2:
        raise _LineError("truncated", "FLASER line ends before its beam count")
    n = _count(parts[1], "FLASER beam count")
    expected = 2 + n + _FLASER_TAIL
    if len(parts) != expected:
        raise _LineError(
            "field_count",
            f"FLASER says {n} beams, so the line needs {expected} fields, "
            f"but it has {len(parts)} (truncated or corrupt line?)",
        )
    ranges = _numbers(parts[2 : 2 + n], "a FLASER range")
    poses = _finite(_numbers(parts[2 + n : 8 + n], "a FLASER pose"), "a FLASER pose")
    ipc, logger = _stamps(parts)
    return {
        "ranges": ranges,
        "geometry": (n,),
        "laser": poses[:3],
        "robot": poses[3:],
        "ipc": ipc,
        "logger": logger,
    }


def _parse_robotlaser1(parts: list[bytes]) -> dict[str, Any]:
    if len(parts) < 10:
        raise _LineError("truncated", "ROBOTLASER1 line ends before its ranges")
    header = _finite(_numbers(parts[2:8], "a ROBOTLASER1 header field"), "ROBOTLASER1 header")
    start, fov, resolution, max_range = header[0], header[1], header[2], header[3]
    if not resolution > 0.0:
        raise _LineError("bad_geometry", f"ROBOTLASER1 angular resolution {resolution} <= 0")
    if not max_range > 0.0:
        raise _LineError("bad_geometry", f"ROBOTLASER1 max range {max_range} <= 0")
    n = _count(parts[8], "ROBOTLASER1 beam count")
    if len(parts) < 10 + n:
        raise _LineError(
            "field_count",
            f"ROBOTLASER1 says {n} beams but the line has only {len(parts)} fields",
        )
    m_token = parts[9 + n]
    try:
        m = int(m_token)
    except ValueError:
        raise _LineError(
            "non_numeric", f"ROBOTLASER1 remission count is not an integer: {m_token[:40]!r}"
        ) from None
    if m < 0:
        raise _LineError("field_count", f"ROBOTLASER1 remission count {m} < 0")
    expected = 10 + n + m + _ROBOTLASER1_TAIL
    if len(parts) != expected:
        raise _LineError(
            "field_count",
            f"ROBOTLASER1 says {n} beams and {m} remissions, so the line needs "
            f"{expected} fields, but it has {len(parts)} (truncated or corrupt line?)",
        )
    if n > 1 and abs(fov / (n - 1) - resolution) < 1e-5:
        resolution = fov / (n - 1)  # the logged resolution is rounded to 6 decimals
    ranges = _numbers(parts[9 : 9 + n], "a ROBOTLASER1 range")
    if m:
        _numbers(parts[10 + n : 10 + n + m], "a ROBOTLASER1 remission")
    base = 10 + n + m
    poses = _finite(_numbers(parts[base : base + 6], "a ROBOTLASER1 pose"), "a ROBOTLASER1 pose")
    _numbers(parts[base + 6 : base + 11], "a ROBOTLASER1 velocity/safety field")
    ipc, logger = _stamps(parts)
    return {
        "ranges": ranges,
        "geometry": (n, float(start), float(resolution), float(max_range)),
        "laser": poses[:3],
        "robot": poses[3:],
        "ipc": ipc,
        "logger": logger,
    }


def _parse_odom(parts: list[bytes]) -> tuple[np.ndarray, float]:
    if len(parts) != _ODOM_FIELDS:
        raise _LineError(
            "field_count", f"ODOM needs {_ODOM_FIELDS} fields, but the line has {len(parts)}"
        )
    pose = _finite(_numbers(parts[1:4], "an ODOM pose"), "an ODOM pose")
    _numbers(parts[4:7], "an ODOM velocity")
    ipc, _ = _stamps(parts)
    return pose, ipc


def _parse_param(parts: list[bytes]) -> tuple[str, str]:
    if len(parts) < 3:
        raise _LineError("truncated", "PARAM line needs at least a name and a value")
    if len(parts) >= 6:
        value = parts[2:-3]
    elif len(parts) == 5:  # GMapping writes "PARAM name value host logger_ts"
        value = parts[2:-2]
    else:
        value = parts[2:]
    return _text(parts[1]), " ".join(_text(token) for token in value)


def _text(token: bytes) -> str:
    return token.decode("utf-8", "replace")


class _Collector:
    """Routes line problems to an exception or to the skip counters."""

    def __init__(self, path: Path, on_error: str):
        self.path = path
        self.on_error = on_error
        self.stats: dict[str, int] = {}
        self.problems: list[str] = []

    def count(self, key: str, amount: int = 1) -> None:
        self.stats[key] = self.stats.get(key, 0) + amount

    def bad_line(self, line: int | None, error: _LineError) -> None:
        if self.on_error == "raise":
            raise DataFormatError(self.path, line, error.problem)
        self.count("skipped_lines")
        self.count(f"skipped:{error.reason}")
        if len(self.problems) < _MAX_PROBLEMS:
            self.problems.append(str(DataFormatError(self.path, line, error.problem)))


def _param_float(
    params: dict[str, tuple[str, int]], name: str, collector: _Collector
) -> float | None:
    if name not in params:
        return None
    text, line = params[name]
    try:
        value = float(text)
        if not math.isfinite(value):
            raise ValueError
        return value
    except ValueError:
        collector.bad_line(
            line, _LineError("bad_param", f"PARAM {name} is not a finite number: {text[:40]!r}")
        )
        return None


@dataclasses.dataclass
class _Lines:
    """What the line readers collect: scans in file order (``ranges`` NaN-padded to
    the longest scan), ODOM readings and PARAMs (name -> (value text, line))."""

    scan_type: bytes
    ranges: np.ndarray
    geometries: list[tuple]
    laser: np.ndarray
    robot: np.ndarray
    ipc: np.ndarray
    logger: np.ndarray
    lines: np.ndarray
    odom: np.ndarray
    odom_times: np.ndarray
    params: dict[str, tuple[str, int]]
    stats: dict[str, int] = dataclasses.field(default_factory=dict)


def _number_block(rows: list[bytes], columns: int) -> np.ndarray | None:
    """``rows`` of whitespace-separated numbers as a ``(len(rows), columns)`` float64
    array (NumPy's C text parser), or None if any row is not exactly ``columns``
    numbers."""
    if not rows:
        return np.zeros((0, columns))
    try:
        values = np.loadtxt(
            b"\n".join(rows).decode("latin-1").split("\n"),
            dtype=np.float64, comments=None, ndmin=2,
        )
    except ValueError:
        return None
    if values.shape != (len(rows), columns):
        return None
    return values


def _read_lines_fast(text: bytes, scan_type: bytes | None, max_backstep: float) -> _Lines | None:
    """The common case in bulk: a FLASER log with one beam count and no bad line.

    Lines are sorted by message type with one cheap split each; the numbers of all
    FLASER lines, and of all ODOM lines, are then parsed at once by NumPy (the host
    name, the one text field, is cut out first). Anything this path does not handle
    exactly as :func:`_read_lines_slow` would (ROBOTLASER1 scans, several beam counts,
    any malformed or non-finite field, a timestamp going back more than
    ``max_backstep``) returns None, and the caller reads the file line by line
    instead, so the messages, skips and counts are the reference reader's.
    """
    stats: dict[str, int] = {}
    params: dict[str, tuple[str, int]] = {}
    scan_rows: list[bytes] = []
    scan_lines: list[int] = []
    count_tokens: set[bytes] = set()
    odom_rows: list[bytes] = []
    try:
        for line_number, raw in enumerate(text.split(b"\n"), start=1):
            parts = raw.split(None, 2)
            if not parts:
                continue
            head = parts[0]
            if head.startswith(b"#"):
                continue
            if head in (b"FLASER", b"ROBOTLASER1"):
                if scan_type is None:
                    scan_type = head
                if head != scan_type:
                    stats["other_scan_messages"] = stats.get("other_scan_messages", 0) + 1
                    continue
                if head != b"FLASER":
                    return None
                # count, then ranges + 6 pose numbers + ipc_ts; host; logger_ts
                body, _host, logger = parts[2].rsplit(None, 2)
                count_tokens.add(parts[1])
                scan_rows.append(parts[1] + b" " + body + b" " + logger)
                scan_lines.append(line_number)
            elif head == b"ODOM":
                body, _host, logger = raw.split(None, 1)[1].rsplit(None, 2)
                odom_rows.append(body + b" " + logger)
            elif head == b"PARAM":
                name, value = _parse_param(raw.split())
                params[name] = (value, line_number)
            else:
                stats["unknown_messages"] = stats.get("unknown_messages", 0) + 1
                key = f"unknown:{_text(head[:32])}"
                stats[key] = stats.get(key, 0) + 1
    except (ValueError, IndexError, _LineError):
        return None
    if not scan_rows or len(count_tokens) != 1:
        return None
    token = count_tokens.pop()
    try:
        num_beams = int(token)
    except ValueError:
        return None
    if num_beams < 1:
        return None
    scans = _number_block(scan_rows, num_beams + 9)
    odom = _number_block(odom_rows, 8)
    if scans is None or odom is None:
        return None
    ranges, poses, stamps = scans[:, 1 : 1 + num_beams], scans[:, 1 + num_beams : 7 + num_beams], scans[:, -2:]
    if not (np.isfinite(poses).all() and np.isfinite(stamps).all()):
        return None
    if not (np.isfinite(odom[:, :3]).all() and np.isfinite(odom[:, -2:]).all()):
        return None
    steps = np.diff(stamps[:, 0])
    if np.any(steps < -max_backstep):
        return None
    if np.any(steps < 0):
        stats["backwards_timestamps"] = int(np.sum(steps < 0))
    odom_steps = np.diff(odom[:, -2])
    if np.any(odom_steps < 0):
        stats["odom_backwards_timestamps"] = int(np.sum(odom_steps < 0))
    return _Lines(
        scan_type=scan_type,
        ranges=np.ascontiguousarray(ranges),
        geometries=[(num_beams,)] * scans.shape[0],
        laser=np.ascontiguousarray(poses[:, :3]),
        robot=np.ascontiguousarray(poses[:, 3:]),
        ipc=np.ascontiguousarray(stamps[:, 0]),
        logger=np.ascontiguousarray(stamps[:, 1]),
        lines=np.array(scan_lines, dtype=np.int64),
        odom=np.ascontiguousarray(odom[:, :3]),
        odom_times=np.ascontiguousarray(odom[:, -2]),
        params=params,
        stats=stats,
    )


def _read_lines_slow(
    text: bytes,
    path: Path,
    collector: _Collector,
    scan_type: bytes | None,
    max_backstep: float,
    mixed_geometry: str,
) -> _Lines:
    """Every line in Python, one by one: the reference reader, with every check and
    message of the module docstring (bad lines raise or are skipped via ``collector``)."""
    ranges_list: list[np.ndarray] = []
    geometries: list[tuple] = []
    laser_list: list[np.ndarray] = []
    robot_list: list[np.ndarray] = []
    ipc_list: list[float] = []
    logger_list: list[float] = []
    line_list: list[int] = []
    odom_list: list[np.ndarray] = []
    odom_time_list: list[float] = []
    params: dict[str, tuple[str, int]] = {}
    first_geometry_line = 0

    for line_number, raw in enumerate(text.split(b"\n"), start=1):
        parts = raw.split()
        if not parts:
            continue
        head = parts[0]
        if head.startswith(b"#"):
            continue
        try:
            if head in (b"FLASER", b"ROBOTLASER1"):
                if scan_type is None:
                    scan_type = head
                if head != scan_type:
                    collector.count("other_scan_messages")
                    continue
                parse = _parse_flaser if head == b"FLASER" else _parse_robotlaser1
                record = parse(parts)
                if ipc_list:
                    step = record["ipc"] - ipc_list[-1]
                    if step < -max_backstep:
                        raise _LineError(
                            "backwards_timestamp",
                            f"timestamp {record['ipc']!r} goes back {-step:.6g} s from the "
                            f"previous scan (line {line_list[-1]}); more than "
                            f"max_backstep={max_backstep} s",
                        )
                    if step < 0:
                        collector.count("backwards_timestamps")
                if geometries and record["geometry"] != geometries[0]:
                    if mixed_geometry == "raise":
                        raise DataFormatError(
                            path,
                            line_number,
                            f"scan geometry changes: {_describe(record['geometry'])} here, "
                            f"but {_describe(geometries[0])} on line {first_geometry_line}; "
                            f"pass mixed_geometry='pad' to pad scans to a common length",
                        )
                elif not geometries:
                    first_geometry_line = line_number
                ranges_list.append(record["ranges"])
                geometries.append(record["geometry"])
                laser_list.append(record["laser"])
                robot_list.append(record["robot"])
                ipc_list.append(record["ipc"])
                logger_list.append(record["logger"])
                line_list.append(line_number)
            elif head == b"ODOM":
                pose, stamp = _parse_odom(parts)
                if odom_time_list and stamp < odom_time_list[-1]:
                    collector.count("odom_backwards_timestamps")
                odom_list.append(pose)
                odom_time_list.append(stamp)
            elif head == b"PARAM":
                name, value = _parse_param(parts)
                params[name] = (value, line_number)
            else:
                collector.count("unknown_messages")
                collector.count(f"unknown:{_text(head[:32])}")
        except _LineError as error:
            collector.bad_line(line_number, error)

    if not ranges_list:
        skipped = collector.stats.get("skipped_lines", 0)
        raise DataFormatError(
            path,
            None,
            "no laser scans (FLASER or ROBOTLASER1 lines) in the log"
            + (f"; {skipped} bad lines were skipped" if skipped else ""),
        )
    counts = np.array([g[0] for g in geometries])
    ranges = np.full((len(ranges_list), int(counts.max())), np.nan, dtype=np.float64)
    for index, scan in enumerate(ranges_list):
        ranges[index, : scan.shape[0]] = scan
    return _Lines(
        scan_type=scan_type,
        ranges=ranges,
        geometries=geometries,
        laser=np.array(laser_list, dtype=np.float64).reshape(-1, 3),
        robot=np.array(robot_list, dtype=np.float64).reshape(-1, 3),
        ipc=np.array(ipc_list, dtype=np.float64),
        logger=np.array(logger_list, dtype=np.float64),
        lines=np.array(line_list, dtype=np.int64),
        odom=np.array(odom_list, dtype=np.float64).reshape(-1, 3),
        odom_times=np.array(odom_time_list, dtype=np.float64),
        params=params,
    )


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
) -> CarmenLog:
    """Read a CARMEN log (plain or gzipped) into a :class:`CarmenLog`.

    Args:
        path: the log file; gzip is detected from its first bytes.
        on_error: ``"raise"`` (default) raises :class:`DataFormatError` on the first
            bad line; ``"skip"`` drops bad lines and counts them in ``stats``.
        max_range: range limit in m. Default: the ROBOTLASER1 line's own field, else
            PARAM ``robot_front_laser_max``, else :data:`DEFAULT_FLASER_MAX_RANGE`;
            lowered to the start of a "no return" sentinel pile if one is found
            below it (:func:`detect_no_return`). An explicit value is used as is.
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
            not given (see :func:`detect_no_return`; the decision is in ``no_return``).

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
    collector = _Collector(path, on_error)
    scan_type = None if message is None else message.encode()

    lines = _read_lines_fast(text, scan_type, max_backstep)
    if lines is None:
        lines = _read_lines_slow(text, path, collector, scan_type, max_backstep, mixed_geometry)
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
        resolution_deg = _param_float(params, "laser_front_laser_resolution", collector)
        fov = _param_float(params, "laser_front_laser_fov", collector)
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
        logged = _param_float(params, "robot_front_laser_max", collector)
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
            _param_float(params, f"robot_frontlaser_{name}", collector)
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
    )
    for field in dataclasses.fields(log):
        value = getattr(log, field.name)
        if isinstance(value, np.ndarray):
            value.setflags(write=False)
    return log


NO_RETURN_BAND = 0.25
"""Width of the band at the top of the observed ranges searched for a sentinel pile (m)."""


def detect_no_return(
    ranges: np.ndarray,
    limit: np.ndarray | float,
    *,
    band: float = NO_RETURN_BAND,
    gap: float = 2.0,
    min_share: float = 1e-3,
    min_count: int = 50,
    min_contrast: float = 20.0,
    min_beam_share: float = 0.1,
) -> dict[str, Any]:
    """Find a "no return" sentinel: readings piled up at the top of the observed range.

    Some lasers (and logs converted from other formats) report "no echo" not as their
    range limit or a code above it but as a value just above their real range, with
    no PARAM saying so: MIT Killian's SICK has a 50 m range and logs about 40,000
    readings at 51.05-51.22 m; Orebro's logs about 970 at 32.76-32.77 m. Taken as
    hits they draw walls that do not exist. Such a pile has a shape that real echoes
    do not have, and all of these must hold:

    1. Narrow and on top: the ``band``-wide window (1 cm histogram bins) holding the
       most readings among windows that start in the top 10 % of the observed range
       (readings ``0 < r < limit``), with at most 1 % of its count above it.
    2. A cliff, not a slope: its density (readings per m) is at least
       ``min_contrast`` times the density in the ``gap`` metres just below it. Walls
       seen from a moving robot spread over many ranges (a flat wall at distance
       ``d`` gives ``d / cos(angle)``, densest at ``d``, thinning out upwards), so
       real data falls off gently towards its top.
    3. Frequent: at least ``min_count`` readings and ``min_share`` of all readings.
    4. On many beams: at least ``min_beam_share`` of the beam indices have a reading
       in it. One wall at a fixed distance (a robot driving along a corridor, its
       side beam at a constant range) fills one or a few beams, a sentinel every
       beam that looks into open space somewhere along the path.

    On the shipped logs the sentinels score contrast 110-5000, share 0.7-8 % and beam
    share 0.59-1.0, and every other log's top window contrast < 35 with fewer than
    200 readings; the thresholds sit in between. The pile starts at the lowest 1 cm
    bin reached from its fullest bin going down over bins with at least 0.1 % of the
    fullest bin's count (and two readings), across holes of at most 5 cm, so the
    pile's stray codes are not left as hits and real echoes further below are.

    Args:
        ranges: (S, B) ranges (NaN for missing beams).
        limit: the range limit in use, scalar or (S,) per scan; readings at or above
            it are already "no return" and not looked at.
        band, gap, min_share, min_count, min_contrast, min_beam_share: the criteria
            above.

    Returns:
        ``{"detected": bool, "range_m": start of the pile or None, "readings": n,
        "share", "contrast", "beam_share", "window_m": [lo, hi]}`` (the statistics of
        the best window, also when it is not a sentinel).
    """
    ranges = np.asarray(ranges, dtype=np.float64)
    limit = np.broadcast_to(np.asarray(limit, dtype=np.float64).reshape(-1, 1), (ranges.shape[0], 1))
    with np.errstate(invalid="ignore"):
        usable = np.isfinite(ranges) & (ranges > 0.0) & (ranges < limit)
    values = ranges[usable]
    result: dict[str, Any] = {"detected": False, "range_m": None, "readings": 0, "share": 0.0,
                              "contrast": 0.0, "beam_share": 0.0, "window_m": None}
    if values.size < min_count:
        return result
    step = 0.01
    width = max(int(round(band / step)), 1)
    top = float(values.max())
    counts = np.bincount(np.floor(values / step).astype(np.int64))
    windows = np.convolve(counts, np.ones(width, dtype=np.int64), mode="valid")
    first = min(int(0.9 * top / step), windows.size - 1)
    start = first + int(np.argmax(windows[first:]))
    pile_count = int(windows[start])
    low, high = start * step, (start + width) * step
    above = int(counts[start + width :].sum())
    below = int(counts[max(start - int(round(gap / step)), 0) : start].sum())
    contrast = (pile_count / band) / max(below / gap, 1.0 / gap)
    bins = np.floor(ranges / step)
    with np.errstate(invalid="ignore"):
        in_window = usable & (bins >= start) & (bins < start + width)
    beam_share = float(np.mean(in_window.any(axis=0)))
    result.update(readings=pile_count, share=pile_count / values.size, contrast=float(contrast),
                  beam_share=beam_share, window_m=[round(low, 2), round(high, 2)])
    if (
        pile_count >= max(min_count, min_share * values.size)
        and above <= 0.01 * pile_count
        and contrast >= min_contrast
        and beam_share >= min_beam_share
    ):
        window = counts[start : start + width]
        floor = max(2, 0.001 * window.max())
        edge, hole = int(np.argmax(window)), 0
        for index in range(edge - 1, -1, -1):  # down from the fullest bin over holes <= 5 cm
            if window[index] >= floor:
                edge, hole = index, 0
            else:
                hole += 1
                if hole > 5:
                    break
        result.update(detected=True, range_m=round((start + edge) * step, 2))
    return result


def _describe(geometry: tuple) -> str:
    if len(geometry) == 1:
        return f"{geometry[0]} beams"
    n, start, resolution, max_range = geometry
    return (
        f"{n} beams from {start:.6g} rad every {resolution:.6g} rad, max range {max_range:.6g} m"
    )


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


def load_dataset_log(name: os.PathLike | str, **options: Any) -> CarmenLog:
    """Load a registered CARMEN log by name, or any CARMEN log by path.

    Names are those of :mod:`jaxslam.datasets.registry` with a CARMEN loader:
    ``intel``, ``fr079``, ``mit-csail``, ``fr-clinic``, ``mit-killian`` (raw logs in
    ``carmen_raw/``), ``<place>-corrected`` (GMapping-corrected logs in
    ``carmen_gmapping_corrected/``, with ``laser_offset`` zero because their poses are
    laser poses), and ``mrpt-sena``, ``mrpt-localization-demo``, ``mrpt-ual``; each
    entry's ``options`` are its reading defaults.

    Args:
        name: a name above, or a path to a log file.
        **options: keyword arguments for :func:`load_carmen`; they override the
            per-log defaults.
    """
    from jaxslam.datasets.registry import DATASETS, lookup

    key = str(name)
    try:
        info = lookup(key)
    except KeyError:
        info = None
    if info is not None and info.loader == "carmen":
        return info.load(**options)
    path = Path(name)
    if path.is_file():
        return load_carmen(path, **options)
    known = ", ".join(sorted(n for n, i in DATASETS.items() if i.loader == "carmen"))
    raise FileNotFoundError(f"{key!r} is neither a known CARMEN log ({known}) nor a file")
