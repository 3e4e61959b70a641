r"""Normalised estimation error squared (NEES) of pose estimates.

For an estimate :math:`\hat x_t` with covariance :math:`P_t` of a true pose
:math:`x_t` (heading difference wrapped),

.. math::
    \epsilon_t = (x_t - \hat x_t)^T P_t^{-1} (x_t - \hat x_t),

which for a consistent filter is :math:`\chi^2` distributed with ``dof`` = 3 degrees
of freedom: mean 3 (Bar-Shalom, Li & Kirubarajan 2001, Sec. 5.4). Larger values mean
an overconfident filter. Host-side NumPy; chi-square quantiles from
:data:`scipy.stats.chi2`.
"""

from __future__ import annotations

import numpy as np
from scipy.stats import chi2

from jaxslam.datasets.geometry import wrap_angle


def pose_errors(estimates: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """``truth - estimates`` for poses ``(T, 3)``, heading wrapped."""
    d = np.asarray(truth, np.float64) - np.asarray(estimates, np.float64)
    d[..., 2] = wrap_angle(d[..., 2])
    return d


def nees(errors: np.ndarray, covs: np.ndarray) -> np.ndarray:
    """NEES ``(T,)`` of errors ``(T, n)`` under covariances ``(T, n, n)``."""
    errors = np.asarray(errors, np.float64)
    covs = np.asarray(covs, np.float64)
    sol = np.linalg.solve(covs, errors[..., None])[..., 0]
    return np.einsum("...i,...i->...", errors, sol)


def pose_nees(estimates: np.ndarray, covs: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """NEES ``(T,)`` of pose estimates ``(T, 3)`` with covariances ``(T, 3, 3)``."""
    return nees(pose_errors(estimates, truth), covs)


def nees_band(dof: int, confidence: float = 0.95) -> tuple[float, float]:
    """The two-sided ``confidence`` interval of a chi-square variable with ``dof``
    degrees of freedom: the ``(1 - c)/2`` and ``(1 + c)/2`` quantiles.

    The mean NEES of ``n`` independent runs times ``n`` is chi-square with
    ``n * dof`` degrees of freedom, so its band is ``nees_band(n * dof) / n``.
    """
    return float(chi2.ppf(0.5 * (1 - confidence), dof)), float(chi2.ppf(0.5 * (1 + confidence), dof))


def nees_summary(values: np.ndarray, dof: int = 3, confidence: float = 0.95) -> dict[str, float]:
    """Mean NEES, its ratio to the expectation ``dof``, and the fraction of steps inside
    the two-sided ``confidence`` chi-square interval (NaN steps ignored)."""
    v = np.asarray(values, np.float64)
    v = v[np.isfinite(v)]
    lo, hi = nees_band(dof, confidence)
    return dict(
        mean=float(v.mean()) if v.size else float("nan"),
        mean_over_dof=float(v.mean() / dof) if v.size else float("nan"),
        median=float(np.median(v)) if v.size else float("nan"),
        fraction_inside=float(((v >= lo) & (v <= hi)).mean()) if v.size else float("nan"),
        fraction_above=float((v > hi).mean()) if v.size else float("nan"),
        lower=lo,
        upper=hi,
        steps=int(v.size),
    )
