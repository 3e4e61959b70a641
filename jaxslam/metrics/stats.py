r"""Summaries of repeated runs (seeds): mean, spread and a confidence interval.

For ``n`` independent results :math:`x_i` with mean :math:`\bar x` and sample standard
deviation :math:`s`, the two-sided confidence interval of the mean is
:math:`\bar x \pm t_{n-1, (1+c)/2}\, s / \sqrt n` (Student's t). For a rate
(``k`` of ``n`` runs, e.g. diverged) the Wilson score interval is used, which stays
inside ``[0, 1]`` and is sensible at ``k = 0`` or ``k = n``. Host-side NumPy; the
t and normal quantiles come from :mod:`scipy.stats`.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import stats


def mean_ci(values, confidence: float = 0.95) -> dict[str, float]:
    """Mean, sample standard deviation (``ddof=1``) and the Student-t confidence
    interval of the mean of ``values`` (NaN values are an error, not dropped)."""
    x = np.asarray(values, np.float64).ravel()
    if x.size == 0:
        raise ValueError("mean_ci needs at least one value")
    if not np.all(np.isfinite(x)):
        raise ValueError(f"mean_ci got non-finite values: {x[~np.isfinite(x)][:5].tolist()}")
    mean = float(x.mean())
    if x.size == 1:
        return dict(mean=mean, std=float("nan"), ci_low=float("nan"), ci_high=float("nan"), n=1)
    std = float(x.std(ddof=1))
    half = float(stats.t.ppf(0.5 * (1.0 + confidence), x.size - 1)) * std / math.sqrt(x.size)
    return dict(mean=mean, std=std, ci_low=mean - half, ci_high=mean + half, n=int(x.size))


def rate_ci(successes: int, trials: int, confidence: float = 0.95) -> dict[str, float]:
    """A rate ``successes / trials`` with its Wilson score interval."""
    if trials <= 0 or not 0 <= successes <= trials:
        raise ValueError(f"need 0 <= successes <= trials and trials > 0, got {successes}/{trials}")
    z = float(stats.norm.ppf(0.5 * (1.0 + confidence)))
    p = successes / trials
    denom = 1.0 + z * z / trials
    centre = (p + z * z / (2 * trials)) / denom
    half = z * math.sqrt(p * (1 - p) / trials + z * z / (4 * trials * trials)) / denom
    return dict(rate=p, ci_low=max(0.0, centre - half), ci_high=min(1.0, centre + half), k=successes, n=trials)

