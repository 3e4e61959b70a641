"""Trajectory and map error (relations, GPS, NEES), trajectory files and filter
diagnostics; host-side NumPy."""

__all__ = ["gps", "nees", "particle_diagnostics", "relations", "scoring", "stats", "trajectory_io"]
