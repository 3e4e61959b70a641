"""jaxslam.feature."""
