"""Localization in a known map: the likelihood field and KLD-adaptive augmented MCL.

Modules:

* :mod:`~jaxslam.localization.field` — the map's distance field (SciPy's exact
  Euclidean distance transform) and the beam-endpoint likelihood.
* :mod:`~jaxslam.localization.mcl` — :func:`mcl`, the filter (``init``/``step``).
* :mod:`~jaxslam.localization.experiment` — :func:`localize`, a log in a map.
"""

from jaxslam.localization.field import LikelihoodField, distance_at, likelihood_field
from jaxslam.localization.mcl import MclConfig, MclInfo, MclParams, MclState, default_params, mcl

__all__ = [
    "LikelihoodField",
    "MclConfig",
    "MclInfo",
    "MclParams",
    "MclState",
    "default_params",
    "distance_at",
    "likelihood_field",
    "mcl",
]
