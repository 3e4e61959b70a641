"""Live views of running filters (optional: ``pip install "jaxslam[viz]"``)."""
