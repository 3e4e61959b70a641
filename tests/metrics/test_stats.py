"""Seed statistics (Student-t mean intervals, Wilson rate intervals) against printed
table values and SciPy's own interval routines."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats as sps

from jaxslam.metrics.stats import mean_ci, rate_ci


# two-sided 95% Student-t critical values t_{n-1, 0.975} from a printed table
# (e.g. NIST/SEMATECH e-Handbook, 1.3.6.7.2)
@pytest.mark.parametrize("n,t_crit", [(2, 12.706), (3, 4.303), (5, 2.776), (10, 2.262), (30, 2.045)])
def test_mean_ci_half_width_uses_student_t_table_value(n, t_crit):
    x = np.random.default_rng(n).normal(size=n)
    got = mean_ci(x)
    half = t_crit * x.std(ddof=1) / math.sqrt(n)
    assert got["ci_high"] - got["mean"] == pytest.approx(half, rel=5e-4)
    assert got["mean"] - got["ci_low"] == pytest.approx(half, rel=5e-4)


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
    z = 1.959963984540054  # two-sided 95% normal critical value, Phi^-1(0.975)
    p = k / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z / (1 + z * z / n) * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
    got = rate_ci(k, n)
    assert got["rate"] == p
    assert got["ci_low"] == pytest.approx(max(0.0, centre - half), abs=1e-9)
    assert got["ci_high"] == pytest.approx(min(1.0, centre + half), abs=1e-9)

