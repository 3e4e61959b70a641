r"""The RB and ERB unscented proposals (Kim, Kim & Chung 2011), one signature.

For one particle with predicted pose :math:`\hat x, \bar P = \bar L \bar L^T` and an
observation :math:`z` of a landmark :math:`\mathcal N(\mu, \Sigma_m)`, both proposals
push the :math:`2 N_a + 1 = 11` sigma points of the augmented state
:math:`[x; m] \sim \mathcal N([\hat x; \mu], \operatorname{blockdiag}(\bar P, \Sigma_m))`
through the observation model :math:`h` (Sec. III-A):

.. math::
    \hat y = \sum_i w^g_i \mathcal A_i, \quad
    \mathcal S = \sum_i w^c_i (\mathcal A_i - \hat y)(\cdot)^T + R, \quad
    \Sigma^{xy} = \sum_i w^c_i (\zeta^{xv}_i - \hat x)(\mathcal A_i - \hat y)^T .

* **ERB** uses them as they are: :math:`\mathcal S` holds robot, map and measurement
  uncertainty (eq. 8).
* **RB** makes the perfect-map assumption of eqs. 1-3: the landmark sigma points are
  put at the landmark mean (:math:`\Sigma_m = 0`), so the innovation covariance
  :math:`V = \sum w^c (\mathcal Y - \hat y)(\cdot)^T + R` only holds robot and
  measurement uncertainty. The pose sigma points are the same in both, so one
  evaluation of :math:`h` serves both proposals (used for the paper's Fig. 1).

Proposal moments (eqs. 9-10) and weight (eq. 11) for one observation:

.. math::
    x = \hat x + \Sigma^{xy} \mathcal S^{-1} \nu, \quad
    P = \bar P - \Sigma^{xy} \mathcal S^{-1} \Sigma^{xy\,T}, \quad
    w = \mathcal N(\nu; 0, \mathcal S), \quad \nu = z - \hat y .

**Batch update.** For all observations of a scan at once the pose part is written
as a statistical linear regression: with the whitened Jacobian
:math:`G = \Sigma^{xy\,T} \bar L^{-T}` (read straight off the pose sigma-point pairs,
:math:`G_{:,j} = \gamma w^c_j (\mathcal A_{j} - \mathcal A_{n+j})`) and the
non-pose part :math:`Z = \mathcal S - G G^T` (map + measurement + higher order), the
stacked innovation covariance is :math:`G_{1:k} G_{1:k}^T + \operatorname{blockdiag}(Z_i)`;
landmarks of different observations are independent given the pose, so only the pose
correlates them. By the Woodbury identity everything is a sum of per-observation terms
and one 3x3 factorisation:

.. math::
    M = I + \sum_i G_i^T Z_i^{-1} G_i, \quad c = \sum_i G_i^T Z_i^{-1} \nu_i, \quad
    x = \hat x + \bar L M^{-1} c, \quad P = \bar L M^{-1} \bar L^T,

    \log w = -\tfrac12 \Big(\sum_i \nu_i^T Z_i^{-1} \nu_i - c^T M^{-1} c
             + \sum_i \log|Z_i| + \log|M|\Big) - k \log 2\pi .

For one observation this is exactly eqs. 9-11. **Sequential update** applies the
single-observation form observation after observation, re-drawing the sigma points
around the updated pose ([6] of the paper).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from jaxslam.core.se2 import wrap_angle
from jaxslam.core.sigma import ut_weights
from jaxslam.feature import _small
from jaxslam.feature.params import Params
from jaxslam.models.range_bearing import observe_unwrapped, sensor_position

POSE_DIM = 3
LANDMARK_DIM = 2
AUG_DIM = POSE_DIM + LANDMARK_DIM
# Sigma points of the augmented state in filterpy order [x, x + cols, x - cols]:
# columns 0-2 perturb the pose, 3-4 the landmark.
_LANDMARK_POINTS = np.zeros(2 * AUG_DIM + 1, bool)
_LANDMARK_POINTS[[1 + 3, 1 + 4, 1 + AUG_DIM + 3, 1 + AUG_DIM + 4]] = True


class Proposal(NamedTuple):
    """Gaussian proposal of one particle's pose and its log-likelihood (eq. 11).

    Attributes:
        mean: ``(3,)`` proposal mean, heading wrapped.
        sqrt_cov: ``(3, 3)`` a square root ``F`` of the covariance, ``P = F F^T``.
        log_det_cov: ``log det P``.
        log_likelihood: ``log N(nu; 0, S)`` of the used observations (0 if none).
        num_used: number of observations used.
    """

    mean: Array
    sqrt_cov: Array
    log_det_cov: Array
    log_likelihood: Array
    num_used: Array


class InnovationTerms(NamedTuple):
    """Per-observation pieces of the update (see the module docstring)."""

    predicted: Array  # (..., 2) y_hat
    innovation: Array  # (..., 2) nu = z - y_hat, bearing wrapped
    innovation_cov: Array  # (..., 2, 2) S (with R)
    whitened_jacobian: Array  # (..., 2, 3) G
    residual_cov: Array  # (..., 2, 2) Z = S - G G^T


def measurement_cov(params: Params, dtype) -> Array:
    """``R = diag(range_std^2, bearing_std^2)``."""
    return jnp.diag(jnp.stack([jnp.asarray(params.range_std, dtype) ** 2, jnp.asarray(params.bearing_std, dtype) ** 2]))


def _pose_sigma_sensors(pose_mean: Array, pose_sqrt: Array, params: Params) -> tuple[Array, Array]:
    """Sensor positions ``(7, 2)`` and headings ``(7,)`` of the pose sigma points
    ``[centre, +cols, -cols]`` of the augmented transform (n = 5 scaling)."""
    dtype = pose_mean.dtype
    _, _, lam = ut_weights(AUG_DIM, params.ut_update, dtype)
    offsets = jnp.sqrt(AUG_DIM + lam) * pose_sqrt.T
    poses = jnp.concatenate([pose_mean[None], pose_mean + offsets, pose_mean - offsets], 0)
    sensors = jax.vmap(sensor_position, (0, None))(poses, jnp.asarray(params.sensor_offset, dtype))
    return sensors, poses[:, 2]


def _assemble(sensors: Array, headings: Array, landmark_mean: Array, landmark_chol: Array, gamma: Array) -> Array:
    """The 11 predicted observations of one landmark (filterpy order), bearings
    unwrapped about the centre's (:func:`jaxslam.models.range_bearing.observe_unwrapped`)."""
    off = gamma * landmark_chol.T
    zero2 = jnp.zeros((2, 2), landmark_mean.dtype)
    # points: pose 0-3, landmark +cols, pose 4-6, landmark -cols
    sensor = jnp.concatenate([sensors[:4], jnp.broadcast_to(sensors[0], (2, 2)), sensors[4:],
                              jnp.broadcast_to(sensors[0], (2, 2))], 0)
    heading = jnp.concatenate([headings[:4], jnp.broadcast_to(headings[0], (2,)), headings[4:],
                               jnp.broadcast_to(headings[0], (2,))])
    landmark = landmark_mean + jnp.concatenate([zero2[:1].repeat(4, 0), off, zero2[:1].repeat(3, 0), -off], 0)
    return observe_unwrapped(sensor, heading, landmark)


