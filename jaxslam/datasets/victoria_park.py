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
---------------------------------------------------------------------------
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
----------------------------------------
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

* raw laser ranges above :data:`~jaxslam.datasets.victoria_park_files.NO_RETURN_M` (the file's 81.91 m) mean "no
  reflection"; they stay in ``ranges`` and are counted (``laser_no_return_beams``);
* raw laser ranges that are NaN, +-inf or <= 0 are replaced by
  :data:`~jaxslam.datasets.victoria_park_files.NO_RETURN_VALUE` (a no return) and counted (``laser_invalid_ranges``);
* detections at or beyond ``max_range`` are dropped and counted
  (``observations_beyond_max_range``, also ``n_dropped_range``).

:func:`~jaxslam.datasets.victoria_park_files.load_laser` puts its counts in
``LaserScans.meta``; :func:`load_sequence` puts those of the source it used in
``meta["recovered"]``.

Steering calibration: ``load_sequence(steering="acfr")`` replaces the ``.mat`` steering
by ACFR's later recalibration, the affine map ``steer_ascii = c_1 steer_mat + c_0`` that the
ASCII release applied (fitted here by least squares on the samples both releases share,
``c_1 = 1.05919``, ``c_0 = 0.00261`` rad, max residual 5e-5 rad, and applied to every
``.mat`` sample, so the sequence keeps the full 1549.6 s). Dead reckoning alone drifts
less with it (over 120 s windows aligned to GPS: 2.7 m mean against 6.5 m with the
``.mat`` steering); the default stays ``"mat"``, the papers' data.

Note: UFastSLAM skips prediction *and* update whenever the DR speed is exactly 0 (the
car stands still for the first ~20 s); a filter that wants the same behaviour can test
``(controls[i, :, 0] != 0).any()``.

Layout: the readers of the single files
(:func:`~jaxslam.datasets.victoria_park_files.load_dead_reckoning`,
:func:`~jaxslam.datasets.victoria_park_files.load_gps`,
:func:`~jaxslam.datasets.victoria_park_files.load_scan_times`,
:func:`~jaxslam.datasets.victoria_park_files.load_laser`,
:func:`~jaxslam.datasets.victoria_park_files.load_detections`) are in
:mod:`jaxslam.datasets.victoria_park_files` and re-exported here; the strict table
reader they share is :mod:`jaxslam.datasets.reader`.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from jaxslam.datasets import trees
from jaxslam.datasets.paths import DataFormatError, find
from jaxslam.datasets.victoria_park_files import (
    BEAM_ANGLES,
    DATASET,
    FOLDER,
    N_BEAMS,
    NO_RETURN_M,
    NO_RETURN_VALUE,
    TIME_ZERO_MS,
    DeadReckoning,
    Detections,
    GpsFixes,
    LaserScans,
    load_dead_reckoning,
    load_detections,
    load_detections_file,
    load_gps,
    load_laser,
    load_scan_times,
    ms_to_s,
    read_laser_text,
)

__all__ = [
    "BEAM_ANGLES", "CAR_GEOMETRY", "DATASET", "EXPECTED", "FOLDER", "LASER_OFFSET", "N_BEAMS", "NO_RETURN_M",
    "NO_RETURN_VALUE", "TIME_ZERO_MS", "DeadReckoning", "Detections", "GpsFixes", "LaserScans",
    "VictoriaParkSequence", "acfr_steering", "build_controls", "build_observations", "load_dead_reckoning", "load_detections",
    "load_gps", "load_laser", "load_scan_times", "load_sequence", "ms_to_s", "read_laser_text",
]
"""Public names; the file readers live in :mod:`jaxslam.datasets.victoria_park_files`."""

CAR_GEOMETRY = dict(L=2.83, H=0.76, a=0.95, b=0.5)
"""ACFR's car parameters [m] (``info.txt``): wheelbase ``L``, encoder offset ``H``,
laser ``a`` ahead of the front axle and ``b`` to the left."""

LASER_OFFSET = (round(CAR_GEOMETRY["L"] + CAR_GEOMETRY["a"], 9), CAR_GEOMETRY["b"])
"""Laser position in the rear-axle frame, ``(L + a, b) = (3.78, 0.5)`` m."""

EXPECTED = dict(
    n_dr=61945,
    n_gps=4466,
    n_scans=7249,
    n_raw_scans=7230,
    n_detections=52974,
)
"""Counts stated in the dataset README, for checks."""


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


def acfr_steering(dr: DeadReckoning) -> tuple[DeadReckoning, tuple[float, float]]:
    """``dr`` with ACFR's recalibrated steering (module docstring) and the fitted
    ``(c_1, c_0)``, from the ASCII release's dead reckoning at the shared timestamps.

    Raises:
        DataFormatError: the two releases' steering is not one affine map of the other
            (a residual above 1e-3 rad).
    """
    ascii_dr = load_dead_reckoning("ascii")
    mat_ms = np.round(dr.times * 1000.0).astype(np.int64)
    ascii_ms = np.round(ascii_dr.times * 1000.0).astype(np.int64)
    shared, mat_index, ascii_index = np.intersect1d(mat_ms, ascii_ms, return_indices=True)
    design = np.stack([dr.steering[mat_index], np.ones(shared.size)], axis=1)
    coef, *_ = np.linalg.lstsq(design, ascii_dr.steering[ascii_index], rcond=None)
    residual = np.abs(design @ coef - ascii_dr.steering[ascii_index]).max()
    if residual > 1e-3:
        raise DataFormatError(find(DATASET, FOLDER, "acfr_ascii", "DRS.txt"), None,
                              f"steering is no affine map of the .mat steering (residual {residual:.2g} rad)")
    scale, offset = float(coef[0]), float(coef[1])
    return dataclasses.replace(dr, steering=scale * dr.steering + offset), (scale, offset)


def load_sequence(
    source: str = "detections",
    max_range: float = 30.0,
    max_steps: int | None = None,
    steering: str = "mat",
) -> VictoriaParkSequence:
    """Build the event sequence the filters consume (one step per laser scan).

    Args:
        source: ``"detections"``: ACFR's ``detectTreesI16`` detections on all 7249
            ``aa3_lsr2`` scans (T = 7249, to 1549.2 s; the papers' data), or
            ``"extractor"``: :func:`jaxslam.datasets.trees.extract_trees` run on the
            7230 raw ASCII scans (T = 7230, to 1545.2 s).
        max_range: keep observations with ``range < max_range`` [m] (the papers' 30 m).
        max_steps: keep only the first ``max_steps`` scans (GPS is cut to match).
        steering: ``"mat"`` (the ``.mat`` calibration, the papers' data) or ``"acfr"``
            (ACFR's recalibration, :func:`acfr_steering`).

    Returns:
        A :class:`VictoriaParkSequence` in the module's time base, ``.mat`` DR and GPS.
    """
    if source not in ("detections", "extractor"):
        raise ValueError(f"source must be 'detections' or 'extractor', got {source!r}")
    if steering not in ("mat", "acfr"):
        raise ValueError(f"steering must be 'mat' or 'acfr', got {steering!r}")
    if max_steps is not None and max_steps < 1:
        raise ValueError(f"max_steps must be at least 1, got {max_steps}")
    dr = load_dead_reckoning("mat")
    steering_fit = None
    if steering == "acfr":
        dr, steering_fit = acfr_steering(dr)
    gps = load_gps("mat")
    recovered: dict[str, int] = {}
    files = {
        "dead_reckoning": str(find(DATASET, FOLDER, "mat", "aa3_dr.npz")),
        "gps": str(find(DATASET, FOLDER, "mat", "aa3_gpsx.npz")),
    }
    if source == "detections":
        scan_times = load_scan_times()
        detections_file = find(DATASET, FOLDER, "rfs_slam_ascii", "measurements.dat")
        detections, lines = load_detections_file(detections_file)
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
        release="mat (OpenSLAM ufastslam / aa3_*.mat); "
        + (".mat steering calibration" if steering_fit is None else "ACFR's recalibrated steering"),
        steering=steering,
        steering_fit=steering_fit,
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
