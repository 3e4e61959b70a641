r"""The likelihood field of a known map (Thrun, Burgard & Fox, *Probabilistic Robotics*, 6.4).

Host side, once per map: the Euclidean distance from every cell centre to the
nearest occupied cell centre (SciPy's exact ``distance_transform_edt``), in metres,
capped at ``max_distance``; the cells that are free, from which global localization
and random injection draw poses.

In a kernel, for one particle: a beam end point :math:`p` in the world is taken into
the map frame, :math:`q = R(-\psi)(p - o)` (origin :math:`o`, yaw :math:`\psi`), and
read at cell :math:`(\lfloor q_y / r\rfloor, \lfloor q_x / r\rfloor)`; outside the map
the distance is ``max_distance`` (as in AMCL's ``map_calc_occ_dist`` lookups). The
beam-endpoint model of Table 6.3 then gives each hit

.. math::
    p(z^k \mid x, m) = z_{hit}\,\mathcal N(d_k; 0, \sigma_{hit}^2) + z_{rand} / z_{max},

and readings at the range limit are left out.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax.numpy as jnp
import numpy as np
from jax import Array
from scipy.ndimage import distance_transform_edt

from jaxslam.grid.mapfile import OccupancyMap


class LikelihoodField(NamedTuple):
    """A map's distance field, ready for a kernel (all leaves arrays, traced).

    Attributes:
        distance: ``(H, W)`` metres from each cell centre to the nearest occupied one,
            at most ``max_distance``.
        origin: ``(3,)`` ``(x, y, yaw)`` of cell (0, 0)'s corner.
        resolution: ``()`` metres per cell.
        max_distance: ``()`` the cap, also the distance read outside the map.
    """

    distance: Array
    origin: Array
    resolution: Array
    max_distance: Array


def distance_to_occupied(occupied: np.ndarray, resolution: float, max_distance: float) -> np.ndarray:
    """``(H, W)`` float64 metres from each cell centre to the nearest occupied cell centre,
    capped at ``max_distance`` (everywhere ``max_distance`` when nothing is occupied)."""
    occupied = np.asarray(occupied, bool)
    if not occupied.any():
        return np.full(occupied.shape, float(max_distance))
    distance = distance_transform_edt(~occupied) * float(resolution)
    return np.minimum(distance, float(max_distance))


def likelihood_field(grid: OccupancyMap, max_distance: float = 2.0, dtype=np.float32) -> LikelihoodField:
    """The :class:`LikelihoodField` of a map (occupied: AMCL's value 100)."""
    if not max_distance > 0:
        raise ValueError(f"max_distance must be positive, got {max_distance}")
    distance = distance_to_occupied(grid.occupied, grid.resolution, max_distance)
    return LikelihoodField(
        distance=jnp.asarray(distance, dtype), origin=jnp.asarray(grid.origin, dtype),
        resolution=jnp.asarray(grid.resolution, dtype), max_distance=jnp.asarray(max_distance, dtype),
    )


def free_cell_centres(grid: OccupancyMap, max_cells: int | None = None, seed: int = 0) -> np.ndarray:
    """``(F, 2)`` world centres of the free cells (an even random subset of at most
    ``max_cells`` of them; draws then add a uniform offset within the cell)."""
    rows, cols = np.nonzero(grid.free)
    if max_cells is not None and rows.size > max_cells:
        keep = np.sort(np.random.default_rng(seed).choice(rows.size, max_cells, replace=False))
        rows, cols = rows[keep], cols[keep]
    return grid.cell_centres(rows, cols)


def distance_at(field: LikelihoodField, points: Array) -> Array:
    """Distance to the nearest obstacle at world points ``(..., 2)`` (nearest cell)."""
    dtype = field.distance.dtype
    points = points.astype(dtype)
    ox, oy, yaw = field.origin[0], field.origin[1], field.origin[2]
    c, s = jnp.cos(yaw), jnp.sin(yaw)
    dx, dy = points[..., 0] - ox, points[..., 1] - oy
    qx, qy = c * dx + s * dy, -s * dx + c * dy
    col = jnp.floor(qx / field.resolution)
    row = jnp.floor(qy / field.resolution)
    height, width = field.distance.shape
    inside = (col >= 0) & (col < width) & (row >= 0) & (row < height)
    flat = jnp.where(inside, row * width + col, 0).astype(jnp.int32)
    return jnp.where(inside, field.distance.reshape(-1)[flat], field.max_distance)


def beam_log_likelihood(distance: Array, sigma_hit, z_hit, z_rand, max_range) -> Array:
    """``log(z_hit N(d; 0, sigma_hit^2) + z_rand / max_range)`` per beam (Table 6.3)."""
    dtype = distance.dtype
    sigma = jnp.asarray(sigma_hit, dtype)
    gauss = jnp.exp(-0.5 * jnp.square(distance / sigma)) / (sigma * jnp.asarray(math.sqrt(2.0 * math.pi), dtype))
    return jnp.log(jnp.asarray(z_hit, dtype) * gauss + jnp.asarray(z_rand, dtype) / jnp.asarray(max_range, dtype))


__all__ = [
    "LikelihoodField",
    "beam_log_likelihood",
    "distance_at",
    "distance_to_occupied",
    "free_cell_centres",
    "likelihood_field",
]
