"""The RB and ERB proposals against a dense float64 reference (in float64 and in the
production float32), and their ordering."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxslam.feature import _small
from jaxslam.feature.params import Params
from jaxslam.feature.proposals import erb_proposal, rb_proposal

from .conftest import dense_proposal, observe_np

R = np.diag([0.5**2, math.radians(2.0) ** 2])
PARAMS = Params(range_std=0.5, bearing_std=math.radians(2.0))


def _case(seed, k=3):
    rng = np.random.default_rng(seed)
    pose = np.array([rng.uniform(-5, 5), rng.uniform(-5, 5), rng.uniform(-np.pi, np.pi)])
    a = rng.normal(size=(3, 3)) * np.array([0.3, 0.3, 0.05])[:, None]
    pose_cov = a @ a.T + np.diag([0.01, 0.01, 1e-4])
    landmarks, lcovs, obs = [], [], []
    for _ in range(k):
        r, b = rng.uniform(5, 25), rng.uniform(-1.4, 1.4)
        lm = pose[:2] + r * np.array([np.cos(pose[2] + b), np.sin(pose[2] + b)])
        m = rng.normal(size=(2, 2)) * 0.5
        landmarks.append(lm)
        lcovs.append(m @ m.T + 0.05 * np.eye(2))
        z = observe_np(pose, lm + rng.normal(size=2) * 0.3) + rng.normal(size=2) * np.sqrt(np.diag(R))
        obs.append(z)
    return pose, pose_cov, np.array(landmarks), np.array(lcovs), np.array(obs)


def _ours(fn, pose, pose_cov, landmarks, lcovs, obs, mask=None, dtype=jnp.float64, sequential=False):
    mask = np.ones(len(obs), bool) if mask is None else mask
    f = jax.jit(fn, static_argnames="sequential")
    return f(
        jnp.asarray(pose, dtype),
        jnp.asarray(np.linalg.cholesky(pose_cov), dtype),
        jnp.asarray(landmarks, dtype),
        jnp.asarray(np.linalg.cholesky(lcovs), dtype),
        jnp.asarray(obs, dtype),
        jnp.asarray(mask),
        PARAMS,
        sequential=sequential,
    )


# Absolute tolerances against the float64 reference. float64: rounding only. float32
# (eps 1.2e-7): poses and landmarks up to ~30 m resolve to ~4e-6 m, and the
# covariances (~1e-2..1) come from differences of sigma points, so each loses a few
# digits; over 32 random cases the worst errors were mean 2.6e-6, covariance 2.3e-7,
# log-likelihood 1.1e-5 and log-determinant 2.3e-6: the bounds are ~10x those.
PROPOSAL_TOL = {
    np.float64: dict(mean=1e-9, cov=1e-10, log_likelihood=1e-8, log_det=1e-8),
    np.float32: dict(mean=3e-5, cov=3e-6, log_likelihood=1e-4, log_det=3e-5),
}


@pytest.mark.parametrize("perfect_map", [False, True])
@pytest.mark.parametrize("k", [1, 3])
def test_matches_dense_reference(perfect_map, k, dtype):
    tol = PROPOSAL_TOL[dtype]
    pose, pose_cov, lms, lcovs, obs = _case(k, k)
    ref_mean, ref_cov, ref_ll = dense_proposal(pose, pose_cov, lms, lcovs, obs, R, perfect_map=perfect_map)
    prop = _ours(rb_proposal if perfect_map else erb_proposal, pose, pose_cov, lms, lcovs, obs, dtype=dtype)
    assert prop.mean.dtype == dtype and prop.sqrt_cov.dtype == dtype
    cov = np.asarray(prop.sqrt_cov @ prop.sqrt_cov.T, np.float64)
    np.testing.assert_allclose(np.asarray(prop.mean, np.float64), ref_mean, atol=tol["mean"])
    np.testing.assert_allclose(cov, ref_cov, atol=tol["cov"])
    np.testing.assert_allclose(float(prop.log_likelihood), ref_ll, atol=tol["log_likelihood"])
    np.testing.assert_allclose(float(prop.log_det_cov), np.linalg.slogdet(ref_cov)[1], atol=tol["log_det"])


def test_masked_rows_are_ignored():
    pose, pose_cov, lms, lcovs, obs = _case(7, 3)
    full = _ours(erb_proposal, pose, pose_cov, lms[:2], lcovs[:2], obs[:2])
    masked = _ours(erb_proposal, pose, pose_cov, lms, lcovs, obs, mask=np.array([True, True, False]))
    np.testing.assert_allclose(np.asarray(full.mean), np.asarray(masked.mean), atol=1e-12)
    np.testing.assert_allclose(float(full.log_likelihood), float(masked.log_likelihood), rtol=1e-12)


def test_sequential_single_observation_equals_batch():
    pose, pose_cov, lms, lcovs, obs = _case(3, 1)
    batch = _ours(erb_proposal, pose, pose_cov, lms, lcovs, obs)
    seq = _ours(erb_proposal, pose, pose_cov, lms, lcovs, obs, sequential=True)
    np.testing.assert_allclose(np.asarray(seq.mean), np.asarray(batch.mean), atol=1e-10)
    np.testing.assert_allclose(float(seq.log_det_cov), float(batch.log_det_cov), rtol=1e-9)
    np.testing.assert_allclose(float(seq.log_likelihood), float(batch.log_likelihood), rtol=1e-9)


def test_sequential_close_to_batch_for_several():
    pose, pose_cov, lms, lcovs, obs = _case(4, 3)
    batch = _ours(erb_proposal, pose, pose_cov, lms, lcovs, obs)
    seq = _ours(erb_proposal, pose, pose_cov, lms, lcovs, obs, sequential=True)
    np.testing.assert_allclose(np.asarray(seq.mean)[:2], np.asarray(batch.mean)[:2], atol=0.05)
    assert abs(float(seq.log_det_cov) - float(batch.log_det_cov)) < 0.2


def test_zero_landmark_covariance_proposals_coincide():
    pose, pose_cov, lms, _, obs = _case(11, 3)
    zero = np.zeros((3, 2, 2))
    args = (
        jnp.asarray(pose, jnp.float32),
        jnp.asarray(np.linalg.cholesky(pose_cov), jnp.float32),
        jnp.asarray(lms, jnp.float32),
        jnp.asarray(zero, jnp.float32),
        jnp.asarray(obs, jnp.float32),
        jnp.ones(3, bool),
        PARAMS,
    )
    erb = jax.jit(erb_proposal)(*args)
    rb = jax.jit(rb_proposal)(*args)
    for a, b in zip(erb, rb):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    heading=st.floats(-math.pi, math.pi),
    pose_scale=st.floats(0.01, 1.0),
    landmark_scale=st.floats(0.0, 2.0),
    num=st.integers(1, 4),
)
def test_erb_covariance_dominates_rb(seed, heading, pose_scale, landmark_scale, num):
    """Loewner order P_ERB >= P_RB (the paper's Fig. 1 claim) for random states."""
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(3, 3)) * np.array([pose_scale, pose_scale, 0.1 * pose_scale])[:, None]
    pose_cov = a @ a.T + 1e-4 * np.eye(3)
    pose = np.array([rng.uniform(-50, 50), rng.uniform(-50, 50), heading])
    lms, lcovs, obs = [], [], []
    for _ in range(num):
        r, b = rng.uniform(3, 30), rng.uniform(-1.5, 1.5)
        lms.append(pose[:2] + r * np.array([np.cos(heading + b), np.sin(heading + b)]))
        m = rng.normal(size=(2, 2)) * landmark_scale
        lcovs.append(m @ m.T + 1e-6 * np.eye(2))
        obs.append(observe_np(pose, lms[-1]) + rng.normal(size=2) * np.array([0.5, 0.03]))
    erb = _ours(erb_proposal, pose, pose_cov, np.array(lms), np.array(lcovs), np.array(obs))
    rb = _ours(rb_proposal, pose, pose_cov, np.array(lms), np.array(lcovs), np.array(obs))
    p_erb = np.asarray(erb.sqrt_cov @ erb.sqrt_cov.T)
    p_rb = np.asarray(rb.sqrt_cov @ rb.sqrt_cov.T)
    gap = np.linalg.eigvalsh(p_erb - p_rb)
    assert gap.min() >= -1e-9 * np.abs(p_rb).max()
    assert float(erb.log_det_cov) >= float(rb.log_det_cov) - 1e-9


