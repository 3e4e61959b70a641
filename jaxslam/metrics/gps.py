"""Trajectory error against GPS (host-side NumPy).

Outdoor datasets such as Victoria Park have no ground-truth poses, only a GPS that
drops out and jumps (ACFR's ``info.txt``: "the gps unit was failing, it is possible to
see jumps and regions without gps data"). :func:`gps_error` measures an estimated
trajectory against it in three steps:

1. **Jump rejection** (:func:`gps_jump_mask`), which looks at the GPS alone, never at
   the estimate: walking through the fixes in time order, a fix is kept when it lies
   within ``max_speed * dt + noise_m`` of the last *kept* fix, where ``dt`` is the time
   between them; otherwise it is skipped. A spike is dropped entirely; after a step
   (the receiver settles on a new offset) the new track is taken up again once the
   allowance has grown past the step, so a dropout never removes the rest of the run.
   The defaults (10 m/s, 1 m) sit above the car's top speed in the DR log (6.6 m/s)
   and the GPS scatter at rest (about 0.1 m).
2. **Interpolation**: the estimate ``(x, y)`` is linearly interpolated at the kept GPS
   times inside the estimate's time span; fixes outside it are skipped.
3. **Rigid alignment** (Umeyama 1991 without scale, i.e. Kabsch in 2-D): the rotation
   ``R`` and translation ``t`` that minimise ``sum_k |R p_k + t - g_k|^2`` over the
   estimate points ``p_k`` and GPS fixes ``g_k``. By default it is fitted on the
   **whole run** (the absolute-trajectory-error convention of Sturm et al. 2012): a
   filter's frame is fixed only by its initial pose, and Victoria Park starts with the
   car standing still for ~20 s, where the GPS says nothing about heading, so a fit on
   the first seconds would turn GPS noise into a heading error that grows with
   distance. ``align_seconds`` fits on the first seconds instead (a drift measure).

The errors ``|R p_k + t - g_k|`` give the mean, RMS and maximum. The estimate and the
GPS antenna are different points of the car (the Victoria Park pose is the laser's);
the lever arm adds up to a few metres, the same for every filter.
"""

from __future__ import annotations

from typing import Any

import numpy as np


def gps_jump_mask(
    times: np.ndarray, xy: np.ndarray, max_speed: float = 10.0, noise_m: float = 1.0
) -> np.ndarray:
    """Which GPS fixes to keep (True) under the speed rule in the module docstring.

    Args:
        times: (G,) increasing fix times [s].
        xy: (G, 2) fix positions [m].
        max_speed: the fastest the vehicle can move [m/s].
        noise_m: allowance for GPS scatter [m].
    """
    times = np.asarray(times, dtype=np.float64)
    xy = np.asarray(xy, dtype=np.float64)
    keep = np.zeros(times.shape[0], dtype=bool)
    if times.size == 0:
        return keep
    keep[0] = True
    last = 0
    for k in range(1, times.size):
        reach = max_speed * (times[k] - times[last]) + noise_m
        if np.hypot(*(xy[k] - xy[last])) <= reach:
            keep[k] = True
            last = k
    return keep


