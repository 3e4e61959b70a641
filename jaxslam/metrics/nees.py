r"""Normalised estimation error squared (NEES) of pose estimates.

For an estimate :math:`\hat x_t` with covariance :math:`P_t` of a true pose
:math:`x_t` (heading difference wrapped),

.. math::
    \epsilon_t = (x_t - \hat x_t)^T P_t^{-1} (x_t - \hat x_t),

which for a consistent filter is :math:`\chi^2` distributed with ``dof`` = 3 degrees
of freedom: mean 3 (Bar-Shalom, Li & Kirubarajan 2001, Sec. 5.4). Larger values mean
an overconfident filter. Host-side NumPy.
"""

from __future__ import annotations

import math

import numpy as np

from jaxslam.datasets.geometry import wrap_angle
from jaxslam.metrics.stats import bisect_increasing


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


def chi2_cdf(x: float, dof: int) -> float:
    """Chi-square CDF for integer ``dof`` (closed forms and the recursion
    ``P_{k+2}(x) = P_k(x) - (x/2)^{k/2} e^{-x/2} / Gamma(k/2 + 1)``)."""
    if x <= 0:
        return 0.0
    half = 0.5 * x
    if dof % 2:
        p, k = math.erf(math.sqrt(half)), 1
    else:
        p, k = 1.0 - math.exp(-half), 2
    while k < dof:
        p -= math.exp((0.5 * k) * math.log(half) - half - math.lgamma(0.5 * k + 1))
        k += 2
    return p


def chi2_quantile(p: float, dof: int) -> float:
    """Chi-square quantile for integer ``dof`` (bisection on :func:`chi2_cdf`)."""
    return bisect_increasing(lambda x: chi2_cdf(x, dof), p, 0.0, 10.0 * dof + 100.0)


def nees_summary(values: np.ndarray, dof: int = 3, confidence: float = 0.95) -> dict[str, float]:
    """Mean NEES, its ratio to the expectation ``dof``, and the fraction of steps inside
    the two-sided ``confidence`` chi-square interval (NaN steps ignored)."""
    v = np.asarray(values, np.float64)
    v = v[np.isfinite(v)]
    lo = chi2_quantile(0.5 * (1 - confidence), dof)
    hi = chi2_quantile(0.5 * (1 + confidence), dof)
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
