"""NEES metric against scipy's chi-square."""

from __future__ import annotations

import numpy as np
from scipy import stats

from jaxslam.metrics.nees import chi2_quantile, nees, nees_summary, pose_nees


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


def test_chi2_quantile():
    for dof in (2, 3, 5):
        for p in (0.025, 0.5, 0.975):
            assert abs(chi2_quantile(p, dof) - stats.chi2.ppf(p, dof)) < 1e-6 * (1 + stats.chi2.ppf(p, dof))