def sigma_observations(
    pose_mean: Array, pose_sqrt: Array, landmark_mean: Array, landmark_chol: Array, params: Params
) -> Array:
    """Predicted observations of the augmented sigma points ``zeta``.

    The sigma points are those of :func:`jaxslam.core.sigma.sigma_points` for
    ``[pose; landmark]`` with factor ``blockdiag(pose_sqrt, landmark_chol)`` (filterpy
    order). ``landmark_mean`` ``(..., 2)`` and ``landmark_chol`` ``(..., 2, 2)`` may
    carry leading axes; the pose part is computed once. Bearings are unwrapped about
    the centre point's, so their weighted mean is valid. ``pose_sqrt`` may be any
    square root of the pose covariance.

    Returns:
        ``(..., 11, 2)``.
    """
    dtype = pose_mean.dtype
    _, _, lam = ut_weights(AUG_DIM, params.ut_update, dtype)
    gamma = jnp.sqrt(AUG_DIM + lam)
    sensors, headings = _pose_sigma_sensors(pose_mean, pose_sqrt, params)
    batch = landmark_mean.shape[:-1]
    flat_mean = landmark_mean.reshape((-1, 2))
    flat_chol = landmark_chol.reshape((-1, 2, 2))
    out = jax.vmap(_assemble, (None, None, 0, 0, None))(sensors, headings, flat_mean, flat_chol, gamma)
    return out.reshape(batch + (2 * AUG_DIM + 1, 2))


