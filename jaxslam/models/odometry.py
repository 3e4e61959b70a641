r"""Odometry motion models for one particle (SE(2) poses ``[x, y, theta]``).

Two models are given, each written for a single particle (``vmap`` it):

**GMapping's sampled model** (Grisetti et al. 2005/2007, ``MotionModel::drawFromMotion``
of the OpenSLAM code). With the odometry increment
:math:`\delta = \ominus o_{t-1} \oplus o_t = (\delta_x, \delta_y, \delta_\theta)` in the
robot frame and :math:`s_{xy} = 0.3\, s_{rr}`:

.. math::
    \tilde\delta_x &= \delta_x + \mathcal N(0, (s_{rr}|\delta_x| + s_{tr}|\delta_\theta|
                      + s_{xy}|\delta_y|)^2) \\
    \tilde\delta_y &= \delta_y + \mathcal N(0, (s_{rr}|\delta_y| + s_{tr}|\delta_\theta|
                      + s_{xy}|\delta_x|)^2) \\
    \tilde\delta_\theta &= \delta_\theta + \mathcal N(0, (s_{tt}|\delta_\theta|
                      + s_{rt}\lVert\delta_{xy}\rVert)^2) \\
    x_t &= x_{t-1} \oplus \tilde\delta

(``str`` scales the *translational* noise with rotation and ``srt`` the rotational
noise with translation, exactly as in the C++ code; the ROS wiki words them the other
way round.)

**The augmented [pose; noise] model of SRUPF-GM** (Zandara & Nicholson 2009, Algorithm
2, function ``f``): the augmented state is :math:`a = [x, y, \theta, n_v, n_\delta]` with
:math:`n \sim \mathcal N(0, Q)` and

.. math::
    V = v + n_v, \quad G = \delta + n_\delta, \quad
    f(a, u) = \begin{pmatrix} x + V \cos(\theta + \phi + n_\delta) \\
                              y + V \sin(\theta + \phi + n_\delta) \\
                              \theta + G \end{pmatrix}

where :math:`v` is the signed length of the odometry translation, :math:`\delta` its
rotation and :math:`\phi` the bearing of the translation in the robot frame (0 when
the robot drives straight, :math:`\pi` backwards). The paper writes the heading of the
translation as :math:`\theta + G` (turn, then drive); with the measured bearing
:math:`\phi` the noiseless ``f`` reproduces the odometry increment exactly, which
the paper's form does not when the robot turns while it drives.
:func:`paper_augmented_motion` keeps the paper's literal form.

:func:`unscented_predict` (dense) and :func:`sqrt_unscented_predict` (square root,
eqs. 1-8) push the sigma points of ``[pose; noise]`` through ``f``.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax import Array

from jaxslam.core import se2
from jaxslam.core.numerics import safe_atan2, safe_sqrt
from jaxslam.core.sigma import UTParams, sigma_points, ut_weights
from jaxslam.core.sqrt import sqrt_ut_moments


def odometry_increment(odom_prev: Array, odom_cur: Array) -> Array:
    """The odometry motion ``⊖ odom_prev ⊕ odom_cur`` in the frame of ``odom_prev``."""
    return se2.relative(odom_prev, odom_cur)


def gmapping_noise_std(increment: Array, srr, srt, str_, stt) -> Array:
    """Standard deviations ``(3,)`` of GMapping's noise on ``(dx, dy, dtheta)``."""
    dx, dy, dth = jnp.abs(increment[..., 0]), jnp.abs(increment[..., 1]), jnp.abs(increment[..., 2])
    sxy = 0.3 * srr
    std_x = srr * dx + str_ * dth + sxy * dy
    std_y = srr * dy + str_ * dth + sxy * dx
    std_t = stt * dth + srt * jnp.sqrt(dx * dx + dy * dy)
    return jnp.stack([std_x, std_y, std_t], -1)


