"""Motion and observation models, one function per model and one particle: odometry
(GMapping's sampled model, SRUPF-GM's augmented model and its unscented predictions),
the car of Victoria Park, range-bearing observations."""

__all__ = ["odometry", "range_bearing", "vehicle"]
