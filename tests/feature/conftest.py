"""Shared helpers for the landmark-SLAM tests: an independent float64 NumPy reference
of the proposals (filterpy's sigma points, dense matrices)."""

from __future__ import annotations

import math

import numpy as np
from filterpy.kalman import MerweScaledSigmaPoints


def wrap(a):
    return (a + np.pi) % (2 * np.pi) - np.pi


def observe_np(pose, landmark, offset=(0.0, 0.0)):
    c, s = math.cos(pose[2]), math.sin(pose[2])
    px = pose[0] + c * offset[0] - s * offset[1]
    py = pose[1] + s * offset[0] + c * offset[1]
    dx, dy = landmark[0] - px, landmark[1] - py
    return np.array([math.hypot(dx, dy), math.atan2(dy, dx) - pose[2]])


def dense_proposal(pose_mean, pose_cov, landmarks, landmark_covs, observations, R, ut=(1.0, 2.0, 1.0), perfect_map=False):
    """Batch proposal from the stacked innovation covariance, built densely.

    Each observation i gets its own 11 augmented sigma points (filterpy); its block
    S_ii is the unscented innovation covariance, and off-diagonal blocks come from the
    shared pose: S_ij = Sxy_i^T P^-1 Sxy_j. Returns mean, cov, log-likelihood.
    """
    alpha, beta, kappa = ut
    pts = MerweScaledSigmaPoints(5, alpha=alpha, beta=beta, kappa=kappa)
    k = len(observations)
    nus, sxys, s_blocks = [], [], []
    for i in range(k):
        mean = np.concatenate([pose_mean, landmarks[i]])
        cov = np.zeros((5, 5))
        cov[:3, :3] = pose_cov
        cov[3:, 3:] = 0.0 if perfect_map else landmark_covs[i]
        cov[3:, 3:] += 1e-300 * np.eye(2)
        try:
            sig = pts.sigma_points(mean, cov)
        except np.linalg.LinAlgError:
            sig = pts.sigma_points(mean, cov + 1e-18 * np.eye(5))
        if perfect_map:
            sig[:, 3:] = landmarks[i]
        y = np.array([observe_np(p[:3], p[3:]) for p in sig])
        y[:, 1] = y[0, 1] + wrap(y[:, 1] - y[0, 1])
        y_mean = pts.Wm @ y
        dev = y - y_mean
        s = np.einsum("i,ij,ik->jk", pts.Wc, dev, dev) + R
        sxy = np.einsum("i,ij,ik->jk", pts.Wc, sig[:, :3] - pose_mean, dev)
        nu = observations[i] - y_mean
        nu[1] = wrap(nu[1])
        s_blocks.append(s)
        sxys.append(sxy)
        nus.append(nu)
    p_inv = np.linalg.inv(pose_cov)
    S = np.zeros((2 * k, 2 * k))
    for i in range(k):
        for j in range(k):
            S[2 * i : 2 * i + 2, 2 * j : 2 * j + 2] = s_blocks[i] if i == j else sxys[i].T @ p_inv @ sxys[j]
    sxy_all = np.concatenate(sxys, 1)
    nu_all = np.concatenate(nus)
    gain = sxy_all @ np.linalg.inv(S)
    mean = pose_mean + gain @ nu_all
    cov = pose_cov - gain @ S @ gain.T
    sign, logdet = np.linalg.slogdet(S)
    loglik = -0.5 * (nu_all @ np.linalg.solve(S, nu_all) + logdet + 2 * k * math.log(2 * math.pi))
    return mean, cov, loglik

