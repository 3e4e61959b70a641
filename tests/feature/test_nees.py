"""NEES metric: sample consistency, heading wrap, the chi-square band against table values."""

from __future__ import annotations

import numpy as np
import pytest

from jaxslam.metrics.nees import nees, nees_band, nees_summary, pose_nees


def test_consistent_samples_have_mean_dof():
    rng = np.random.default_rng(0)
    a = rng.normal(size=(3, 3))
    cov = a @ a.T + np.eye(3)
    errors = rng.multivariate_normal(np.zeros(3), cov, size=20000)
    values = nees(errors, np.broadcast_to(cov, (20000, 3, 3)))
    assert abs(values.mean() - 3.0) < 0.1
    s = nees_summary(values)
    assert abs(s["fraction_inside"] - 0.95) < 0.01


def test_heading_is_wrapped():
    est = np.array([[0.0, 0.0, 3.1]])
    truth = np.array([[0.0, 0.0, -3.1]])
    v = pose_nees(est, np.eye(3)[None] * 0.01, truth)
    np.testing.assert_allclose(v, (2 * np.pi - 6.2) ** 2 / 0.01)


# 0.025 and 0.975 chi-square quantiles from a printed table (e.g. NIST/SEMATECH
# e-Handbook, 1.3.6.7.4), to the table's precision
@pytest.mark.parametrize("dof,lower,upper", [(1, 0.000982, 5.024), (2, 0.0506, 7.378), (3, 0.216, 9.348),
                                             (5, 0.831, 12.833), (10, 3.247, 20.483)])
def test_nees_band_matches_chi_square_table(dof, lower, upper):
    lo, hi = nees_band(dof)
    assert lo == pytest.approx(lower, rel=2e-3)
    assert hi == pytest.approx(upper, rel=2e-4)
    s = nees_summary(np.array([lower * 0.99, lower * 1.01, upper * 0.99, upper * 1.01]), dof=dof)
    assert (s["lower"], s["upper"]) == (lo, hi)
    assert s["fraction_inside"] == 0.5 and s["fraction_above"] == 0.25
