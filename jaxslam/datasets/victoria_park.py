"""Victoria Park (ACFR, Guivant & Nebot 2001): loaders and the filter's event sequence.

Host-side NumPy only; never imported by a kernel.

Which release, which time base
------------------------------
The recording exists in two releases (see the dataset README). jaxslam uses the
**MATLAB release** (``mat/aa3_dr``, ``mat/aa3_gpsx``, the ``aa3_lsr2`` scan times and
the tree detections ACFR's ``detectTreesI16`` extracted from every ``aa3_lsr2`` scan),
because that is what the authors of the ERB paper (Kim, Kim & Chung, ICRA 2011) and of
UFastSLAM (Kim, Sakthivel & Chung, T-RO 2008) used: their public code (OpenSLAM
``ufastslam``, ``setconfigfile.m``) loads the ``.mat`` speed, the ``.mat`` steering
(the original calibration, not the ACFR ASCII recalibration
``steer_ascii = 1.05919 steer_mat + 0.00261``) and all 7249 ``aa3_lsr2`` scans, and runs
the full 1549.6 s, whereas the ACFR ASCII release stops at 1545.2 s.

Every time in this module is in one base: **seconds since the .mat millisecond stamp
20967** (the first GPS fix), ``t_s = (t_ms - 20967) / 1000``. This is also the time of
the ACFR ASCII release and of the RFS-SLAM conversion, so the raw ASCII laser scans and
the ``.mat`` data line up without any shift (the 7230 ASCII scans are the first 7230
``aa3_lsr2`` scans, to the millisecond).

Vehicle model (Guivant & Nebot 2001, Sec. II; UFastSLAM ``predictACFRu.m``)
--------------------------------------------------------------------------
The car is an Ackermann vehicle with wheelbase ``L``. The speed sensor is an encoder on
the rear-left wheel, ``H`` to the left of the rear-axle centre; the laser is ``a`` ahead
of the front axle and ``b`` to the left of the centre line (``CAR_GEOMETRY``, from ACFR's
``info.txt``). The filter's pose ``(x, y, phi)`` is the **laser's position** and the
car's heading, so the laser sits at ``LASER_OFFSET = (L + a, b) = (3.78, 0.5)`` m in the
rear-axle frame (UFastSLAM sets ``vehicle.a = 3.78``). With encoder speed ``v_e`` and
steering angle ``s`` held over ``dt``::

    v_c   = v_e / (1 - tan(s) H / L)                      # speed of the rear-axle centre
    w     = v_c tan(s) / L                                # yaw rate
    x'    = x   + dt (v_c cos(phi) - w (A sin(phi) + b cos(phi)))
    y'    = y   + dt (v_c sin(phi) + w (A cos(phi) - b sin(phi)))
    phi'  = phi + dt w                                     # with A = L + a = 3.78 m

(the velocity of the point ``(A, b)`` of a body whose rear-axle centre moves at ``v_c``
and turns at ``w``). A row with ``dt = 0`` leaves the pose unchanged.

Observation model
-----------------
An observation ``z = (r, theta)`` is the range from the laser to the trunk centre and
the bearing in the laser/car frame, 0 straight ahead, positive to the left (the raw
laser bearing, 0..pi with pi/2 ahead, minus pi/2, as in UFastSLAM ``getObservation.m``).
For a landmark at ``(m_x, m_y)`` and the pose above (the laser's pose)::

    r     = sqrt((m_x - x)^2 + (m_y - y)^2)
    theta = wrap(atan2(m_y - y, m_x - x) - phi)

If a filter tracks the rear-axle centre instead, the laser is at
``pose (+) LASER_OFFSET`` (SE(2) composition) and the same formula applies from there.

The sequence
------------
``load_sequence`` gives one step per laser scan. Step ``i`` carries the controls that
move the car from scan ``i-1`` to scan ``i`` (zero-order hold: a DR sample holds until
the next one; the last piece is split at the scan time so that the ``dt`` of step ``i``
add up to ``times[i] - times[i-1]``), padded with ``dt = 0`` rows, then the
observations of scan ``i``. Step 0 has no motion (it is the initial pose, at the time of
scan 0; before the first DR sample the car is at rest). The paper's 30 m perception
limit is applied as ``range < max_range`` (UFastSLAM: ``OD < perceplimit``).

Input checks and the policy for oddities
---------------------------------------
Every loader raises :class:`~jaxslam.datasets.paths.DataFormatError`, naming the file,
the line (text) or record (``.npz``) and the problem, for: a wrong number of columns; a
word that is not a number (including ``1_000``, which Python would accept); NaN or
inf in a time, speed, steering, GPS coordinate or detection; a character that is not
printable ASCII; times that go backwards (DR, GPS, scan times and raw scans must
strictly increase, detections must not decrease); a file with no records; a truncated
or corrupt gzip stream (recognised by its magic bytes, whatever the suffix); an
``.npz`` that is unreadable, lacks an array, holds non-numeric or differently sized
arrays; a raw laser stream that is not whole ``1 + 361``-number records; a detection
with range <= 0, raw bearing outside [0, pi] or negative diameter, or (in
:func:`load_sequence`) at a time that is no scan time. A missing file raises
:class:`~jaxslam.datasets.paths.DatasetNotFoundError`. No line is skipped: these
files are small and clean, and a dropped DR or detection line would silently bend
the trajectory.

Recoverable oddities are kept, handled by a fixed rule and counted, never silently:

* raw laser ranges above :data:`NO_RETURN_M` (the file's 81.91 m) mean "no
  reflection"; they stay in ``ranges`` and are counted (``laser_no_return_beams``);
* raw laser ranges that are NaN, +-inf or <= 0 are replaced by
  :data:`NO_RETURN_VALUE` (a no return) and counted (``laser_invalid_ranges``);
* detections at or beyond ``max_range`` are dropped and counted
  (``observations_beyond_max_range``, also ``n_dropped_range``).

:func:`load_laser` puts its counts in ``LaserScans.meta``; :func:`load_sequence` puts
those of the source it used in ``meta["recovered"]``.

Note: UFastSLAM skips prediction *and* update whenever the DR speed is exactly 0 (the
car stands still for the first ~20 s); a filter that wants the same behaviour can test
``(controls[i, :, 0] != 0).any()``.
"""

