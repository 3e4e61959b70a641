"""jaxslam.models."""
