"""Landmark SLAM: unscented FastSLAM with the RB or the exactly Rao-Blackwellized (ERB)
proposal (Kim, Kim & Chung, ICRA 2011), per-particle landmark tables and data
association.

* :mod:`~jaxslam.feature.filter`: ``init`` / ``step`` / ``run``, ``State``, ``Info``.
* :mod:`~jaxslam.feature.particle`: one particle's part of a step and the landmark
  update / initialisation kernels.
* :mod:`~jaxslam.feature.params`: ``Params`` (traced) and ``Config`` (static).
* :mod:`~jaxslam.feature.proposals`: ``erb_proposal`` and ``rb_proposal`` (one signature).
* :mod:`~jaxslam.feature.association`: maximum-likelihood association with gates.
* :mod:`~jaxslam.feature.landmarks`: fixed-capacity landmark tables.
* :mod:`~jaxslam.feature.experiment`: ``run_landmark_slam`` on a whole sequence.
* :mod:`~jaxslam.feature.ensemble`: ``run_landmark_ensemble``, one run per seed in one program.
"""

from jaxslam.feature.ensemble import run_landmark_ensemble
from jaxslam.feature.experiment import LandmarkSlamResult, run_landmark_slam
from jaxslam.feature.filter import Info, Observation, State, init, run, step
from jaxslam.feature.landmarks import LandmarkTable
from jaxslam.feature.params import Config, Params
from jaxslam.feature.proposals import Proposal, erb_proposal, rb_proposal

__all__ = [
    "Config", "Info", "LandmarkSlamResult", "LandmarkTable", "Observation", "Params", "Proposal", "State",
    "erb_proposal", "init", "rb_proposal", "run", "run_landmark_ensemble", "run_landmark_slam", "step",
]