def sample_gmapping(key: Array, pose: Array, increment: Array, srr, srt, str_, stt) -> Array:
    """Draw ``pose ⊕ (increment + noise)`` with GMapping's srr/srt/str/stt model.

    Args:
        key: PRNG key.
        pose: ``(3,)`` particle pose at ``t-1``.
        increment: ``(3,)`` odometry increment in the robot frame.
        srr, srt, str_, stt: GMapping's noise gains (traced).

    Returns:
        The sampled pose ``(3,)``.
    """
    std = gmapping_noise_std(increment, srr, srt, str_, stt)
    noise = jax.random.normal(key, (3,), pose.dtype) * std.astype(pose.dtype)
    noisy = increment + noise
    noisy = noisy.at[2].set(se2.wrap_angle(noisy[2]))
    return se2.compose(pose, noisy)


class PolarIncrement(NamedTuple):
    """An odometry increment as ``(v, delta, phi)``: signed length, rotation, bearing."""

    length: Array
    rotation: Array
    bearing: Array


def polar_increment(increment: Array) -> PolarIncrement:
    """Split ``(dx, dy, dtheta)`` into signed length, rotation and translation bearing.

    A backward translation gets a negative length and a bearing near 0 (not pi), so
    the translation noise stays along the direction of travel.
    """
    dx, dy = increment[..., 0], increment[..., 1]
    backwards = dx < 0
    length = safe_sqrt(dx * dx + dy * dy)  # finite gradients at zero motion
    length = jnp.where(backwards, -length, length)
    moving = length != 0
    bearing = safe_atan2(jnp.where(backwards, -dy, dy), jnp.where(backwards, -dx, dx), defined=moving)
    return PolarIncrement(length, increment[..., 2], bearing)


def augmented_motion(augmented: Array, increment: Array) -> Array:
    """SRUPF-GM's ``f``: pose after the odometry increment with additive noise.

    Args:
        augmented: ``(5,)`` ``[x, y, theta, n_v, n_delta]``.
        increment: ``(3,)`` odometry increment ``(dx, dy, dtheta)`` in the robot frame.

    Returns:
        The pose ``(3,)``; with zero noise it equals ``pose ⊕ increment``.
    """
    polar = polar_increment(increment)
    x, y, theta, n_v, n_d = (augmented[i] for i in range(5))
    v = polar.length + n_v
    heading = theta + polar.bearing + n_d
    return jnp.stack(
        [x + v * jnp.cos(heading), y + v * jnp.sin(heading), se2.wrap_angle(theta + polar.rotation + n_d)]
    )


def paper_augmented_motion(augmented: Array, control: Array) -> Array:
    """Algorithm 2's ``f`` literally, for a control ``(v, delta)``."""
    x, y, theta, n_v, n_d = (augmented[i] for i in range(5))
    v = control[0] + n_v
    g = control[1] + n_d
    return jnp.stack([x + v * jnp.cos(g + theta), y + v * jnp.sin(g + theta), se2.wrap_angle(theta + g)])


def motion_noise_sqrt(
    increment: Array, linear, angular, linear_per_m=0.0, angular_per_rad=0.0, angular_per_m=0.0
) -> Array:
    r"""Lower factor ``(2, 2)`` of ``Q = diag(s_v^2, s_delta^2)``.

    The paper's Q is constant (``s_v = linear``, ``s_delta = angular``); the optional
    gains add noise proportional to the motion, as GMapping's srr/stt/srt do:
    ``s_v = linear + linear_per_m |v|`` and
    ``s_delta = angular + angular_per_rad |delta| + angular_per_m |v|``.
    """
    polar = polar_increment(increment)
    dtype = increment.dtype
    dist = jnp.abs(polar.length)
    s_v = jnp.asarray(linear, dtype) + jnp.asarray(linear_per_m, dtype) * dist
    s_d = (
        jnp.asarray(angular, dtype)
        + jnp.asarray(angular_per_rad, dtype) * jnp.abs(polar.rotation)
        + jnp.asarray(angular_per_m, dtype) * dist
    )
    return jnp.diag(jnp.stack([s_v, s_d]).astype(dtype))


