"""jaxslam.datasets."""
