r"""Laser-corrected odometry: the heading change between consecutive scans from the
scans themselves, so that keyframe selection and the filters' motion input see
rotations that the wheel odometry misses (a robot turning in a doorway).

For scans :math:`t-1, t` with wheel odometry :math:`o_{t-1}, o_t` and laser offset
:math:`l`, the odometry's laser increment is
:math:`v = (o_{t-1} \oplus l)^{-1} \oplus (o_t \oplus l)`. The hits of scan
:math:`t-1` (laser frame, within ``radius``) are drawn into a local grid of cell
``resolution`` and blurred with a separable kernel :math:`[1, 2, 3, 2, 1]/3`
(a basin of about two cells); the hits :math:`q_b` of scan :math:`t` are scored at

.. math:: s(\phi) = \frac{1}{n}\sum_b G\big(R(\phi)\, q_b + t_v\big),
   \qquad \phi \in \theta_v + [-\Phi, \Phi]

(nearest cell, :math:`G` the blurred grid, translation from the odometry) on a
coarse grid of headings and then on a fine one around the best. The laser heading
change becomes :math:`\hat\phi` when the match is trusted -- the best score
reaches ``min_score`` and beats the odometry's own heading by ``min_gain`` -- and
stays :math:`\theta_v` otherwise (a featureless or changed scene falls back to the
wheels). Translation stays the odometry's: the failure this addresses is rotation,
and a scan-to-scan translation estimate in a corridor is the weakest part of such
a match. The corrected increments are composed from :math:`o_0` into new odometry
poses; every pair is independent, so all pairs are matched at once in chunks
(``vmap``), in one jitted function.

:func:`laser_corrected_log` returns a copy of a :class:`~jaxslam.datasets.carmen.CarmenLog` with these poses
as ``odom_poses`` (and the counts in ``stats``), for
:func:`jaxslam.grid.experiment.run_grid_slam` or any other consumer of odometry.

Status: opt-in, not used by ``run_grid_slam``. A scan matched against the previous
scan alone errs less than the wheels in heading on average, but a single false match
(a corridor, a changed scene) can turn the increment by tens of degrees, which no
later scan takes back. Per-scan tracking (:mod:`jaxslam.grid.tracking`) addresses the
same missed rotations by matching each scan against the best particle's map instead
of the previous scan.
"""

from __future__ import annotations

import dataclasses
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from jaxslam.datasets.carmen import CarmenLog
from jaxslam.datasets.geometry import se2_between, se2_compose, se2_inverse, wrap_angle

__all__ = ["LaserOdometryConfig", "laser_corrected_log", "laser_heading_increments"]


@dataclasses.dataclass(frozen=True)
class LaserOdometryConfig:
    """Settings of the scan-to-scan heading search.

    Attributes:
        radius: hits farther than this (m) are not used.
        resolution: cell size of the local grid (m).
        max_rotation: the search covers the odometry heading change +- this (rad).
        coarse_step, fine_step: heading steps of the two searches (rad).
        min_score: smallest mean blurred occupancy at the best heading to trust it.
        min_gain: the best heading must beat the odometry's score by this much.
        min_points: fewer hits than this in either scan: keep the odometry.
        chunk: pairs matched per vmapped batch.
    """

    radius: float = 10.0
    resolution: float = 0.05
    max_rotation: float = 0.6
    coarse_step: float = 0.02
    fine_step: float = 0.002
    min_score: float = 0.3
    min_gain: float = 0.02
    min_points: int = 30
    chunk: int = 64


_BLUR = np.array([1.0, 2.0, 3.0, 2.0, 1.0]) / 3.0


def _points(ranges: np.ndarray, valid: np.ndarray, angles: np.ndarray, radius: float):
    use = valid & np.isfinite(ranges) & (ranges > 0) & (ranges < radius)
    r = np.where(use, ranges, 0.0)
    return np.stack([r * np.cos(angles), r * np.sin(angles)], -1).astype(np.float32), use


