"""Victoria Park's files (ACFR, Guivant & Nebot 2001), each read strictly: dead
reckoning, GPS, scan times, raw laser scans and tree detections.

The conventions (time base, beam angles, the range policy of the raw laser and the
input checks) are those of :mod:`jaxslam.datasets.victoria_park`, which builds the
filters' event sequence from these records and re-exports every name here.
"""

from __future__ import annotations

import dataclasses
import os
import re
from pathlib import Path
from typing import Any

import numpy as np

from jaxslam.datasets.paths import DataFormatError, find
from jaxslam.datasets.reader import (
    check_increasing,
    check_printable,
    finite_columns,
    load_npz,
    parse_floats,
    read_records,
    read_text,
    same_length,
)

DATASET = "Victoria Park"
FOLDER = "victoria_park"

TIME_ZERO_MS = 20967
"""The .mat millisecond stamp that is t = 0 s (the first GPS fix)."""

NO_RETURN_M = 80.0
"""Laser ranges above this are 'no reflection' (the file value is 81.91 m)."""

NO_RETURN_VALUE = 81.91
"""The file's 'no reflection' range [m]; NaN, inf and non-positive ranges become this."""

N_BEAMS = 361
BEAM_ANGLES = np.arange(N_BEAMS) * (np.pi / 360.0)
"""Raw laser beam angles in rad (0 right, pi/2 ahead, pi left)."""


# --------------------------------------------------------------------------- records


@dataclasses.dataclass(frozen=True)
class DeadReckoning:
    """Dead-reckoning samples: ``times`` [s], encoder ``speed`` [m/s], ``steering`` [rad]."""

    times: np.ndarray
    speed: np.ndarray
    steering: np.ndarray


@dataclasses.dataclass(frozen=True)
class GpsFixes:
    """GPS fixes: ``times`` [s] and ``xy`` (G, 2) local east/north [m]."""

    times: np.ndarray
    xy: np.ndarray


@dataclasses.dataclass(frozen=True)
class LaserScans:
    """Raw scans: ``times`` (S,), ``ranges`` (S, 361) [m], ``angles`` (361,) 0..pi [rad].

    ``meta`` holds the file and the counts of the range policy (module docstring):
    ``laser_no_return_beams`` and ``laser_invalid_ranges``.
    """

    times: np.ndarray
    ranges: np.ndarray
    angles: np.ndarray
    meta: dict[str, Any] = dataclasses.field(default_factory=dict)


@dataclasses.dataclass(frozen=True)
class Detections:
    """Tree detections, one row each, in time order.

    ``bearings`` are in the car frame: 0 ahead, left positive (raw bearing - pi/2).
    """

    times: np.ndarray
    ranges: np.ndarray
    bearings: np.ndarray
    diameters: np.ndarray

_TOKEN = re.compile(r"\S+")


def _locate(default: tuple[str, ...], path: os.PathLike | str | None) -> Path:
    return Path(path) if path is not None else find(DATASET, FOLDER, *default)


def ms_to_s(t_ms: np.ndarray) -> np.ndarray:
    """.mat milliseconds to the module's time base [s]."""
    return (np.asarray(t_ms, dtype=np.float64) - TIME_ZERO_MS) / 1000.0

# --------------------------------------------------------------------------- loaders


def load_dead_reckoning(release: str = "mat", path: os.PathLike | str | None = None) -> DeadReckoning:
    """Load the dead-reckoning samples (40 Hz).

    Args:
        release: ``"mat"`` (``mat/aa3_dr.npz``: 61945 samples, t = 0.973 .. 1549.573 s,
            original steering calibration; the default, see the module docstring) or
            ``"ascii"`` (``acfr_ascii/DRS.txt``: 61763 samples to 1545.023 s,
            recalibrated steering). A path that is not ``.npz`` is read as text
            ``time speed steering`` whatever the release.
        path: read this file instead of the one in the data folder.

    Raises:
        DataFormatError: see the module docstring (input checks).
    """
    default = {"mat": ("mat", "aa3_dr.npz"), "ascii": ("acfr_ascii", "DRS.txt")}
    times, speed, steering = _load_timed_table(
        release, path, default, ("time", "speed", "steering"), "time_s speed_m_s steering_rad"
    )
    return DeadReckoning(times=times, speed=speed, steering=steering)


