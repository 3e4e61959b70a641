"""The application: the ``jaxslam`` command line, the data a command reads, runs and
their output folders and report, figures, and the calibration command. It sits on
top of the filters and the runtime; nothing below it imports it."""

__all__ = ["calibrate", "cli", "data", "outputs", "plotting", "report", "runs"]