def innovation_terms(sigma_obs: Array, observation: Array, params: Params, perfect_map: bool) -> InnovationTerms:
    """Moments of one observation from its sigma-point predictions ``(11, 2)``.

    Args:
        sigma_obs: output of :func:`sigma_observations`.
        observation: ``(2,)`` measured range and bearing.
        params: filter parameters (noise, UT scaling).
        perfect_map: RB (True: landmark sigma points at the mean) or ERB (False).
    """
    dtype = sigma_obs.dtype
    if perfect_map:
        sigma_obs = jnp.where(jnp.asarray(_LANDMARK_POINTS)[:, None], sigma_obs[0], sigma_obs)
    mean_w, cov_w, lam = ut_weights(AUG_DIM, params.ut_update, dtype)
    gamma = jnp.sqrt(AUG_DIM + lam)
    r, b = sigma_obs[..., 0], sigma_obs[..., 1]
    predicted = jnp.stack([_small.wsum(mean_w, r), _small.wsum(mean_w, b)], -1)
    dr, db = r - predicted[..., 0, None], b - predicted[..., 1, None]
    s01 = _small.wsum_product(cov_w, dr, db)
    cov = jnp.stack(
        [
            jnp.stack([_small.wsum_product(cov_w, dr, dr) + params.range_std**2, s01], -1),
            jnp.stack([s01, _small.wsum_product(cov_w, db, db) + params.bearing_std**2], -1),
        ],
        -2,
    ).astype(dtype)
    pairs = sigma_obs[..., 1 : 1 + POSE_DIM, :] - sigma_obs[..., 1 + AUG_DIM : 1 + AUG_DIM + POSE_DIM, :]  # (3, 2)
    jac = (gamma * cov_w[1 : 1 + POSE_DIM])[:, None] * pairs  # (3, 2) = G^T
    jac_t = jnp.swapaxes(jac, -1, -2)
    residual_cov = cov - _small.matmul(jac_t, jac)
    innovation = jnp.stack(
        [observation[..., 0] - predicted[..., 0], wrap_angle(observation[..., 1] - predicted[..., 1])], -1
    )
    return InnovationTerms(predicted, innovation, cov, jac_t, 0.5 * (residual_cov + jnp.swapaxes(residual_cov, -1, -2)))