from __future__ import annotations

import dataclasses
import os
import re
from pathlib import Path
from typing import Any

import numpy as np

from jaxslam.datasets import trees
from jaxslam.datasets.paths import DataFormatError, find
from jaxslam.datasets.reader import check_printable, load_npz, read_text

DATASET = "Victoria Park"
FOLDER = "victoria_park"

CAR_GEOMETRY = dict(L=2.83, H=0.76, a=0.95, b=0.5)
"""ACFR's car parameters [m] (``info.txt``): wheelbase ``L``, encoder offset ``H``,
laser ``a`` ahead of the front axle and ``b`` to the left."""

LASER_OFFSET = (round(CAR_GEOMETRY["L"] + CAR_GEOMETRY["a"], 9), CAR_GEOMETRY["b"])
"""Laser position in the rear-axle frame [m]: ``(L + a, b) = (3.78, 0.5)``."""

TIME_ZERO_MS = 20967
"""The .mat millisecond stamp that is t = 0 s (the first GPS fix)."""

NO_RETURN_M = 80.0
"""Laser ranges above this are 'no reflection' (the file value is 81.91 m)."""

NO_RETURN_VALUE = 81.91
"""The file's 'no reflection' range [m]; NaN, inf and non-positive ranges become this."""

N_BEAMS = 361
BEAM_ANGLES = np.arange(N_BEAMS) * (np.pi / 360.0)
"""Raw laser beam angles [rad]: 0 = right, pi/2 = ahead, pi = left."""

EXPECTED = dict(
    n_dr=61945,
    n_gps=4466,
    n_scans=7249,
    n_raw_scans=7230,
    n_detections=52974,
)
"""Counts stated in the dataset README, for checks."""


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


@dataclasses.dataclass(frozen=True)
class VictoriaParkSequence:
    """Fixed-shape event sequence, one step per laser scan.

    Attributes:
        times: (T,) scan times [s].
        controls: (T, K, 3) ``[encoder speed m/s, steering rad, dt s]`` pieces that move
            the car from scan ``i-1`` to scan ``i``; padding rows are all zero.
        observations: (T, Z, 2) ``[range m, bearing rad]`` from the laser, bearing 0
            ahead and left positive; padding rows are zero.
        obs_mask: (T, Z) which observation rows are real.
        gps_times: (G,) [s], same time base.
        gps_xy: (G, 2) local east/north [m] (``aa3_gpsx`` ``Lo_m``, ``La_m``).
        meta: source files, counts and conventions; ``meta["recovered"]`` counts every
            recoverable oddity the input policy handled (module docstring).
    """

    times: np.ndarray
    controls: np.ndarray
    observations: np.ndarray
    obs_mask: np.ndarray
    gps_times: np.ndarray
    gps_xy: np.ndarray
    meta: dict[str, Any]

    @property
    def n_steps(self) -> int:
        return int(self.times.shape[0])


# --------------------------------------------------------------------------- parsing