def align_rigid_2d(
    source: np.ndarray, target: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares rotation and translation taking ``source`` onto ``target``.

    Minimises ``sum_k |R source_k + t - target_k|^2`` over rotations ``R`` (det +1) and
    translations ``t`` (Umeyama 1991, without scale).

    Args:
        source: (N, 2) points.
        target: (N, 2) points, N >= 2 and not all coincident.

    Returns:
        ``(R (2, 2), t (2,))``.
    """
    source = np.asarray(source, dtype=np.float64)
    target = np.asarray(target, dtype=np.float64)
    if source.shape != target.shape or source.ndim != 2 or source.shape[1] != 2:
        raise ValueError(f"expected two (N, 2) arrays, got {source.shape} and {target.shape}")
    if source.shape[0] < 2:
        raise ValueError("need at least 2 point pairs to fit a rotation")
    source_mean = source.mean(axis=0)
    target_mean = target.mean(axis=0)
    cross = (target - target_mean).T @ (source - source_mean)
    u, _, vt = np.linalg.svd(cross)
    flip = np.diag([1.0, np.sign(np.linalg.det(u @ vt)) or 1.0])
    rotation = u @ flip @ vt
    translation = target_mean - rotation @ source_mean
    return rotation, translation


def gps_error(
    est_times: np.ndarray,
    est_xy: np.ndarray,
    gps_times: np.ndarray,
    gps_xy: np.ndarray,
    *,
    max_speed: float = 10.0,
    noise_m: float = 1.0,
    align_seconds: float | None = None,
) -> dict[str, Any]:
    """Error of an estimated trajectory against GPS after rigid alignment.

    Args:
        est_times: (T,) increasing times of the estimate [s], same base as the GPS.
        est_xy: (T, >=2) estimated poses; columns 0 and 1 are x, y [m].
        gps_times: (G,) fix times [s].
        gps_xy: (G, 2) fixes [m].
        max_speed: jump rule speed [m/s] (see :func:`gps_jump_mask`).
        noise_m: jump rule allowance [m].
        align_seconds: fit the alignment on the fixes of the first ``align_seconds`` of
            the estimate only (None: the whole run).

    Returns:
        dict with ``gps_mean_m``, ``gps_rms_m``, ``gps_max_m``, ``n_used``,
        ``n_skipped`` (= ``n_skipped_jumps`` + ``n_skipped_outside``), ``n_aligned``,
        ``rotation`` (2, 2), ``translation`` (2,), ``rotation_rad``, and per fix
        ``used`` (G,) bool and ``errors_m`` (G,) (NaN where not used).
    """
    est_times = np.asarray(est_times, dtype=np.float64)
    est_xy = np.asarray(est_xy, dtype=np.float64)[:, :2]
    gps_times = np.asarray(gps_times, dtype=np.float64)
    gps_xy = np.asarray(gps_xy, dtype=np.float64)
    if est_times.ndim != 1 or est_xy.shape[0] != est_times.shape[0]:
        raise ValueError(f"est_times {est_times.shape} and est_xy {est_xy.shape} do not match")
    if np.any(np.diff(est_times) < 0):
        raise ValueError("est_times must not decrease")
    if not np.all(np.isfinite(est_xy)):
        raise ValueError("the estimate has non-finite positions")

    not_jump = gps_jump_mask(gps_times, gps_xy, max_speed, noise_m)
    inside = (gps_times >= est_times[0]) & (gps_times <= est_times[-1])
    used = not_jump & inside
    if used.sum() < 2:
        raise ValueError(f"only {int(used.sum())} GPS fixes fall inside the estimate's time span")
    points = np.stack(
        [np.interp(gps_times[used], est_times, est_xy[:, i]) for i in range(2)], axis=1
    )
    fixes = gps_xy[used]
    fit = np.ones(points.shape[0], dtype=bool)
    if align_seconds is not None:
        fit = gps_times[used] <= est_times[0] + align_seconds
    rotation, translation = align_rigid_2d(points[fit], fixes[fit])
    residuals = np.linalg.norm(points @ rotation.T + translation - fixes, axis=1)
    errors = np.full(gps_times.shape[0], np.nan)
    errors[used] = residuals
    return dict(
        gps_mean_m=float(residuals.mean()),
        gps_rms_m=float(np.sqrt(np.mean(residuals**2))),
        gps_max_m=float(residuals.max()),
        n_used=int(used.sum()),
        n_skipped=int((~used).sum()),
        n_skipped_jumps=int((~not_jump & inside).sum()),
        n_skipped_outside=int((~inside).sum()),
        n_aligned=int(fit.sum()),
        rotation=rotation,
        translation=translation,
        rotation_rad=float(np.arctan2(rotation[1, 0], rotation[0, 0])),
        used=used,
        errors_m=errors,
    )