def test_small_linear_algebra():
    rng = np.random.default_rng(0)
    a = rng.normal(size=(5, 3, 3))
    spd = a @ np.swapaxes(a, 1, 2) + 0.1 * np.eye(3)
    l = np.asarray(_small.chol3(jnp.asarray(spd)))
    np.testing.assert_allclose(l, np.linalg.cholesky(spd), atol=1e-12)
    np.testing.assert_allclose(np.asarray(_small.tril_inv3(jnp.asarray(l))), np.linalg.inv(l), atol=1e-10)
    np.testing.assert_allclose(np.asarray(_small.det3(jnp.asarray(a))), np.linalg.det(a), atol=1e-10)
    np.testing.assert_allclose(np.asarray(_small.tril_logdet(jnp.asarray(l))), np.linalg.slogdet(spd)[1], atol=1e-10)
    inv, logdet = _small.inv2(jnp.asarray(spd[:, :2, :2]))
    np.testing.assert_allclose(np.asarray(inv), np.linalg.inv(spd[:, :2, :2]), atol=1e-10)
    np.testing.assert_allclose(np.asarray(logdet), np.linalg.slogdet(spd[:, :2, :2])[1], atol=1e-12)
    np.testing.assert_allclose(np.asarray(_small.chol2(jnp.asarray(spd[:, :2, :2]))), np.linalg.cholesky(spd[:, :2, :2]), atol=1e-12)