_TOKEN = re.compile(r"\S+")


def _parse_floats(words: list[str]) -> tuple[np.ndarray | None, int | None]:
    """``(values, None)``, or ``(None, index of the first word that is not a number)``.

    Python's and NumPy's float parsers accept ``1_000``; a data file never means that,
    so words with an underscore are refused too.
    """
    try:
        values = np.array(words, dtype=np.float64)
    except ValueError:
        values = None
    if values is not None and not any("_" in word for word in words):
        return values, None
    bad = next(i for i, word in enumerate(words) if "_" in word or not _is_float(word))
    return None, bad


def _is_float(word: str) -> bool:
    try:
        float(word)
    except ValueError:
        return False
    return True


def _read_records(path: Path, n_columns: int, what: str) -> tuple[np.ndarray, np.ndarray]:
    """Parse a line-per-record numeric table; ``(table (N, n_columns), line numbers (N,))``."""
    text = read_text(path)
    check_printable(path, text)
    words: list[str] = []
    line_numbers: list[int] = []
    for number, line in enumerate(text.replace("\r\n", "\n").replace("\r", "\n").split("\n"), start=1):
        parts = line.split()
        if not parts:
            continue
        if len(parts) != n_columns:
            raise DataFormatError(
                path, number, f"expected {n_columns} numbers ({what}), found {len(parts)}: {line.strip()[:80]!r}"
            )
        words.extend(parts)
        line_numbers.append(number)
    if not line_numbers:
        raise DataFormatError(path, None, f"no records ({what})")
    lines = np.asarray(line_numbers, dtype=np.int64)
    values, bad = _parse_floats(words)
    if values is None:
        raise DataFormatError(
            path, int(lines[bad // n_columns]),
            f"{words[bad][:40]!r} is not a number (field {bad % n_columns + 1} of {n_columns}: {what})",
        )
    finite = np.isfinite(values)
    if not finite.all():
        bad = int(np.argmin(finite))
        raise DataFormatError(
            path, int(lines[bad // n_columns]),
            f"non-finite value {words[bad][:40]!r} (field {bad % n_columns + 1} of {n_columns}: {what})",
        )
    return values.reshape(-1, n_columns), lines


def read_table(path: os.PathLike | str, n_columns: int, what: str) -> np.ndarray:
    """Read a whitespace-separated numeric table, one record per line.

    Blank lines are skipped; LF, CRLF and CR line ends are accepted; a gzip stream is
    recognised by its first bytes. Every problem (wrong column count, a word that is not
    a number, a non-finite value, a character that is not printable ASCII, a truncated
    or corrupt gzip stream, no records at all) raises :class:`DataFormatError` naming
    the file and line.

    Args:
        path: the file.
        n_columns: the number of numbers each line must hold.
        what: the column names, for the error message.

    Returns:
        (N, n_columns) float64.
    """
    return _read_records(Path(path), n_columns, what)[0]


def _record(lines: np.ndarray | None, k: int) -> tuple[int | None, str]:
    """Line number of record ``k`` (text files) or ``None`` and a record label (arrays)."""
    if lines is None:
        return None, f"record {k + 1}: "
    return int(lines[k]), ""


def _check_increasing(path: Path, times: np.ndarray, strict: bool, lines: np.ndarray | None = None) -> None:
    """Raise if ``times`` ever decreases (or repeats, when ``strict``); names the line or record."""
    steps = np.diff(times)
    bad = np.nonzero(steps <= 0 if strict else steps < 0)[0]
    if bad.size:
        k = int(bad[0]) + 1
        line, label = _record(lines, k)
        order = "increase" if strict else "not decrease"
        raise DataFormatError(
            path, line, f"{label}time {times[k]:.3f} s after {times[k - 1]:.3f} s: times must {order}"
        )


def _finite_columns(path: Path, **columns: np.ndarray) -> None:
    """Raise naming the first record of any column that is not finite."""
    for name, values in columns.items():
        finite = np.isfinite(values)
        if not finite.all():
            k = int(np.argmin(finite.reshape(finite.shape[0], -1).all(axis=1)))
            raise DataFormatError(path, None, f"record {k + 1}: {name} is not finite")


def _same_length(path: Path, **columns: np.ndarray) -> None:
    lengths = {name: int(values.shape[0]) for name, values in columns.items()}
    if len(set(lengths.values())) > 1:
        raise DataFormatError(path, None, f"arrays differ in length: {lengths}")


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
        _same_length(file, **columns)
        _finite_columns(file, **columns)
        time_ms, first, second = (columns[n] for n in npz_names)
        times, lines = ms_to_s(time_ms), None
    else:
        table, lines = _read_records(file, 3, text_header)
        times, first, second = (column.copy() for column in table.T)
    _check_increasing(file, times, strict=True, lines=lines)
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
    table, lines = _read_records(file, 1, "TLsr_ms")
    times = ms_to_s(table[:, 0])
    _check_increasing(file, times, strict=True, lines=lines)
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
        _finite_columns(file, time_s=times)
        ranges, counts = _range_policy(ranges)
        _check_increasing(file, times, strict=True)
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
    values, bad = _parse_floats(words)
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


def _load_detections(file: Path) -> tuple[Detections, np.ndarray]:
    table, lines = _read_records(file, 4, "time_s range_m bearing_rad diameter_m")
    times, ranges, raw_bearings, diameters = (column.copy() for column in table.T)
    _check_increasing(file, times, strict=False, lines=lines)
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
    return _load_detections(_locate(("rfs_slam_ascii", "measurements.dat"), path))[0]


# --------------------------------------------------------------------------- sequence


def build_controls(scan_times: np.ndarray, dr: DeadReckoning) -> np.ndarray:
    """Zero-order-hold control pieces between consecutive scans.

    Piece boundaries are the union of scan and DR times; a piece that starts at ``p``
    uses the last DR sample at or before ``p``. Pieces before the first DR sample are
    dropped (the car is at rest). Returns (T, K, 3) ``[speed, steering, dt]`` with
    ``K`` the largest number of pieces in a step and zero rows as padding.
    """
    scan_times = np.asarray(scan_times, dtype=np.float64)
    n_steps = scan_times.shape[0]
    inside = (dr.times > scan_times[0]) & (dr.times < scan_times[-1])
    points = np.union1d(scan_times, dr.times[inside])
    starts, ends = points[:-1], points[1:]
    sample = np.searchsorted(dr.times, starts, side="right") - 1
    keep = sample >= 0
    starts, ends, sample = starts[keep], ends[keep], sample[keep]
    step = np.searchsorted(scan_times, ends, side="left")
    counts = np.bincount(step, minlength=n_steps)
    width = max(int(counts.max()) if counts.size else 0, 1)
    slot = np.arange(step.size) - np.concatenate([[0], np.cumsum(counts)])[step]
    controls = np.zeros((n_steps, width, 3), dtype=np.float64)
    controls[step, slot, 0] = dr.speed[sample]
    controls[step, slot, 1] = dr.steering[sample]
    controls[step, slot, 2] = ends - starts
    return controls


def _scan_of(scan_times: np.ndarray, obs_times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Scan index of each observation time and whether it matches no scan time (to the ms)."""
    scan_ms = np.round(np.asarray(scan_times) * 1000.0).astype(np.int64)
    obs_ms = np.round(np.asarray(obs_times) * 1000.0).astype(np.int64)
    step = np.searchsorted(scan_ms, obs_ms)
    unmatched = scan_ms[np.minimum(step, scan_ms.size - 1)] != obs_ms
    return step, unmatched


def build_observations(
    scan_times: np.ndarray,
    obs_times: np.ndarray,
    ranges: np.ndarray,
    bearings: np.ndarray,
    max_range: float,
    capacity: int | None = None,
) -> tuple[np.ndarray, np.ndarray, dict[str, int]]:
    """Group detections by scan into padded (T, Z, 2) arrays, keeping ``range < max_range``.

    Every detection time must equal a scan time to the millisecond.

    Returns:
        ``(observations, obs_mask, counts)`` where counts has ``n_kept``,
        ``n_dropped_range`` and ``Z``.
    """
    step, unmatched = _scan_of(scan_times, obs_times)
    if unmatched.any():
        k = int(np.nonzero(unmatched)[0][0])
        raise ValueError(f"detection {k} at t = {obs_times[k]:.3f} s falls on no scan time")
    keep = np.asarray(ranges) < max_range
    order = np.argsort(step[keep], kind="stable")
    padded, mask = trees.pad_by_scan(
        step[keep][order], np.shape(scan_times)[0], capacity,
        ranges=np.asarray(ranges, dtype=np.float64)[keep][order],
        bearings=np.asarray(bearings, dtype=np.float64)[keep][order],
    )
    observations = np.stack([padded["ranges"], padded["bearings"]], axis=-1)
    width = mask.shape[1]
    info = dict(n_kept=int(keep.sum()), n_dropped_range=int((~keep).sum()), Z=width)
    return observations, mask, info


def load_sequence(
    source: str = "detections",
    max_range: float = 30.0,
    max_steps: int | None = None,
) -> VictoriaParkSequence:
    """Build the event sequence the filters consume (one step per laser scan).

    Args:
        source: ``"detections"``: ACFR's ``detectTreesI16`` detections on all 7249
            ``aa3_lsr2`` scans (T = 7249, to 1549.2 s; the papers' data), or
            ``"extractor"``: :func:`jaxslam.datasets.trees.extract_trees` run on the
            7230 raw ASCII scans (T = 7230, to 1545.2 s).
        max_range: keep observations with ``range < max_range`` [m] (the papers' 30 m).
        max_steps: keep only the first ``max_steps`` scans (GPS is cut to match).

    Returns:
        A :class:`VictoriaParkSequence` in the module's time base, ``.mat`` DR and GPS.
    """
    if source not in ("detections", "extractor"):
        raise ValueError(f"source must be 'detections' or 'extractor', got {source!r}")
    if max_steps is not None and max_steps < 1:
        raise ValueError(f"max_steps must be at least 1, got {max_steps}")
    dr = load_dead_reckoning("mat")
    gps = load_gps("mat")
    recovered: dict[str, int] = {}
    files = {
        "dead_reckoning": str(find(DATASET, FOLDER, "mat", "aa3_dr.npz")),
        "gps": str(find(DATASET, FOLDER, "mat", "aa3_gpsx.npz")),
    }
    if source == "detections":
        scan_times = load_scan_times()
        detections_file = find(DATASET, FOLDER, "rfs_slam_ascii", "measurements.dat")
        detections, lines = _load_detections(detections_file)
        obs_times, obs_ranges, obs_bearings = detections.times, detections.ranges, detections.bearings
        _, unmatched = _scan_of(scan_times, obs_times)
        if unmatched.any():
            k = int(np.argmax(unmatched))
            raise DataFormatError(
                detections_file, int(lines[k]),
                f"detection at t = {obs_times[k]:.3f} s falls on no scan time of lasersampling.txt",
            )
        files["scan_times"] = str(find(DATASET, FOLDER, "ufastslam", "lasersampling.txt"))
        files["detections"] = str(detections_file)
    else:
        laser = load_laser()
        scan_times = laser.times
        found = trees.extract_trees(laser.ranges)
        scan_index = np.broadcast_to(np.arange(scan_times.size)[:, None], found.mask.shape)[found.mask]
        obs_times = scan_times[scan_index]
        obs_ranges, obs_bearings = found.ranges[found.mask], found.bearings[found.mask]
        files["laser"] = str(find(DATASET, FOLDER, "acfr_ascii", "laser_acfr_ascii.npz"))
        recovered.update({k: laser.meta[k] for k in ("laser_no_return_beams", "laser_invalid_ranges")})

    n_scans_total = int(scan_times.size)
    if max_steps is not None:
        scan_times = scan_times[:max_steps]
        in_window = obs_times <= scan_times[-1] + 5e-4
        obs_times, obs_ranges, obs_bearings = obs_times[in_window], obs_ranges[in_window], obs_bearings[in_window]
    controls = build_controls(scan_times, dr)
    observations, obs_mask, counts = build_observations(scan_times, obs_times, obs_ranges, obs_bearings, max_range)
    recovered["observations_beyond_max_range"] = counts["n_dropped_range"]
    gps_keep = gps.times <= scan_times[-1]
    meta = dict(
        dataset=DATASET,
        source=source,
        files=files,
        release="mat (OpenSLAM ufastslam / aa3_*.mat); .mat steering calibration",
        time_base="seconds since .mat stamp 20967 ms (= ACFR ASCII / RFS-SLAM time)",
        bearing_frame="laser/car frame: 0 ahead, left positive (raw - pi/2)",
        pose_convention="pose = laser position + car heading; laser at (L + a, b) in the rear-axle frame",
        car_geometry=dict(CAR_GEOMETRY),
        laser_offset=LASER_OFFSET,
        max_range=float(max_range),
        n_steps=int(scan_times.size),
        n_scans_available=n_scans_total,
        n_dr=int(dr.times.size),
        n_gps=int(gps_keep.sum()),
        n_detections=int(obs_times.size),
        n_observations=counts["n_kept"],
        n_dropped_range=counts["n_dropped_range"],
        n_scans_without_obs=int((~obs_mask.any(axis=1)).sum()),
        K=int(controls.shape[1]),
        Z=int(observations.shape[1]),
        recovered=recovered,
    )
    return VictoriaParkSequence(
        times=scan_times,
        controls=controls,
        observations=observations,
        obs_mask=obs_mask,
        gps_times=gps.times[gps_keep],
        gps_xy=gps.xy[gps_keep],
        meta=meta,
    )
