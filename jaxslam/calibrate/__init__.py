"""Noise calibration by differentiating the particle filters' log marginal likelihood
estimate (stop-gradient resampling, Scibior & Wood 2021).

* :mod:`~jaxslam.calibrate.landmark`: ``differentiable_step`` and ``log_likelihoods``
  for RB/ERB-UPF.
* :mod:`~jaxslam.calibrate.fit`: ``calibrate`` (optax Adam over log noise levels,
  several filters per step).
"""

from jaxslam.calibrate.fit import CalibrationResult, calibrate
from jaxslam.calibrate.landmark import NOISE_NAMES, differentiable_step, log_likelihoods

__all__ = ["CalibrationResult", "NOISE_NAMES", "calibrate", "differentiable_step", "log_likelihoods"]