def combine_batch(pose_mean: Array, pose_sqrt: Array, terms: InnovationTerms, mask: Array) -> Proposal:
    """Batch proposal of one particle from the terms of its observations ``(k, ...)``."""
    dtype = pose_mean.dtype
    z_inv, z_logdet = _small.inv2(terms.residual_cov)
    maskf = mask.astype(dtype)
    z_inv = z_inv * maskf[:, None, None]
    nu = terms.innovation * maskf[:, None]
    g = terms.whitened_jacobian
    g_t = jnp.swapaxes(g, -1, -2)
    gt_zinv = _small.matmul(g_t, z_inv)  # (k, 3, 2)
    info = jnp.eye(POSE_DIM, dtype=dtype) + jnp.sum(_small.matmul(gt_zinv, g), 0)
    c = jnp.sum(_small.matvec(gt_zinv, nu), 0)
    info_chol = _small.chol3(info)
    info_chol_inv = _small.tril_inv3(info_chol)
    u = _small.matvec(info_chol_inv, c)
    sqrt_cov = _small.matmul(pose_sqrt, info_chol_inv.T)
    mean = pose_mean + _small.matvec(sqrt_cov, u)
    mean = mean.at[2].set(wrap_angle(mean[2]))
    info_logdet = _small.tril_logdet(info_chol)
    log_det_cov = _small.sqrt_logdet3(pose_sqrt) - info_logdet
    quad = jnp.sum(_small.quad2(nu, z_inv)) - jnp.sum(u * u)
    num_used = jnp.sum(maskf)
    log_det_s = jnp.sum(z_logdet * maskf) + info_logdet
    log_lik = -0.5 * (quad + log_det_s) - num_used * jnp.log(jnp.asarray(2 * np.pi, dtype))
    return Proposal(mean, sqrt_cov, log_det_cov, log_lik, num_used)


def erb_proposal(
    pose_mean: Array,
    pose_sqrt: Array,
    landmark_means: Array,
    landmark_chols: Array,
    observations: Array,
    mask: Array,
    params: Params,
    sequential: bool = False,
    *,
    perfect_map: bool = False,
) -> Proposal:
    """Exactly Rao-Blackwellized proposal (Sec. III-A, eqs. 9-11) of one particle.

    Args:
        pose_mean: ``(3,)`` predicted pose.
        pose_sqrt: ``(3, 3)`` square root of the predicted pose covariance.
        landmark_means: ``(k, 2)`` means of the associated landmarks.
        landmark_chols: ``(k, 2, 2)`` Cholesky factors of their covariances.
        observations: ``(k, 2)`` measured ranges and bearings.
        mask: ``(k,)`` which rows are used.
        params: filter parameters.
        sequential: sequential instead of batch update (static).
        perfect_map: take the landmarks as exactly known (static): the innovations
            leave out the landmark covariance, which is the conventional proposal
            (:func:`rb_proposal`).
    """
    if not sequential:
        sig = sigma_observations(pose_mean, pose_sqrt, landmark_means, landmark_chols, params)
        terms = jax.vmap(innovation_terms, (0, 0, None, None))(sig, observations, params, perfect_map)
        return combine_batch(pose_mean, pose_sqrt, terms, mask)

    def one(carry, inputs):
        mean, sqrt, log_det, log_lik, used = carry
        lm_mean, lm_chol, z, ok = inputs
        sig = sigma_observations(mean, sqrt, lm_mean, lm_chol, params)
        terms = innovation_terms(sig, z, params, perfect_map)
        terms = jax.tree_util.tree_map(lambda x: x[None], terms)
        upd = combine_batch(mean, sqrt, terms, ok[None])
        new = (
            jnp.where(ok, upd.mean, mean),
            jnp.where(ok, upd.sqrt_cov, sqrt),
            log_det + jnp.where(ok, upd.log_det_cov - _small.sqrt_logdet3(sqrt), 0.0),
            log_lik + jnp.where(ok, upd.log_likelihood, 0.0),
            used + ok.astype(mean.dtype),
        )
        return new, None

    dtype = pose_mean.dtype
    zero = jnp.zeros((), dtype)
    init = (pose_mean, pose_sqrt, _small.sqrt_logdet3(pose_sqrt), zero, zero)
    (mean, sqrt, log_det, log_lik, used), _ = jax.lax.scan(
        one, init, (landmark_means, landmark_chols, observations, mask)
    )
    return Proposal(mean, sqrt, log_det, log_lik, used)


def rb_proposal(*args, **kwargs) -> Proposal:
    """Conventional Rao-Blackwellized proposal (eqs. 1-3, perfect map): the
    arguments of :func:`erb_proposal`; ``landmark_chols`` is ignored."""
    return erb_proposal(*args, perfect_map=True, **kwargs)


PROPOSAL_FUNCTIONS = {"erb": erb_proposal, "rb": rb_proposal}