def augment(pose: Array, pose_sqrt_cov: Array, noise_sqrt: Array) -> tuple[Array, Array]:
    """Eq. (1): ``mu_aug = [pose; 0]`` and the block-diagonal lower factor."""
    dtype = pose.dtype
    q = noise_sqrt.shape[0]
    mean = jnp.concatenate([pose, jnp.zeros((q,), dtype)])
    chol = jnp.zeros((3 + q, 3 + q), dtype)
    chol = chol.at[:3, :3].set(pose_sqrt_cov).at[3:, 3:].set(noise_sqrt.astype(dtype))
    return mean, chol


class Prediction(NamedTuple):
    """Result of an unscented odometry prediction for one particle."""

    mean: Array  # (3,)
    sqrt_cov: Array  # (3, 3) lower; for the dense version the Cholesky of ``cov``
    cov: Array  # (3, 3)
    propagated: Array  # (11, 3) sigma points after f
    mean_weights: Array  # (11,)
    cov_weights: Array  # (11,)


def unscented_predict(
    pose: Array, pose_sqrt_cov: Array, increment: Array, noise_sqrt: Array, ut_params: UTParams
) -> Prediction:
    """Dense unscented prediction of ``f`` over ``[pose; noise]`` (the reference).

    ``cov = sum_i W^c_i (f(chi_i) - mu)(f(chi_i) - mu)^T`` with wrapped headings.
    """
    mean_aug, chol_aug = augment(pose, pose_sqrt_cov, noise_sqrt)
    wm, wc, _ = ut_weights(5, ut_params, pose.dtype)
    points = sigma_points(mean_aug, chol_aug, ut_params)
    propagated = jax.vmap(augmented_motion, (0, None))(points, increment)
    mean = se2.pose_mean(propagated, wm)
    dev = se2.pose_residual(propagated, mean)
    cov = jnp.einsum("i,ij,ik->jk", wc, dev, dev)
    cov = 0.5 * (cov + cov.T)
    return Prediction(mean, jnp.linalg.cholesky(cov), cov, propagated, wm, wc)


def sqrt_unscented_predict(
    pose: Array, pose_sqrt_cov: Array, increment: Array, noise_sqrt: Array, ut_params: UTParams,
    motion=augmented_motion,
) -> Prediction:
    """Square-root unscented prediction, eqs. (1)-(8) of Zandara & Nicholson.

    Sigma points of the augmented state, ``f`` applied to each, the mean (6), a QR of
    the weighted deviations of points ``1..2n`` (7) and a rank-1 Cholesky update (a
    downdate if ``W^c_0 < 0``) with the zeroth deviation (8).

    Args:
        pose: ``(3,)``; pose_sqrt_cov: its lower factor ``(3, 3)``.
        increment: the control, as ``motion`` takes it.
        noise_sqrt: ``(q, q)`` lower factor of the process noise.
        ut_params: the unscented transform's scalings.
        motion: ``f(augmented (3 + q,), control) -> pose (3,)``
            (:class:`jaxslam.base.MotionModel`); SRUPF-GM's by default.
    """
    mean_aug, chol_aug = augment(pose, pose_sqrt_cov, noise_sqrt)
    wm, wc, _ = ut_weights(mean_aug.shape[0], ut_params, pose.dtype)
    points = sigma_points(mean_aug, chol_aug, ut_params)
    propagated = jax.vmap(motion, (0, None))(points, increment)
    mean, chol, _ = sqrt_ut_moments(propagated, wm, wc, se2.pose_mean, se2.pose_residual)
    return Prediction(mean, chol, chol @ chol.T, propagated, wm, wc)


__all__ = [
    "PolarIncrement",
    "Prediction",
    "augment",
    "augmented_motion",
    "gmapping_noise_std",
    "motion_noise_sqrt",
    "odometry_increment",
    "paper_augmented_motion",
    "polar_increment",
    "sample_gmapping",
    "sqrt_unscented_predict",
    "unscented_predict",
]
