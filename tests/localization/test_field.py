"""The likelihood field against brute force, and the beam-endpoint model."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxslam.grid.mapfile import OccupancyMap
from jaxslam.localization.field import (
    beam_log_likelihood,
    distance_at,
    distance_to_occupied,
    free_cell_centres,
    likelihood_field,
)


def _brute_force(occupied, resolution, cap):
    rows, cols = np.nonzero(occupied)
    out = np.full(occupied.shape, cap)
    for r in range(occupied.shape[0]):
        for c in range(occupied.shape[1]):
            if rows.size:
                out[r, c] = min(cap, resolution * np.sqrt(np.min((rows - r) ** 2 + (cols - c) ** 2)))
    return out


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**31 - 1), st.integers(1, 12), st.integers(1, 15), st.floats(0.02, 0.5),
       st.floats(0.05, 3.0), st.floats(0.0, 0.4))
def test_distance_field_is_the_nearest_obstacle_distance(seed, h, w, resolution, cap, density):
    occupied = np.random.default_rng(seed).random((h, w)) < density
    np.testing.assert_allclose(distance_to_occupied(occupied, resolution, cap),
                               _brute_force(occupied, resolution, cap), rtol=1e-12, atol=1e-12)


def _grid(seed=0, yaw=0.0):
    rng = np.random.default_rng(seed)
    occupancy = np.where(rng.random((20, 30)) < 0.05, 100, 0).astype(np.int8)
    return OccupancyMap(occupancy=occupancy, resolution=0.1, origin=(-1.0, 2.0, yaw))


def test_distance_at_reads_the_cell_of_each_point_and_the_cap_outside():
    for yaw in (0.0, 0.7):
        grid = _grid(1, yaw)
        field = likelihood_field(grid, max_distance=1.5, dtype=np.float32)
        rng = np.random.default_rng(2)
        local = rng.uniform([-0.5, -0.5], [3.5, 2.5], (500, 2))  # map frame, some outside
        c, s = math.cos(yaw), math.sin(yaw)
        world = np.stack([-1.0 + c * local[:, 0] - s * local[:, 1], 2.0 + s * local[:, 0] + c * local[:, 1]], -1)
        got = np.asarray(jax.jit(distance_at)(field, jnp.asarray(world, jnp.float32)))
        col, row = np.floor(local[:, 0] / 0.1).astype(int), np.floor(local[:, 1] / 0.1).astype(int)
        inside = (col >= 0) & (col < 30) & (row >= 0) & (row < 20)
        table = distance_to_occupied(grid.occupied, 0.1, 1.5)
        # a point within float32 rounding of a cell edge may read the neighbour
        edge = (np.abs(local / 0.1 - np.round(local / 0.1)) < 1e-4).any(-1)
        expected = np.where(inside, table[np.clip(row, 0, 19), np.clip(col, 0, 29)], 1.5)
        np.testing.assert_allclose(got[~edge], expected[~edge], rtol=1e-6)


def test_beam_log_likelihood_is_the_mixture_of_table_6_3():
    d = np.linspace(0.0, 2.0, 21)
    got = np.asarray(beam_log_likelihood(jnp.asarray(d, jnp.float32), 0.2, 0.9, 0.1, 30.0))
    expected = np.log(0.9 * np.exp(-0.5 * (d / 0.2) ** 2) / (0.2 * np.sqrt(2 * np.pi)) + 0.1 / 30.0)
    np.testing.assert_allclose(got, expected, rtol=1e-6)


def test_free_cell_centres_are_free_cells():
    grid = _grid(3, 0.4)
    centres = free_cell_centres(grid, max_cells=50)
    assert centres.shape == (50, 2)
    field = likelihood_field(grid, 1.0, np.float64) if jax.config.jax_enable_x64 else likelihood_field(grid, 1.0)
    assert np.all(np.asarray(distance_at(field, jnp.asarray(centres, field.distance.dtype))) > 0)
