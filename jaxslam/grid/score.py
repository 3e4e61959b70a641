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
subset). The filters pass weights :math:`w_b \in [0, 1]` in its place
(:func:`jaxslam.grid.filter.beam_weights`: 0 for unused beams, less than 1 for beams
beyond ``sensor.score_range``); a boolean mask is the special case of weights 0 and 1.

``kernel="gaussian3"`` replaces the bilinear evidence by GMapping's neighbourhood
form, the best :math:`o(c) \exp(-d^2/\sigma^2)` over the 3 x 3 cells around the end
point (:func:`gaussian_window_occupancy`): a wider basin for 9 cells per beam.

Maps are read through a :data:`~jaxslam.grid.map.CellReader` (a dense grid or a
particle's paged map) in a frame with ``resolution``, ``origin_x``, ``origin_y``;
cells outside the map read as unknown.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax import Array

from jaxslam.core import se2
from jaxslam.core.numerics import safe_divide
from jaxslam.grid.map import CellReader


def beam_points(ranges: Array, angles: Array) -> Array:
    """End points ``(B, 2)`` of the beams in the laser frame."""
    return ranges[:, None] * jnp.stack([jnp.cos(angles), jnp.sin(angles)], -1)


def bilinear_occupancy(read: CellReader, points: Array, frame, saturation) -> Array:
    """Occupancy in ``[0, 1]`` at world ``points (..., 2)``, bilinear between cell centres.

    Args:
        read: ``(cols, rows) -> int8 cells`` of one map (unknown outside it).
        points: ``(..., 2)`` world coordinates.
        frame: resolution and origin of the map (:class:`~jaxslam.grid.map.GridSpec` or a paged layout).
        saturation: log-odds step count at which a cell counts as fully occupied.
    """
    dtype = points.dtype
    u = cell_coords(points, frame) - 0.5
    base = jnp.floor(u)
    frac = u - base
    base = base.astype(jnp.int32)
    col0, row0 = base[..., 0], base[..., 1]
    sat = jnp.asarray(saturation, dtype)

    def cell(dc, dr):
        return jnp.clip(read(col0 + dc, row0 + dr).astype(dtype), 0, sat) / sat

    fx, fy = frac[..., 0], frac[..., 1]
    return (
        (1 - fx) * (1 - fy) * cell(0, 0)
        + fx * (1 - fy) * cell(1, 0)
        + (1 - fx) * fy * cell(0, 1)
        + fx * fy * cell(1, 1)
    )


def gaussian_window_occupancy(read: CellReader, points: Array, frame, saturation, sigma) -> Array:
    r"""GMapping-style neighbourhood evidence at world ``points (..., 2)``.

    :math:`\max_{c \in 3\times 3} o(c)\, k(\Delta x^2/\sigma^2)\, k(\Delta y^2/\sigma^2)`
    over the 3 x 3 cells around the end point :math:`e`, with
    :math:`(\Delta x, \Delta y) = e - \bar c` (:math:`\bar c` the cell centre) and
    :math:`k(x) = \max(1 - x/4, 0)^4 \approx e^{-x}`: GMapping's ``kernelSize = 1``
    window with its Gaussian of the distance, on cell centres instead of the
    per-cell mean hit point, and a polynomial in place of the exponential (which
    cost as much as the rest of the score on a CPU). Cells outside the map read as
    unknown.
    """
    dtype = points.dtype
    u = cell_coords(points, frame)
    cell = jnp.floor(u).astype(jnp.int32)
    col0 = cell[..., 0] - 1
    row0 = cell[..., 1] - 1
    sat = jnp.asarray(saturation, dtype)
    res = jnp.asarray(frame.resolution, dtype)
    scale = res * res / jnp.asarray(sigma, dtype) ** 2
    offs = jnp.arange(3, dtype=dtype) + 0.5
    # k(d^2) ~ k(dx^2) k(dy^2): 6 kernel values per beam, not 9.
    kx = _bump(((col0.astype(dtype)[..., None] + offs - u[..., 0:1]) ** 2) * scale)
    ky = _bump(((row0.astype(dtype)[..., None] + offs - u[..., 1:2]) ** 2) * scale)
    best = jnp.zeros(points.shape[:-1], dtype)
    for j in range(3):
        for i in range(3):
            v = jnp.clip(read(col0 + i, row0 + j).astype(dtype), 0, sat)
            best = jnp.maximum(best, v * (kx[..., i] * ky[..., j]))
    return best / sat


def gaussian_nearest_occupancy(read: CellReader, points: Array, frame, saturation, sigma) -> Array:
    r"""Like :func:`gaussian_window_occupancy` over the 2 x 2 cells whose centres
    surround the end point (the bilinear stencil): 4 cells per beam."""
    dtype = points.dtype
    u = cell_coords(points, frame) - 0.5
    base = jnp.floor(u)
    col0 = base[..., 0].astype(jnp.int32)
    row0 = base[..., 1].astype(jnp.int32)
    fx = u[..., 0] - base[..., 0]
    fy = u[..., 1] - base[..., 1]
    sat = jnp.asarray(saturation, dtype)
    res = jnp.asarray(frame.resolution, dtype)
    scale = res * res / jnp.asarray(sigma, dtype) ** 2
    kx = (_bump(fx * fx * scale), _bump((1 - fx) * (1 - fx) * scale))
    ky = (_bump(fy * fy * scale), _bump((1 - fy) * (1 - fy) * scale))
    best = jnp.zeros(points.shape[:-1], dtype)
    for j in range(2):
        for i in range(2):
            v = jnp.clip(read(col0 + i, row0 + j).astype(dtype), 0, sat)
            best = jnp.maximum(best, v * (kx[i] * ky[j]))
    return best / sat


def cell_coords(points: Array, frame) -> Array:
    """Continuous cell coordinates ``(col, row)`` of world points."""
    origin = jnp.asarray([frame.origin_x, frame.origin_y], points.dtype)
    return (points - origin) / jnp.asarray(frame.resolution, points.dtype)


KERNELS = ("bilinear", "gaussian2", "gaussian3")


def _bump(x: Array) -> Array:
    """``max(1 - x/4, 0)^4``: a compact stand-in for ``exp(-x)`` (equal slope and value
    at 0, within 0.06 everywhere) at a few multiplies instead of an exponential."""
    t = jnp.maximum(1.0 - 0.25 * x, 0.0)
    t = t * t
    return t * t


def evidence(read: CellReader, points: Array, frame, saturation, sigma, kernel: str = "bilinear") -> Array:
    """Map evidence in ``[0, 1]`` at world points with the chosen (static) kernel."""
    if kernel == "bilinear":
        return bilinear_occupancy(read, points, frame, saturation)
    if kernel == "gaussian3":
        return gaussian_window_occupancy(read, points, frame, saturation, sigma)
    if kernel == "gaussian2":
        return gaussian_nearest_occupancy(read, points, frame, saturation, sigma)
    raise ValueError(f"unknown score kernel {kernel!r}; choose one of {KERNELS}")


class ScoreModel(NamedTuple):
    """Traced settings of the score: occupancy saturation, kernel width, floor."""

    saturation: Array | float = 8.0
    sigma: Array | float = 0.05
    floor: Array | float = 0.018


def free_points(local_points: Array, frame) -> Array:
    """Points ``sqrt(2)`` cells before each end point, towards the sensor (GMapping's
    ``freeCellRatio``), in the laser frame."""
    dist = jnp.sqrt(jnp.sum(local_points * local_points, -1, keepdims=True))
    back = jnp.asarray(frame.resolution * 2**0.5, local_points.dtype)
    beyond = dist > back
    scale = jnp.where(beyond, 1.0 - safe_divide(back, dist, defined=beyond), 0.0)
    return local_points * scale


def endpoint_occupancy(
    read: CellReader,
    pose: Array,
    local_points: Array,
    laser_offset: Array,
    frame,
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
    value = evidence(read, world, frame, model.saturation, model.sigma, kernel)
    if free_check:
        before = se2.transform_points(sensor, free_points(local_points.astype(pose.dtype), frame))
        cell = jnp.floor(cell_coords(before, frame)).astype(jnp.int32)
        sat = jnp.asarray(model.saturation, value.dtype)
        occ_before = jnp.clip(read(cell[..., 0], cell[..., 1]).astype(value.dtype), 0, sat) / sat
        value = value * (1.0 - occ_before)
    return value


def scan_log_likelihood(
    read: CellReader,
    pose: Array,
    local_points: Array,
    mask: Array,
    laser_offset: Array,
    frame,
    model: ScoreModel,
    kernel: str = "bilinear",
    free_check: bool = False,
) -> tuple[Array, Array]:
    """``(log p(z | x, m), score)`` for one pose (see module docstring)."""
    occ = endpoint_occupancy(read, pose, local_points, laser_offset, frame, model, kernel, free_check)
    eps = jnp.asarray(model.floor, occ.dtype)
    log_lik = jnp.log(eps + (1 - eps) * occ)
    return jnp.sum(_weighted(mask, log_lik)), jnp.sum(_weighted(mask, occ))


def _weighted(weights: Array, values: Array) -> Array:
    """``w_b v_b``, exactly 0 where ``w_b`` is 0 or False (whatever ``v_b`` holds)."""
    w = jnp.asarray(weights)
    return jnp.where(w > 0, w.astype(values.dtype) * values, 0.0)


def make_score_fn(
    read: CellReader,
    local_points,
    mask,
    laser_offset,
    frame,
    model: ScoreModel,
    kernel: str = "bilinear",
    free_check: bool = False,
):
    """``poses (C, 3) -> scores (C,)`` for one particle's map (closure for the
    matchers): the matching score ``sum_b w_b o(e_b)`` of each pose (``mask``: boolean
    or weights), the second value of :func:`scan_log_likelihood`."""

    def one(pose: Array) -> Array:
        occ = endpoint_occupancy(read, pose, local_points, laser_offset, frame, model, kernel, free_check)
        return jnp.sum(_weighted(mask, occ))

    def score_fn(poses: Array) -> Array:
        return jax.vmap(one)(poses)

    return score_fn


__all__ = [
    "KERNELS",
    "ScoreModel",
    "beam_points",
    "cell_coords",
    "bilinear_occupancy",
    "endpoint_occupancy",
    "evidence",
    "free_points",
    "gaussian_window_occupancy",
    "make_score_fn",
    "scan_log_likelihood",
]
