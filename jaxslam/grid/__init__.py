"""jaxslam.grid."""
