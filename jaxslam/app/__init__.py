"""The application: the ``jaxslam`` command line, runs and their output folders,
figures, and the calibration command. It sits on top of the filters and the
runtime; nothing below it imports it."""

__all__ = ["calibrate", "cli", "outputs", "plotting", "runs"]
