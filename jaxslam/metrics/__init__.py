"""jaxslam.metrics."""
