"""Seed statistics (Student-t mean intervals, Wilson rate intervals) against SciPy."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats as sps

from jaxslam.metrics.nees import chi2_quantile
from jaxslam.metrics.stats import mean_ci, rate_ci, student_t_quantile, student_t_two_sided


@pytest.mark.parametrize("dof", [1, 2, 3, 4, 5, 9, 10, 49])
def test_student_t_matches_scipy(dof):
    for t in (0.1, 1.0, 2.5, 7.0):
        assert student_t_two_sided(t, dof) == pytest.approx(sps.t.cdf(t, dof) - sps.t.cdf(-t, dof), abs=1e-12)
    for p in (0.9, 0.975, 0.995):
        assert student_t_quantile(p, dof) == pytest.approx(sps.t.ppf(p, dof), rel=1e-9)


def test_mean_ci_matches_scipy():
    x = np.random.default_rng(0).normal(2.0, 0.7, size=10)
    got = mean_ci(x)
    low, high = sps.t.interval(0.95, len(x) - 1, loc=x.mean(), scale=sps.sem(x))
    assert got["mean"] == pytest.approx(x.mean())
    assert got["std"] == pytest.approx(x.std(ddof=1))
    assert (got["ci_low"], got["ci_high"]) == pytest.approx((low, high), rel=1e-9)


def test_mean_ci_refuses_nan():
    with pytest.raises(ValueError, match="non-finite"):
        mean_ci([1.0, float("nan")])


@pytest.mark.parametrize("k,n", [(0, 50), (3, 50), (25, 50), (50, 50)])
def test_wilson_interval(k, n):
    z = sps.norm.ppf(0.975)
    p = k / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z / (1 + z * z / n) * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
    got = rate_ci(k, n)
    assert got["rate"] == p
    assert got["ci_low"] == pytest.approx(max(0.0, centre - half), abs=1e-9)
    assert got["ci_high"] == pytest.approx(min(1.0, centre + half), abs=1e-9)


def test_chi2_quantile_still_matches_scipy():
    for dof in (2, 3, 30):
        assert chi2_quantile(0.975, dof) == pytest.approx(sps.chi2.ppf(0.975, dof), rel=1e-9)
