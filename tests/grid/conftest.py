"""Shared fixtures of the grid tests."""

import pytest

from jaxslam.datasets.laser_sim import simulate


@pytest.fixture(scope="module")
def sim():
    """A small simulated log: two rooms and a corridor, 0.6 laps, 91 beams."""
    return simulate(width=12.0, height=8.0, rooms_x=2, laps=0.6, num_beams=91, seed=2)
