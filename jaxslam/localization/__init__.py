"""Localization in a known map: the likelihood field and KLD-adaptive augmented MCL.

Modules:

* :mod:`~jaxslam.localization.field` — the map's distance field (SciPy's exact
  Euclidean distance transform) and the beam-endpoint likelihood.
* :mod:`~jaxslam.localization.monte_carlo` — :func:`~jaxslam.localization.monte_carlo.mcl`, the
  filter (``init``/``step``).
* :mod:`~jaxslam.localization.stream` — :class:`~jaxslam.localization.stream.StreamingLocalizer`,
  the filter fed one scan (or one chunk of scans) at a time.
* :mod:`~jaxslam.localization.experiment` — :func:`~jaxslam.localization.experiment.localize`, a
  log in a map (a streaming localizer fed the log's chunks).
"""

from jaxslam.localization.field import LikelihoodField, distance_at, likelihood_field
from jaxslam.localization.monte_carlo import MclConfig, MclInfo, MclParams, MclState, default_params, mcl
from jaxslam.localization.stream import StreamingLocalizer

__all__ = [
    "LikelihoodField",
    "MclConfig",
    "MclInfo",
    "MclParams",
    "MclState",
    "StreamingLocalizer",
    "default_params",
    "distance_at",
    "likelihood_field",
    "mcl",
]
