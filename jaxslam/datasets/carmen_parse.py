"""CARMEN messages, one line at a time: the parsers of FLASER, ROBOTLASER1, ODOM and
PARAM lines, and the collector of skipped lines (see :mod:`jaxslam.datasets.carmen`
for the formats and the error policy).

Host-side; a parser raises :class:`LineError` with a reason (the ``stats`` key of a
skipped line) and a message, which :mod:`jaxslam.datasets.carmen_read` turns into a
:class:`~jaxslam.datasets.paths.DataFormatError` naming the file and line, or a
skipped line.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from jaxslam.datasets.paths import DataFormatError

_FLASER_TAIL = 9  # x y theta odom_x odom_y odom_theta ipc_ts host logger_ts
_ROBOTLASER1_TAIL = 14  # 6 poses, tv rv fwd side turn, ipc_ts host logger_ts
_ODOM_FIELDS = 10
_MAX_PROBLEMS = 100


class LineError(Exception):
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
        raise LineError("non_numeric", f"{what} is not a number: {token[:40]!r}") from None
    if not math.isfinite(value):
        raise LineError("non_finite", f"{what} is not finite: {token[:40]!r}")
    return value


def _count(token: bytes, what: str) -> int:
    try:
        value = int(token)
    except ValueError:
        raise LineError("non_numeric", f"{what} is not an integer: {token[:40]!r}") from None
    if value < 1:
        raise LineError("bad_beam_count", f"{what} must be positive, got {value}")
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
                raise LineError(
                    "non_numeric", f"{what} is not a number: {token[:40]!r}"
                ) from None
        raise LineError("non_numeric", f"{what} holds a non-number") from None


def _finite(values: np.ndarray, what: str) -> np.ndarray:
    if not np.all(np.isfinite(values)):
        raise LineError("non_finite", f"{what} is not finite (NaN or inf)")
    return values


def _stamps(parts: list[bytes]) -> tuple[float, float]:
    return _float(parts[-3], "ipc_timestamp"), _float(parts[-1], "logger_timestamp")


def parse_flaser(parts: list[bytes]) -> dict[str, Any]:
    if len(parts) < 2:
        raise LineError("truncated", "FLASER line ends before its beam count")
    n = _count(parts[1], "FLASER beam count")
    expected = 2 + n + _FLASER_TAIL
    if len(parts) != expected:
        raise LineError(
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


def parse_robotlaser1(parts: list[bytes]) -> dict[str, Any]:
    if len(parts) < 10:
        raise LineError("truncated", "ROBOTLASER1 line ends before its ranges")
    header = _finite(_numbers(parts[2:8], "a ROBOTLASER1 header field"), "ROBOTLASER1 header")
    start, fov, resolution, max_range = header[0], header[1], header[2], header[3]
    if not resolution > 0.0:
        raise LineError("bad_geometry", f"ROBOTLASER1 angular resolution {resolution} <= 0")
    if not max_range > 0.0:
        raise LineError("bad_geometry", f"ROBOTLASER1 max range {max_range} <= 0")
    n = _count(parts[8], "ROBOTLASER1 beam count")
    if len(parts) < 10 + n:
        raise LineError(
            "field_count",
            f"ROBOTLASER1 says {n} beams but the line has only {len(parts)} fields",
        )
    m_token = parts[9 + n]
    try:
        m = int(m_token)
    except ValueError:
        raise LineError(
            "non_numeric", f"ROBOTLASER1 remission count is not an integer: {m_token[:40]!r}"
        ) from None
    if m < 0:
        raise LineError("field_count", f"ROBOTLASER1 remission count {m} < 0")
    expected = 10 + n + m + _ROBOTLASER1_TAIL
    if len(parts) != expected:
        raise LineError(
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


def parse_odom(parts: list[bytes]) -> tuple[np.ndarray, float, float]:
    """``(pose (3,), tv, ipc_timestamp)`` of an ODOM line."""
    if len(parts) != _ODOM_FIELDS:
        raise LineError(
            "field_count", f"ODOM needs {_ODOM_FIELDS} fields, but the line has {len(parts)}"
        )
    pose = _finite(_numbers(parts[1:4], "an ODOM pose"), "an ODOM pose")
    velocities = _numbers(parts[4:7], "an ODOM velocity")
    ipc, _ = _stamps(parts)
    return pose, float(velocities[0]), ipc


def parse_param(parts: list[bytes]) -> tuple[str, str]:
    if len(parts) < 3:
        raise LineError("truncated", "PARAM line needs at least a name and a value")
    if len(parts) >= 6:
        value = parts[2:-3]
    elif len(parts) == 5:  # GMapping writes "PARAM name value host logger_ts"
        value = parts[2:-2]
    else:
        value = parts[2:]
    return text_of(parts[1]), " ".join(text_of(token) for token in value)


def text_of(token: bytes) -> str:
    return token.decode("utf-8", "replace")


class Collector:
    """Routes line problems to an exception or to the skip counters."""

    def __init__(self, path: Path, on_error: str):
        self.path = path
        self.on_error = on_error
        self.stats: dict[str, int] = {}
        self.problems: list[str] = []

    def count(self, key: str, amount: int = 1) -> None:
        self.stats[key] = self.stats.get(key, 0) + amount

    def bad_line(self, line: int | None, error: LineError) -> None:
        if self.on_error == "raise":
            raise DataFormatError(self.path, line, error.problem)
        self.count("skipped_lines")
        self.count(f"skipped:{error.reason}")
        if len(self.problems) < _MAX_PROBLEMS:
            self.problems.append(str(DataFormatError(self.path, line, error.problem)))


def param_float(
    params: dict[str, tuple[str, int]], name: str, collector: Collector
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
            line, LineError("bad_param", f"PARAM {name} is not a finite number: {text[:40]!r}")
        )
        return None
