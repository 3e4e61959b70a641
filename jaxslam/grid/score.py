r"""Scan-to-map likelihood by gathering cells at the beam end points.

For a pose :math:`x` the end point of beam :math:`b` is
:math:`e_b = s \oplus (r_b \cos a_b, r_b \sin a_b)` with the laser pose
:math:`s = x \oplus o_{laser}`. The map evidence at :math:`e_b` is the bilinear
interpolation, between the four surrounding cell centres, of the cell occupancy

.. math:: o(c) = \mathrm{clip}(\ell(c), 0, \ell_{sat}) / \ell_{sat} \in [0, 1]

(free and unknown cells give 0, a cell that has been hit ``l_sat / l_occ`` times
gives 1), the smoothed-map model of Kohlbrecher et al. 2011 (Hector SLAM). It plays
the part of GMapping's neighbourhood score :math:`\exp(-d^2/\sigma)` with its
``kernelSize = 1`` window, from 4 gathers instead of 18, and it is differentiable
almost everywhere (for the gradient refinement).

* score (maximised by the scan matchers): :math:`s(x) = \sum_b m_b\, o(e_b)`
* log-likelihood (the particle weight): :math:`\log p(z|x, m) = \sum_b m_b
  \log(\epsilon + (1 - \epsilon)\, o(e_b))`, with :math:`\log\epsilon` the
  per-beam penalty of a beam that finds no wall (GMapping's ``nullLikelihood``).

:math:`m_b` masks the beams used (valid, within the usable range, in the matching
subset).

``kernel="gaussian3"`` replaces the bilinear evidence by GMapping's neighbourhood
form, the best :math:`o(c) \exp(-d^2/\sigma^2)` over the 3 x 3 cells around the end
point (:func:`gaussian_window_occupancy`): a wider basin for 9 cells per beam.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax import Array

from jaxslam.core import se2
from jaxslam.grid.map import GridSpec


def beam_points(ranges: Array, angles: Array) -> Array:
    """End points ``(B, 2)`` of the beams in the laser frame."""
    return ranges[:, None] * jnp.stack([jnp.cos(angles), jnp.sin(angles)], -1)


def bilinear_occupancy(grid: Array, points: Array, spec: GridSpec, saturation) -> Array:
    """Occupancy in ``[0, 1]`` at world ``points (..., 2)``, bilinear between cell centres.

    Args:
        grid: ``(H, W)`` int8 quantised log-odds.
        points: ``(..., 2)`` world coordinates.
        spec: grid geometry.
        saturation: log-odds step count at which a cell counts as fully occupied.
    """
    dtype = points.dtype
    res = jnp.asarray(spec.resolution, dtype)
    origin = jnp.asarray([spec.origin_x, spec.origin_y], dtype)
    u = (points - origin) / res - 0.5
    base = jnp.floor(u)
    frac = u - base
    base = base.astype(jnp.int32)
    col0, row0 = base[..., 0], base[..., 1]
    flat = grid.reshape(-1)
    h, w = spec.height, spec.width
    sat = jnp.asarray(saturation, dtype)

    def cell(dc, dr):
        c = col0 + dc
        r = row0 + dr
        inside = (c >= 0) & (c < w) & (r >= 0) & (r < h)
        idx = jnp.where(inside, r * w + c, 0)
        v = flat[idx].astype(dtype)
        return jnp.where(inside, jnp.clip(v, 0, sat) / sat, 0.0)

    fx, fy = frac[..., 0], frac[..., 1]
    return (
        (1 - fx) * (1 - fy) * cell(0, 0)
        + fx * (1 - fy) * cell(1, 0)
        + (1 - fx) * fy * cell(0, 1)
        + fx * fy * cell(1, 1)
    )


def gaussian_window_occupancy(grid: Array, points: Array, spec: GridSpec, saturation, sigma) -> Array:
    r"""GMapping-style neighbourhood evidence at world ``points (..., 2)``.

    :math:`\max_{c \in 3\times 3} o(c)\, k(\Delta x^2/\sigma^2)\, k(\Delta y^2/\sigma^2)`
    over the 3 x 3 cells around the end point :math:`e`, with
    :math:`(\Delta x, \Delta y) = e - \bar c` (:math:`\bar c` the cell centre) and
    :math:`k(x) = \max(1 - x/4, 0)^4 \approx e^{-x}`: GMapping's ``kernelSize = 1``
    window with its Gaussian of the distance, on cell centres instead of the
    per-cell mean hit point, and a polynomial in place of the exponential (which
    cost as much as the rest of the score on a CPU).
    """
    dtype = points.dtype
    res = jnp.asarray(spec.resolution, dtype)
    origin = jnp.asarray([spec.origin_x, spec.origin_y], dtype)
    u = (points - origin) / res
    cell = jnp.floor(u).astype(jnp.int32)
    # Window clamped into the grid; its cell centres are taken where it really is.
    col0 = jnp.clip(cell[..., 0] - 1, 0, spec.width - 3)
    row0 = jnp.clip(cell[..., 1] - 1, 0, spec.height - 3)
    sat = jnp.asarray(saturation, dtype)
    scale = res * res / jnp.asarray(sigma, dtype) ** 2
    offs = jnp.arange(3, dtype=dtype) + 0.5
    # k(d^2) ~ k(dx^2) k(dy^2): 6 kernel values per beam, not 9.
    kx = _bump(((col0.astype(dtype)[..., None] + offs - u[..., 0:1]) ** 2) * scale)
    ky = _bump(((row0.astype(dtype)[..., None] + offs - u[..., 1:2]) ** 2) * scale)
    flat = grid.reshape(-1)
    base = row0 * spec.width + col0
    best = jnp.zeros(points.shape[:-1], dtype)
    for j in range(3):
        for i in range(3):
            v = jnp.clip(flat[base + (j * spec.width + i)].astype(dtype), 0, sat)
            best = jnp.maximum(best, v * (kx[..., i] * ky[..., j]))
    return best / sat


def gaussian_nearest_occupancy(grid: Array, points: Array, spec: GridSpec, saturation, sigma) -> Array:
    r"""Like :func:`gaussian_window_occupancy` over the 2 x 2 cells whose centres
    surround the end point (the bilinear stencil): 4 cells per beam."""
    dtype = points.dtype
    res = jnp.asarray(spec.resolution, dtype)
    origin = jnp.asarray([spec.origin_x, spec.origin_y], dtype)
    u = (points - origin) / res - 0.5
    base = jnp.floor(u)
    frac = u - base
    base = base.astype(jnp.int32)
    col0 = jnp.clip(base[..., 0], 0, spec.width - 2)
    row0 = jnp.clip(base[..., 1], 0, spec.height - 2)
    fx = u[..., 0] - col0.astype(dtype)
    fy = u[..., 1] - row0.astype(dtype)
    del frac
    sat = jnp.asarray(saturation, dtype)
    scale = res * res / jnp.asarray(sigma, dtype) ** 2
    kx = (_bump(fx * fx * scale), _bump((1 - fx) * (1 - fx) * scale))
    ky = (_bump(fy * fy * scale), _bump((1 - fy) * (1 - fy) * scale))
    flat = grid.reshape(-1)
    start = row0 * spec.width + col0
    best = jnp.zeros(points.shape[:-1], dtype)
    for j in range(2):
        for i in range(2):
            v = jnp.clip(flat[start + (j * spec.width + i)].astype(dtype), 0, sat)
            best = jnp.maximum(best, v * (kx[i] * ky[j]))
    return best / sat


KERNELS = ("bilinear", "gaussian2", "gaussian3")


def _bump(x: Array) -> Array:
    """``max(1 - x/4, 0)^4``: a compact stand-in for ``exp(-x)`` (equal slope and value
    at 0, within 0.06 everywhere) at a few multiplies instead of an exponential."""
    t = jnp.maximum(1.0 - 0.25 * x, 0.0)
    t = t * t
    return t * t


def evidence(grid: Array, points: Array, spec: GridSpec, saturation, sigma, kernel: str = "bilinear") -> Array:
    """Map evidence in ``[0, 1]`` at world points with the chosen (static) kernel."""
    if kernel == "bilinear":
        return bilinear_occupancy(grid, points, spec, saturation)
    if kernel == "gaussian3":
        return gaussian_window_occupancy(grid, points, spec, saturation, sigma)
    if kernel == "gaussian2":
        return gaussian_nearest_occupancy(grid, points, spec, saturation, sigma)
    raise ValueError(f"unknown score kernel {kernel!r}; choose one of {KERNELS}")


class ScoreModel(NamedTuple):
    """Traced settings of the score: occupancy saturation, kernel width, floor."""

    saturation: Array | float = 8.0
    sigma: Array | float = 0.05
    floor: Array | float = 0.018


def free_points(local_points: Array, spec: GridSpec) -> Array:
    """Points ``sqrt(2)`` cells before each end point, towards the sensor (GMapping's
    ``freeCellRatio``), in the laser frame."""
    dist = jnp.sqrt(jnp.sum(local_points * local_points, -1, keepdims=True))
    back = jnp.asarray(spec.resolution * 2**0.5, local_points.dtype)
    scale = jnp.where(dist > back, 1.0 - back / jnp.where(dist > back, dist, 1.0), 0.0)
    return local_points * scale


def endpoint_occupancy(
    grid: Array,
    pose: Array,
    local_points: Array,
    laser_offset: Array,
    spec: GridSpec,
    model: ScoreModel,
    kernel: str = "bilinear",
    free_check: bool = False,
) -> Array:
    """Evidence ``(B,)`` at the beam end points for a robot ``pose (3,)``.

    With ``free_check`` (GMapping's test that the cell before the hit is free) the
    evidence is scaled by ``1 - o(c_free)`` for the cell ``sqrt(2)`` cells before the
    end point: a beam cannot end on a wall it would have had to pass through, which
    keeps scans off the far side of thin walls.
    """
    sensor = se2.compose(pose, laser_offset.astype(pose.dtype))
    world = se2.transform_points(sensor, local_points.astype(pose.dtype))
    value = evidence(grid, world, spec, model.saturation, model.sigma, kernel)
    if free_check:
        before = se2.transform_points(sensor, free_points(local_points.astype(pose.dtype), spec))
        cell = jnp.floor(
            (before - jnp.asarray([spec.origin_x, spec.origin_y], pose.dtype)) / jnp.asarray(spec.resolution, pose.dtype)
        ).astype(jnp.int32)
        inside = (cell[..., 0] >= 0) & (cell[..., 0] < spec.width) & (cell[..., 1] >= 0) & (cell[..., 1] < spec.height)
        idx = jnp.where(inside, cell[..., 1] * spec.width + cell[..., 0], 0)
        sat = jnp.asarray(model.saturation, value.dtype)
        occ_before = jnp.where(inside, jnp.clip(grid.reshape(-1)[idx].astype(value.dtype), 0, sat) / sat, 0.0)
        value = value * (1.0 - occ_before)
    return value


def scan_score(
    grid: Array,
    pose: Array,
    local_points: Array,
    mask: Array,
    laser_offset: Array,
    spec: GridSpec,
    model: ScoreModel,
    kernel: str = "bilinear",
    free_check: bool = False,
) -> Array:
    """Matching score ``sum_b m_b o(e_b)`` for one pose."""
    occ = endpoint_occupancy(grid, pose, local_points, laser_offset, spec, model, kernel, free_check)
    return jnp.sum(jnp.where(mask, occ, 0.0))


def scan_log_likelihood(
    grid: Array,
    pose: Array,
    local_points: Array,
    mask: Array,
    laser_offset: Array,
    spec: GridSpec,
    model: ScoreModel,
    kernel: str = "bilinear",
    free_check: bool = False,
) -> tuple[Array, Array]:
    """``(log p(z | x, m), score)`` for one pose (see module docstring)."""
    occ = endpoint_occupancy(grid, pose, local_points, laser_offset, spec, model, kernel, free_check)
    eps = jnp.asarray(model.floor, occ.dtype)
    log_lik = jnp.log(eps + (1 - eps) * occ)
    return jnp.sum(jnp.where(mask, log_lik, 0.0)), jnp.sum(jnp.where(mask, occ, 0.0))


def make_score_fn(
    grid,
    local_points,
    mask,
    laser_offset,
    spec: GridSpec,
    model: ScoreModel,
    kernel: str = "bilinear",
    free_check: bool = False,
):
    """``poses (C, 3) -> scores (C,)`` for one particle's grid (closure for the matchers)."""

    def score_fn(poses: Array) -> Array:
        return jax.vmap(
            lambda p: scan_score(grid, p, local_points, mask, laser_offset, spec, model, kernel, free_check)
        )(poses)

    return score_fn


__all__ = [
    "KERNELS",
    "ScoreModel",
    "beam_points",
    "bilinear_occupancy",
    "endpoint_occupancy",
    "evidence",
    "free_points",
    "gaussian_window_occupancy",
    "make_score_fn",
    "scan_log_likelihood",
    "scan_score",
]
