"""Live views of running filters (optional: ``pip install "jaxslam[viz]"``)."""

__all__ = ["rerun_log"]