def _load_timed_table(
    release: str,
    path: os.PathLike | str | None,
    default: dict[str, tuple[str, ...]],
    npz_names: tuple[str, str, str],
    text_header: str,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(times [s], column 1, column 2)`` from a ``.npz`` (time in ms, arrays named
    ``npz_names``) or a text table ``time_s a b``; times strictly increasing."""
    if release not in default:
        raise ValueError(f"release must be 'mat' or 'ascii', got {release!r}")
    file = _locate(default[release], path)
    if file.suffix == ".npz":
        arrays = load_npz(file, list(npz_names))
        columns = {n: arrays[n].reshape(-1).astype(np.float64) for n in npz_names}
        same_length(file, **columns)
        finite_columns(file, **columns)
        time_ms, first, second = (columns[n] for n in npz_names)
        times, lines = ms_to_s(time_ms), None
    else:
        table, lines = read_records(file, 3, text_header)
        times, first, second = (column.copy() for column in table.T)
    check_increasing(file, times, strict=True, lines=lines)
    return times, first, second


def load_gps(release: str = "mat", path: os.PathLike | str | None = None) -> GpsFixes:
    """Load the GPS fixes.

    Args:
        release: ``"mat"`` (``mat/aa3_gpsx.npz``, 4466 fixes, ``xy = (Lo_m, La_m)``,
            the default) or ``"ascii"`` (``acfr_ascii/GPS.txt``, 948 of them in another
            local frame). A path that is not ``.npz`` is read as text ``time x y``.
        path: read this file instead of the one in the data folder.

    Raises:
        DataFormatError: see the module docstring (input checks).
    """
    default = {"mat": ("mat", "aa3_gpsx.npz"), "ascii": ("acfr_ascii", "GPS.txt")}
    times, east, north = _load_timed_table(release, path, default, ("timeGps", "Lo_m", "La_m"), "time_s x_m y_m")
    xy = np.stack([east, north], axis=1)
    return GpsFixes(times=times, xy=xy)


def load_scan_times(path: os.PathLike | str | None = None) -> np.ndarray:
    """The 7249 ``aa3_lsr2`` scan times [s] (``ufastslam/lasersampling.txt``, in ms).

    Raises:
        DataFormatError: see the module docstring (input checks).
    """
    file = _locate(("ufastslam", "lasersampling.txt"), path)
    table, lines = read_records(file, 1, "TLsr_ms")
    times = ms_to_s(table[:, 0])
    check_increasing(file, times, strict=True, lines=lines)
    return times


def _range_policy(ranges: np.ndarray) -> tuple[np.ndarray, dict[str, int]]:
    """Apply the laser range policy (module docstring): ``(ranges float32, counts)``.

    Judged after the cast to float32, so a range that under- or overflows there
    (``1e-320``, ``1e300``) counts as invalid too.
    """
    with np.errstate(over="ignore"):
        ranges = np.asarray(ranges).astype(np.float32)
    invalid = ~np.isfinite(ranges) | (ranges <= 0)
    no_return = ~invalid & (ranges > NO_RETURN_M)
    ranges = np.where(invalid, np.float32(NO_RETURN_VALUE), ranges)
    return ranges, {"laser_no_return_beams": int(no_return.sum()), "laser_invalid_ranges": int(invalid.sum())}


def load_laser(path: os.PathLike | str | None = None) -> LaserScans:
    """Load the raw laser scans of the ACFR ASCII release (7230 scans, 0.852 .. 1545.182 s).

    Args:
        path: ``laser_acfr_ascii.npz`` (the default), or a ``LASER.txt`` stream of
            ``time r_0 .. r_360`` records (line breaks optional, gzip recognised by its
            first bytes).

    Returns:
        Ranges in metres; values above :data:`NO_RETURN_M` mean no return. NaN, inf and
        non-positive ranges are replaced by :data:`NO_RETURN_VALUE` and counted in
        ``meta`` (the range policy in the module docstring).

    Raises:
        DataFormatError: see the module docstring (input checks).
    """
    file = _locate(("acfr_ascii", "laser_acfr_ascii.npz"), path)
    if file.suffix == ".npz":
        arrays = load_npz(file, ["time_s", "ranges_m"])
        times = arrays["time_s"].reshape(-1).astype(np.float64)
        ranges = arrays["ranges_m"].astype(np.float64)
        if ranges.ndim != 2 or ranges.shape != (times.shape[0], N_BEAMS):
            raise DataFormatError(
                file, None, f"ranges_m has shape {ranges.shape}, expected ({times.shape[0]}, {N_BEAMS})"
            )
        finite_columns(file, time_s=times)
        ranges, counts = _range_policy(ranges)
        check_increasing(file, times, strict=True)
    else:
        times, ranges, counts = _read_laser_text(file)
    meta = dict(file=str(file), n_scans=int(times.size), **counts)
    return LaserScans(times=times, ranges=ranges, angles=BEAM_ANGLES.astype(np.float32), meta=meta)


def read_laser_text(path: os.PathLike | str) -> tuple[np.ndarray, np.ndarray]:
    """Parse ACFR's ``LASER.txt`` (optionally gzipped): records of ``1 + 361`` numbers.

    The original file has no line breaks, so errors name the record (scan), the field
    and the line. Ranges follow the range policy of the module docstring; use
    :func:`load_laser` to get the counts. Returns ``(times (S,), ranges (S, 361) float32)``.
    """
    times, ranges, _ = _read_laser_text(Path(path))
    return times, ranges


def _read_laser_text(path: Path) -> tuple[np.ndarray, np.ndarray, dict[str, int]]:
    record = 1 + N_BEAMS

    def complete_records(partial: bytes) -> tuple[str, int, int]:
        partial_text = partial.decode("ascii", errors="replace")
        return f"records (scans) of {record} numbers", len(partial_text.split()) // record, partial_text.count("\n") + 1

    text = read_text(path, progress=complete_records)
    check_printable(path, text)

    def where(index: int) -> tuple[int, str]:
        match = next(m for i, m in enumerate(_TOKEN.finditer(text)) if i == index)
        line = text.count("\n", 0, match.start()) + 1
        return line, f"record {index // record + 1}, field {index % record + 1} of {record}"

    words = text.split()
    if not words:
        raise DataFormatError(path, None, "no records (time + 361 ranges)")
    values, bad = parse_floats(words)
    if values is None:
        line, place = where(bad)
        raise DataFormatError(path, line, f"{words[bad][:20]!r} is not a number ({place})")
    if values.size % record:
        n_full = values.size // record
        line = text.count("\n", 0, len(text.rstrip())) + 1
        raise DataFormatError(
            path, line,
            f"{values.size} numbers is not a whole number of {record}-number records "
            f"(time + {N_BEAMS} ranges): record {n_full + 1} is incomplete",
        )
    table = values.reshape(-1, record)
    times = table[:, 0].copy()
    finite = np.isfinite(times)
    if not finite.all():
        index = int(np.argmin(finite)) * record
        line, place = where(index)
        raise DataFormatError(path, line, f"scan time {words[index]!r} is not finite ({place})")
    steps = np.diff(times)
    if np.any(steps <= 0):
        k = int(np.argmax(steps <= 0)) + 1
        line, place = where(k * record)
        raise DataFormatError(
            path, line, f"time {times[k]:.3f} s after {times[k - 1]:.3f} s ({place}): times must increase"
        )
    ranges, counts = _range_policy(table[:, 1:])
    return times, ranges, counts


def load_detections_file(file: Path) -> tuple[Detections, np.ndarray]:
    table, lines = read_records(file, 4, "time_s range_m bearing_rad diameter_m")
    times, ranges, raw_bearings, diameters = (column.copy() for column in table.T)
    check_increasing(file, times, strict=False, lines=lines)
    bad = np.nonzero((ranges <= 0) | (raw_bearings < 0) | (raw_bearings > np.pi + 1e-6) | (diameters < 0))[0]
    if bad.size:
        k = int(bad[0])
        raise DataFormatError(
            file, int(lines[k]),
            f"range {ranges[k]} m / bearing {raw_bearings[k]} rad / diameter {diameters[k]} m outside "
            "range > 0, bearing in [0, pi], diameter >= 0",
        )
    detections = Detections(times=times, ranges=ranges, bearings=raw_bearings - np.pi / 2, diameters=diameters)
    return detections, lines


def load_detections(path: os.PathLike | str | None = None) -> Detections:
    """Load ACFR's tree detections (``rfs_slam_ascii/measurements.dat``, 52974 rows).

    Rows are ``time range raw_bearing diameter``; the raw bearing runs 0..pi with pi/2
    ahead and is returned as ``raw - pi/2`` (0 ahead, left positive).

    Raises:
        DataFormatError: see the module docstring (input checks); also a range that is
            not positive, a raw bearing outside [0, pi] or a negative diameter.
    """
    return load_detections_file(_locate(("rfs_slam_ascii", "measurements.dat"), path))[0]
