"""Reading the lines of a CARMEN log: a bulk reader for the common case (one scan
type, one geometry, well-formed lines) and a line-by-line reader that locates every
problem (see :mod:`jaxslam.datasets.carmen` for the formats and the error policy).

:func:`read_lines_fast` returns None whenever the bulk path does not apply, and the
caller falls back to :func:`read_lines_slow`; both give the same :class:`Lines`.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from jaxslam.datasets.carmen_parse import (
    Collector,
    LineError,
    parse_flaser,
    parse_odom,
    parse_param,
    parse_robotlaser1,
    text_of,
)
from jaxslam.datasets.paths import DataFormatError



def describe_geometry(geometry: tuple) -> str:
    if len(geometry) == 1:
        return f"{geometry[0]} beams"
    n, start, resolution, max_range = geometry
    return (
        f"{n} beams from {start:.6g} rad every {resolution:.6g} rad, max range {max_range:.6g} m"
    )


@dataclasses.dataclass
class Lines:
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
    odom_speeds: np.ndarray
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


def read_lines_fast(text: bytes, scan_type: bytes | None, max_backstep: float) -> Lines | None:
    """The common case in bulk: a FLASER log with one beam count and no bad line.

    Lines are sorted by message type with one cheap split each; the numbers of all
    FLASER lines, and of all ODOM lines, are then parsed at once by NumPy (the host
    name, the one text field, is cut out first). Anything this path does not handle
    exactly as :func:`read_lines_slow` would (ROBOTLASER1 scans, several beam counts,
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
                name, value = parse_param(raw.split())
                params[name] = (value, line_number)
            else:
                stats["unknown_messages"] = stats.get("unknown_messages", 0) + 1
                key = f"unknown:{text_of(head[:32])}"
                stats[key] = stats.get(key, 0) + 1
    except (ValueError, IndexError, LineError):
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
    return Lines(
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
        odom_speeds=np.ascontiguousarray(odom[:, 3]),
        params=params,
        stats=stats,
    )


def read_lines_slow(
    text: bytes,
    path: Path,
    collector: Collector,
    scan_type: bytes | None,
    max_backstep: float,
    mixed_geometry: str,
) -> Lines:
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
    odom_speed_list: list[float] = []
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
                parse = parse_flaser if head == b"FLASER" else parse_robotlaser1
                record = parse(parts)
                if ipc_list:
                    step = record["ipc"] - ipc_list[-1]
                    if step < -max_backstep:
                        raise LineError(
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
                            f"scan geometry changes: {describe_geometry(record['geometry'])} here, "
                            f"but {describe_geometry(geometries[0])} on line {first_geometry_line}; "
                            "pass mixed_geometry='pad' (jaxslam run --mixed-geometry pad) to pad scans to a "
                            "common length",
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
                pose, speed, stamp = parse_odom(parts)
                if odom_time_list and stamp < odom_time_list[-1]:
                    collector.count("odom_backwards_timestamps")
                odom_list.append(pose)
                odom_speed_list.append(speed)
                odom_time_list.append(stamp)
            elif head == b"PARAM":
                name, value = parse_param(parts)
                params[name] = (value, line_number)
            else:
                collector.count("unknown_messages")
                collector.count(f"unknown:{text_of(head[:32])}")
        except LineError as error:
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
    return Lines(
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
        odom_speeds=np.array(odom_speed_list, dtype=np.float64),
        params=params,
    )


