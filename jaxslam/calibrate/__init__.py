"""Noise calibration by differentiating the particle filters' log marginal likelihood
estimate (stop-gradient resampling, Scibior & Wood 2021).

* :mod:`~jaxslam.calibrate.fit`: the Adam ascent over log noise levels (several
  filters per step) and the choice of the iterate on held-out scans, for any filter.
* :mod:`~jaxslam.calibrate.landmark`: ``differentiable_step`` and ``log_likelihoods``
  for RB/ERB-UPF, and ``calibrate`` on them.
* :mod:`~jaxslam.calibrate.grid`: ``calibrate_grid`` for SRUPF-GM.

The names below are imported on first use: the command line imports
:mod:`jaxslam.app.calibrate` for its parser on every ``jaxslam`` call, and loading JAX
and optax there cost ``jaxslam run`` about a second before it had done anything.
"""

from importlib import import_module

_HOMES = {
    "CalibrationResult": "jaxslam.calibrate.fit",
    "calibrate": "jaxslam.calibrate.landmark",
    "NOISE_NAMES": "jaxslam.calibrate.landmark",
    "differentiable_step": "jaxslam.calibrate.landmark",
    "log_likelihoods": "jaxslam.calibrate.landmark",
}

__all__ = ["CalibrationResult", "NOISE_NAMES", "calibrate", "differentiable_step", "log_likelihoods"]


def __getattr__(name: str):
    if name in _HOMES:
        return getattr(import_module(_HOMES[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