@partial(jax.jit, static_argnames=("cells", "resolution", "coarse", "fine", "coarse_step", "fine_step"))
def _match_chunk(ref_pts, ref_use, cur_pts, cur_use, inc, *, cells, resolution, coarse, fine, coarse_step, fine_step):
    """Best heading for a batch of pairs: returns ``(phi, score_best, score_odom)``."""
    half = cells // 2
    blur = jnp.asarray(_BLUR, jnp.float32)

    def one(rp, ru, cp, cu, v):
        idx = jnp.floor(rp / resolution).astype(jnp.int32) + half
        inside = ru & jnp.all((idx >= 0) & (idx < cells), -1)
        grid = jnp.zeros((cells, cells), jnp.float32)
        grid = grid.at[jnp.where(inside, idx[:, 1], 0), jnp.where(inside, idx[:, 0], 0)].max(
            inside.astype(jnp.float32)
        )
        for axis in (0, 1):
            padded = jnp.pad(grid, [(2, 2) if a == axis else (0, 0) for a in range(2)])
            grid = sum(
                blur[k] * jax.lax.slice_in_dim(padded, k, k + cells, axis=axis) for k in range(5)
            )
        grid = jnp.minimum(grid, 1.0)
        n = jnp.maximum(jnp.sum(cu), 1).astype(jnp.float32)

        def score(phi):
            c, s = jnp.cos(phi), jnp.sin(phi)
            x = c * cp[:, 0] - s * cp[:, 1] + v[0]
            y = s * cp[:, 0] + c * cp[:, 1] + v[1]
            i = jnp.floor(x / resolution).astype(jnp.int32) + half
            j = jnp.floor(y / resolution).astype(jnp.int32) + half
            ok = cu & (i >= 0) & (i < cells) & (j >= 0) & (j < cells)
            return jnp.sum(jnp.where(ok, grid[jnp.clip(j, 0, cells - 1), jnp.clip(i, 0, cells - 1)], 0.0)) / n

        phis = v[2] + coarse_step * (jnp.arange(coarse, dtype=jnp.float32) - (coarse - 1) / 2)
        scores = jax.vmap(score)(phis)
        best = phis[jnp.argmax(scores)]
        phis = best + fine_step * (jnp.arange(fine, dtype=jnp.float32) - (fine - 1) / 2)
        scores = jax.vmap(score)(phis)
        k = jnp.argmax(scores)
        return phis[k], scores[k], score(v[2])

    return jax.vmap(one)(ref_pts, ref_use, cur_pts, cur_use, inc)


def laser_heading_increments(
    log: CarmenLog, config: LaserOdometryConfig = LaserOdometryConfig()
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Corrected robot-frame increments ``(S-1, 3)`` between consecutive scans.

    Returns:
        ``(increments, info)`` with ``info``: ``accepted (S-1,)`` bool (laser heading
        used), ``score``, ``odom_score`` (mean blurred occupancy at the best and at
        the odometry heading), ``rotation_change`` (rad, laser minus odometry
        heading change; 0 where not accepted).
    """
    odom = np.asarray(log.odom_poses, np.float64)
    offset = np.asarray(log.laser_offset, np.float64)
    laser = se2_compose(odom, np.broadcast_to(offset, odom.shape))
    inc = se2_between(laser[:-1], laser[1:])  # laser-frame increments
    angles = np.broadcast_to(np.asarray(log.beam_angles(), np.float64), log.ranges.shape)
    pts, use = _points(np.asarray(log.ranges, np.float64), np.asarray(log.valid), angles, config.radius)
    cells = int(2 * np.ceil(config.radius / config.resolution)) + 8
    coarse = int(2 * round(config.max_rotation / config.coarse_step)) + 1
    fine = int(2 * round(config.coarse_step / config.fine_step)) + 1
    n = inc.shape[0]
    phi = np.empty(n)
    best = np.empty(n)
    base = np.empty(n)
    for lo in range(0, n, config.chunk):
        hi = min(lo + config.chunk, n)
        pad = config.chunk - (hi - lo)
        sel = np.concatenate([np.arange(lo, hi), np.full(pad, hi - 1)]).astype(int)
        out = _match_chunk(
            jnp.asarray(pts[sel]), jnp.asarray(use[sel]), jnp.asarray(pts[sel + 1]), jnp.asarray(use[sel + 1]),
            jnp.asarray(inc[sel], jnp.float32),
            cells=cells, resolution=float(config.resolution), coarse=coarse, fine=fine,
            coarse_step=float(config.coarse_step), fine_step=float(config.fine_step),
        )
        phi[lo:hi], best[lo:hi], base[lo:hi] = (np.asarray(o, np.float64)[: hi - lo] for o in out)
    enough = (use[:-1].sum(1) >= config.min_points) & (use[1:].sum(1) >= config.min_points)
    accepted = enough & (best >= config.min_score) & (best >= base + config.min_gain)
    corrected = inc.copy()
    corrected[:, 2] = np.where(accepted, wrap_angle(phi), inc[:, 2])
    # Back to robot-frame increments: l (+) v' (+) l^-1.
    robot = se2_compose(se2_compose(np.broadcast_to(offset, corrected.shape), corrected),
                        np.broadcast_to(se2_inverse(offset), corrected.shape))
    info = {
        "accepted": accepted,
        "score": best,
        "odom_score": base,
        "rotation_change": np.where(accepted, wrap_angle(phi - inc[:, 2]), 0.0),
    }
    return robot, info


def laser_corrected_log(log: CarmenLog, config: LaserOdometryConfig = LaserOdometryConfig()) -> CarmenLog:
    """A copy of ``log`` whose ``odom_poses`` use the laser heading increments.

    ``stats`` gains ``laser_odometry_accepted`` (pairs whose heading came from the
    laser) and ``laser_odometry_pairs``.
    """
    increments, info = laser_heading_increments(log, config)
    poses = np.empty_like(np.asarray(log.odom_poses, np.float64))
    poses[0] = log.odom_poses[0]
    for i, u in enumerate(increments):
        poses[i + 1] = se2_compose(poses[i], u)
    stats = dict(log.stats)
    stats["laser_odometry_accepted"] = int(info["accepted"].sum())
    stats["laser_odometry_pairs"] = int(info["accepted"].shape[0])
    return dataclasses.replace(log, odom_poses=poses, stats=stats)
