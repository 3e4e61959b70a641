r"""Per-particle maximum-likelihood data association with a chi-square gate.

For one particle, with predicted pose :math:`\hat x` and the local slots of its
landmark table (:func:`jaxslam.feature.landmarks.local_slots`):

1. **Pre-selection.** Each observation is placed in the world from :math:`\hat x`
   (inverse observation model) and the ``candidates`` nearest local landmarks by
   Euclidean distance are kept (``lax.top_k``).
2. **Sigma-point Mahalanobis test.** For each candidate the 11 sigma points of
   :math:`[x; m]` with covariance :math:`\operatorname{blockdiag}(\bar P, \Sigma_m)`
   are pushed through the observation model (Sec. III-A, last paragraph: sigma points
   that include the landmark covariance and, additively, :math:`R`), giving
   :math:`\hat y` and :math:`\mathcal S` and :math:`d^2 = \nu^T \mathcal S^{-1} \nu`.
3. **Maximum likelihood.** Among candidates with :math:`d^2 <` ``gate_associate`` the
   one of largest likelihood (smallest :math:`d^2 + \log|\mathcal S|`) is taken. If two
   observations of a scan pick the same landmark only the closer one keeps it.
4. **New landmarks.** An observation whose every candidate has
   :math:`d^2 >` ``gate_new`` (or that has no candidate) starts a new landmark;
   observations between the gates are ignored.

The sigma-point predictions of the chosen candidate are returned so the proposal
reuses them (no second evaluation of the observation model), and so is the log
predictive density of each observation under its most likely candidate, gate or no
gate, :math:`\max_c \log \mathcal N(\nu_c; 0, \mathcal S_c)` (``-inf`` without a
candidate), for the mixture likelihood of :mod:`jaxslam.feature.particle`.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax import Array

from jaxslam.feature import _small
from jaxslam.feature.landmarks import LandmarkTable, gather
from jaxslam.feature.params import Params
from jaxslam.feature.proposals import innovation_terms, sigma_observations
from jaxslam.models.range_bearing import inverse_observe


class Association(NamedTuple):
    r"""Association of the observations ``(k,)`` of one scan for one particle.

    Attributes:
        slots: ``(k,)`` table slot of the matched landmark (``C`` if none).
        matched: ``(k,)`` matched to a stored landmark.
        new: ``(k,)`` starts a new landmark.
        distance_sq: ``(k,)`` squared Mahalanobis distance of the best candidate (inf
            if none).
        sigma_obs: ``(k, 11, 2)`` sigma-point predictions of the chosen candidate.
        landmark_means: ``(k, 2)`` chosen landmark means.
        landmark_chols: ``(k, 2, 2)`` their Cholesky factors.
        log_density: ``(k,)`` :math:`\log \mathcal N(\nu; 0, \mathcal S)` of the
            candidate of smallest :math:`d^2 + \log|\mathcal S|`, inside the gates or
            not (``-inf`` if the observation has no candidate).
    """

    slots: Array
    matched: Array
    new: Array
    distance_sq: Array
    sigma_obs: Array
    landmark_means: Array
    landmark_chols: Array
    log_density: Array


def _smallest(values: Array, k: int) -> tuple[Array, Array]:
    """The ``k`` smallest entries of each row ``(m, s)`` and their indices, by ``k``
    rounds of min-reduce and masking (faster on CPU than ``lax.top_k`` for small k)."""
    cols = jnp.arange(values.shape[-1])
    found_v, found_i = [], []
    for _ in range(k):
        low = jnp.min(values, axis=-1)
        idx = jnp.min(jnp.where(values == low[:, None], cols, values.shape[-1]), axis=-1)
        idx = jnp.minimum(idx, values.shape[-1] - 1)
        found_v.append(low)
        found_i.append(idx)
        values = jnp.where(cols == idx[:, None], jnp.inf, values)
    return jnp.stack(found_v, -1), jnp.stack(found_i, -1)


def associate(
    pose_mean: Array,
    pose_sqrt: Array,
    table: LandmarkTable,
    local: Array,
    local_valid: Array,
    observations: Array,
    mask: Array,
    params: Params,
    num_candidates: int,
) -> Association:
    """Associate the observations ``(k, 2)`` of one scan for one particle.

    Args:
        pose_mean, pose_sqrt: predicted pose and a square root of its covariance.
        table: the particle's landmark table.
        local, local_valid: ``(s,)`` local slots and their validity.
        observations: ``(k, 2)`` range, bearing.
        mask: ``(k,)`` real observations.
        params: filter parameters.
        num_candidates: candidates per observation for the sigma-point test (static).
    """
    dtype = pose_mean.dtype
    capacity = table.active.shape[0]
    offset = jnp.asarray(params.sensor_offset, dtype)
    local_means, local_covs = gather(table, local)
    endpoints = jax.vmap(inverse_observe, (None, 0, None))(pose_mean, observations, offset)
    d2 = (endpoints[:, None, 0] - local_means[None, :, 0]) ** 2 + (endpoints[:, None, 1] - local_means[None, :, 1]) ** 2
    d2 = jnp.where(local_valid[None, :], d2, jnp.inf)
    cand_d2, cand = _smallest(d2, num_candidates)  # (k, n)
    cand_valid = jnp.isfinite(cand_d2) & mask[:, None]
    cand_means = local_means[cand]
    cand_chols = _small.chol2(local_covs[cand])

    sig = sigma_observations(pose_mean, pose_sqrt, cand_means, cand_chols, params)  # (k, n, 11, 2)
    terms = jax.vmap(jax.vmap(innovation_terms, (0, None, None, None)), (0, 0, None, None))(
        sig, observations, params, False
    )
    s_inv, s_logdet = _small.inv2(terms.innovation_cov)
    maha = _small.quad2(terms.innovation, s_inv)
    maha = jnp.where(cand_valid, maha, jnp.inf)
    gated = maha < params.gate_associate
    score = jnp.where(gated, maha + s_logdet, jnp.inf)
    best = jnp.argmin(score, axis=1)
    matched = jnp.any(gated, axis=1)
    rows = jnp.arange(observations.shape[0])
    best_maha = jnp.min(maha, axis=1)
    # Double where: a candidate-less row has maha = inf; its cotangent must stay 0.
    densest = jnp.min(jnp.where(cand_valid, maha + s_logdet, jnp.inf), axis=1)
    has_cand = jnp.any(cand_valid, axis=1)
    log_density = jnp.where(
        has_cand, -0.5 * jnp.where(has_cand, densest, 0.0) - jnp.log(2.0 * jnp.pi).astype(dtype), -jnp.inf
    )
    chosen_maha = maha[rows, best]
    new = mask & (best_maha > params.gate_new)
    slots = jnp.where(matched, local[cand[rows, best]], capacity)

    # One landmark, one observation: the closer observation keeps a shared landmark.
    same = (slots[:, None] == slots[None, :]) & matched[:, None] & matched[None, :]
    closer = (chosen_maha[None, :] < chosen_maha[:, None]) | (
        (chosen_maha[None, :] == chosen_maha[:, None]) & (rows[None, :] < rows[:, None])
    )
    beaten = jnp.any(same & closer & (rows[None, :] != rows[:, None]), axis=1)
    matched = matched & ~beaten
    slots = jnp.where(matched, slots, capacity)

    return Association(
        slots=slots,
        matched=matched,
        new=new,
        distance_sq=best_maha,
        sigma_obs=sig[rows, best],
        landmark_means=cand_means[rows, best],
        landmark_chols=cand_chols[rows, best],
        log_density=log_density,
    )
