r"""Unscented FastSLAM with the RB or the ERB proposal (Kim, Kim & Chung 2011).

One filter, ``init``/``step``/``run``; the proposal is ``Config.proposal``
(``"rb"``: eqs. 1-3, ``"erb"``: Sec. III-A), everything else is shared, including
the random streams: with the same key both filters draw the same normals for
sampling and the same uniforms for resampling.

One step (one laser scan), for every particle (``vmap``):

1. **Prediction** (Sec. II-A.1): for each control row ``[v, alpha, dt]`` of the scan
   (padding rows with ``dt = 0`` are skipped), an unscented transform over
   :math:`[x; u_{noise}]` with covariance :math:`\operatorname{blockdiag}(P, Q)`,
   :math:`Q = \operatorname{diag}(\sigma_v^2, \sigma_\alpha^2)`, through the car model
   (:mod:`jaxslam.models.vehicle`) gives :math:`\hat x, \bar P`.
2. **Data association** (:mod:`jaxslam.feature.association`).
3. **Proposal** (:mod:`jaxslam.feature.proposals`) from the matched observations,
   batch (default, as the paper) or sequential; **sampling**
   :math:`x \sim \mathcal N(x^{[m]}, P^{[m]})`, after which the pose covariance is
   reset to ``pose_reset_std``. A particle with no match but new landmarks samples from
   the prediction; one with no observation keeps :math:`(\hat x, \bar P)`.
4. **Weight** (eq. 11): :math:`\log w \mathrel{+}= \log \mathcal N(\nu; 0, S)`.
5. **Map update** given the sampled pose: an unscented Kalman update of each matched
   landmark (2 + additive R), and new landmarks through the inverse observation model
   with the unscented transform of :math:`z \sim \mathcal N(z, R)`; evidence and pruning
   (:mod:`jaxslam.feature.landmarks`).
6. **Selective resampling** when ESS < ``resample_threshold`` N.

``init``/``step``/``run`` follow the protocol of every filter (:mod:`jaxslam.driver`):
step keys ``jaxslam.driver.step_keys(key, T)``, ``Info`` with ``ess``, ``resampled`` and
``ancestors``. **Best particle**: the particle with the largest accumulated
log-likelihood (``State.cumulative_log_likelihood``, the sum of its eq. 11 increments
over its history, carried through resampling), as in the grid filters; not the
highest current weight, which after a resampling is the same for every particle.

``Info`` per step carries the weighted pose estimate and covariance, ESS, whether it
resampled and the ancestors, the weight variance, and the paper's Fig. 1 quantity
:math:`\log \sum_m w^{[m]} \det P^{[m]}` for both the ERB and the RB proposal computed
on the same particles (NaN when no particle was updated).

Robustness policy (every case is counted in ``Info``, none is silent):

* **Bad inputs.** A control row with a NaN or inf is run as ``dt = 0`` (skipped)
  (``num_invalid_controls``); a real observation row with a NaN or inf or a range
  ``<= 0`` is masked out (``num_invalid_observations``). Both are zeroed before any
  arithmetic (:func:`clean_inputs`).
* **Weights** live in log space and are normalised with ``logsumexp``; a likelihood
  that underflows gives ``-inf``, and a step in which every weight is ``-inf`` (or
  NaN) leaves uniform weights (:func:`jaxslam.core.resampling.normalize_log_weights`),
  never NaN.
* **Non-finite particles.** A particle whose sampled pose, pose factor or weight
  increment is NaN or inf is not propagated: it keeps its pose, factor and map from
  before the step and its log weight becomes ``-inf``, so resampling drops it
  (``num_nonfinite_particles``). If every particle fails, the step changes nothing,
  not even the weights.
* **Landmark covariances** are symmetrised and their smallest eigenvalue is lifted to
  a floor (``16 eps`` times the trace of the prior, at least the squared resolution
  of the landmark's coordinates), so a downdate that would lose positive
  definiteness is repaired (``num_cov_repairs``); a landmark update or a new
  landmark that is not finite is not stored (``num_rejected_landmarks``). The
  pose factors use clamped closed-form Cholesky factors (:mod:`jaxslam.feature._small`).
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array
from jax.scipy.special import logsumexp

from jaxslam.core.resampling import effective_sample_size, normalize_log_weights, selective_resample
from jaxslam.core.se2 import pose_residual, wrap_angle
from jaxslam.core.sigma import sigma_points, ut_weights
from jaxslam.driver import best_particle, scan_runner
from jaxslam.feature import _small
from jaxslam.feature.association import associate
from jaxslam.feature.landmarks import LandmarkTable, empty_table, free_slots, local_slots
from jaxslam.feature.params import Config, Params
from jaxslam.feature.proposals import (
    PROPOSAL_FUNCTIONS,
    Proposal,
    combine_batch,
    innovation_terms,
    measurement_cov,
)
from jaxslam.models.range_bearing import inverse_observe, observe_unwrapped, sensor_position
from jaxslam.models.vehicle import motion_step


class Observation(NamedTuple):
    """The observations of one scan: ``values (Z, 2)`` range/bearing, ``mask (Z,)``."""

    values: Array
    mask: Array


class State(NamedTuple):
    """Particles.

    Attributes:
        pose_means: ``(N, 3)`` pose of each particle (a sample once it was updated).
        pose_sqrts: ``(N, 3, 3)`` lower factor of the pose covariance accumulated since
            the last sampling (the predicted covariance ``P-bar``).
        log_weights: ``(N,)`` normalised log-weights.
        cumulative_log_likelihood: ``(N,)`` the sum of the particle's log weight
            increments (eq. 11) over its whole history, carried through resampling;
            its argmax is the best particle (:func:`jaxslam.driver.best_particle`).
        landmarks: :class:`LandmarkTable` with leading axis ``N``.
    """

    pose_means: Array
    pose_sqrts: Array
    log_weights: Array
    cumulative_log_likelihood: Array
    landmarks: LandmarkTable


class Info(NamedTuple):
    """Per-step diagnostics (scalars unless noted)."""

    pose_estimate: Array  # (3,) weighted mean pose
    pose_cov: Array  # (3, 3) weighted covariance of the particle poses
    ess: Array  # effective sample size before resampling
    resampled: Array  # bool
    ancestors: Array  # (N,) int32 resampling ancestors (the identity when it did not resample)
    weight_variance: Array  # variance of the normalised weights before resampling
    log_det_proposal_erb: Array  # log sum_m w_m det P_ERB^[m] (updated particles), NaN if none
    log_det_proposal_rb: Array  # the same for the RB proposal on the same particles
    updated: Array  # bool: some particle had a matched observation
    num_matched: Array  # mean matched observations per particle
    num_new: Array  # mean new landmarks per particle
    num_dropped: Array  # new landmarks dropped because a table was full (all particles)
    local_overflow: Array  # most local candidates left out in one particle
    num_landmarks: Array  # landmarks of the best particle
    num_landmarks_mean: Array  # weighted mean number of landmarks
    best_particle: Array  # int32 index of the best particle (largest cumulative_log_likelihood), before resampling
    num_invalid_controls: Array  # int32 control rows with a non-finite value (run as dt = 0)
    num_invalid_observations: Array  # int32 real observation rows that are non-finite or range <= 0 (masked out)
    num_nonfinite_particles: Array  # int32 particles whose new pose/weight was not finite (not propagated)
    num_rejected_landmarks: Array  # int32 landmark updates/initialisations refused as non-finite (all particles)
    num_cov_repairs: Array  # int32 landmark covariance updates whose eigenvalue floor was applied
    weight_entropy: Array  # entropy -sum w log w of the normalised weights before resampling [nats]
    num_ancestors: Array  # int32 distinct particles that survive this step's resampling (N if none)
    num_landmarks_min: Array  # int32 fewest landmarks over the particles
    num_landmarks_max: Array  # int32 most landmarks over the particles
    association_disagreement: Array  # int32 real observations whose decision (match/new/ignore) differs between particles


def cast_params(params: Params, dtype) -> Params:
    """Every leaf of ``params`` as an array of ``dtype``."""
    return jax.tree_util.tree_map(lambda x: jnp.asarray(x, dtype), params)


@partial(jax.jit, static_argnames=("config",))
def init(key: Array, params: Params, config: Config, initial_pose: Array | None = None) -> State:
    """All particles at ``initial_pose`` (default the origin), empty maps, equal weights.

    The dtype of the filter is that of ``initial_pose`` (default float: float32, or
    float64 under ``jax_enable_x64``). Jitted (one compilation per config). ``key`` is
    unused (a deterministic start, as the grid filters' ``init``) but kept first for
    the common signature (:mod:`jaxslam.driver`).
    """
    del key  # the initial state is deterministic; the key keeps the protocol's signature
    pose = jnp.zeros(3) if initial_pose is None else jnp.asarray(initial_pose)
    if not jnp.issubdtype(pose.dtype, jnp.floating):
        pose = pose.astype(float)
    dtype = pose.dtype
    n = config.num_particles
    reset = jnp.asarray(params.pose_reset_std, dtype)
    return State(
        pose_means=jnp.broadcast_to(pose, (n, 3)),
        pose_sqrts=jnp.broadcast_to(reset * jnp.eye(3, dtype=dtype), (n, 3, 3)),
        log_weights=jnp.full((n,), -jnp.log(jnp.asarray(n, dtype))),
        cumulative_log_likelihood=jnp.zeros((n,), dtype),
        landmarks=empty_table(config.capacity, dtype, (n,)),
    )


# ----------------------------------------------------------------------- one particle


# Augmented sigma points over [pose (3); speed noise; steering noise] in filterpy order
# [centre, +cols (5), -cols (5)]: which of the 7 pose points (centre, +3, -3), which
# speed-noise sign and which of the 3 steering values (centre, +, -) each one uses.
_POSE_OF_POINT = np.array([0, 1, 2, 3, 0, 0, 4, 5, 6, 0, 0])
_SPEED_SIGN = np.array([0, 0, 0, 0, 1, 0, 0, 0, 0, -1, 0], np.float32)
_STEER_OF_POINT = np.array([0, 0, 0, 0, 0, 1, 0, 0, 0, 0, 2])


def predict_pose(pose: Array, pose_sqrt: Array, controls: Array, params: Params) -> tuple[Array, Array]:
    """Unscented prediction over ``[pose; speed noise; steering noise]`` (n = 5) through
    :func:`jaxslam.models.vehicle.car_motion` for each control row ``(K, 3)``; rows with
    ``dt <= 0`` are skipped. Returns the predicted mean and lower Cholesky factor.

    The 11 sigma points have only 7 distinct headings and 3 distinct steering angles,
    so the trigonometry is evaluated on those alone and the car model applied through
    :func:`jaxslam.models.vehicle.motion_step` (the same numbers as the generic
    transform, at a third of the cost).
    """
    dtype = pose.dtype
    mean_w, cov_w, lam = ut_weights(5, params.ut_predict, dtype)
    gamma = jnp.sqrt(5 + lam)
    speed_sign = jnp.asarray(_SPEED_SIGN, dtype)

    def row(carry, control):
        mean, sqrt = carry
        off = gamma * sqrt.T
        poses = jnp.concatenate([mean[None], mean + off, mean - off], 0)[_POSE_OF_POINT]  # (11, 3)
        heading7 = jnp.concatenate([mean[2:3], mean[2] + off[:, 2], mean[2] - off[:, 2]])
        cos7, sin7 = jnp.cos(heading7), jnp.sin(heading7)
        cos, sin = cos7[_POSE_OF_POINT], sin7[_POSE_OF_POINT]
        steer_noise = gamma * params.steering_std
        tan3 = jnp.tan(control[1] + jnp.stack([jnp.zeros((), dtype), steer_noise, -steer_noise]))
        tan = tan3[_STEER_OF_POINT]
        speed = control[0] + speed_sign * (gamma * params.speed_std)
        dt = control[2]
        moved = motion_step(poses, cos, sin, speed, tan, dt, params.geometry)
        heading = moved[0, 2] + _small.wsum(mean_w, wrap_angle(moved[:, 2] - moved[0, 2]))
        new_mean = jnp.stack([_small.wsum(mean_w, moved[:, 0]), _small.wsum(mean_w, moved[:, 1]), wrap_angle(heading)])
        dev = moved - new_mean
        dev = jnp.stack([dev[:, 0], dev[:, 1], wrap_angle(dev[:, 2])], -1)
        cov = _small.weighted_outer(cov_w, dev, dev)
        new_sqrt = _small.chol3(cov)
        ok = dt > 0
        return (jnp.where(ok, new_mean, mean), jnp.where(ok, new_sqrt, sqrt)), None

    (mean, sqrt), _ = jax.lax.scan(row, (pose, pose_sqrt), controls)
    return mean, sqrt


def _cov_floor(cov: Array, mean: Array) -> Array:
    """The smallest eigenvalue a landmark covariance is allowed (dtype-aware).

    ``max(16 eps tr(cov), (4 eps (|mean| + 1 m))^2)``: the first keeps a 2x2
    Cholesky accurate, the second is the squared resolution of the landmark's
    coordinates, below which a variance is rounding noise (float32: 0.5 um at the
    origin, 0.1 mm at 200 m; float64: negligible).
    """
    eps = jnp.finfo(cov.dtype).eps
    resolution = 4.0 * eps * (jnp.max(jnp.abs(mean)) + 1.0)
    return jnp.maximum(16.0 * eps * jnp.trace(cov), resolution * resolution)


def update_landmark(
    pose: Array, mean: Array, cov: Array, observation: Array, params: Params
) -> tuple[Array, Array, Array, Array]:
    """Unscented Kalman update of one landmark given a (sampled) pose (n = 2 sigma
    points over the landmark, additive R).

    The updated covariance ``P - K S K^T`` is symmetrised and its smallest eigenvalue
    lifted to :func:`_cov_floor` of the prior, so a downdate that would lose positive
    definiteness in finite precision (a tiny ``R``, a near-singular prior) is repaired
    rather than stored. An update that is not finite anyway is refused: the prior is
    returned unchanged.

    Returns:
        ``(mean, cov, ok, repaired)``: ``ok`` False where the update was refused,
        ``repaired`` True where the eigenvalue floor was applied.
    """
    dtype = mean.dtype
    mean_w, cov_w, _ = ut_weights(2, params.ut_landmark, dtype)
    points = sigma_points(mean, _small.chol2(cov), params.ut_landmark)
    sensor = sensor_position(pose, jnp.asarray(params.sensor_offset, dtype))
    count = points.shape[0]
    # bearings unwrapped about the centre point's, so that their weighted mean is valid
    y = observe_unwrapped(jnp.broadcast_to(sensor, (count, 2)), jnp.broadcast_to(pose[2], (count,)), points)
    y_mean = _small.wsum(mean_w, y, axis=0)
    dev = y - y_mean
    s = _small.weighted_outer(cov_w, dev, dev) + measurement_cov(params, dtype)
    cross = _small.weighted_outer(cov_w, points - mean, dev)
    s_inv, _ = _small.inv2(s)
    gain = _small.matmul(cross, s_inv)
    nu = jnp.stack([observation[0] - y_mean[0], wrap_angle(observation[1] - y_mean[1])])
    gain_s_gain = _small.matmul(_small.matmul(gain, s), gain.T)
    new_cov, repaired = _small.floor_eigenvalues2(cov - gain_s_gain, _cov_floor(cov, mean))
    new_mean = mean + _small.matvec(gain, nu)
    ok = jnp.all(jnp.isfinite(new_mean)) & jnp.all(jnp.isfinite(new_cov))
    return jnp.where(ok, new_mean, mean), jnp.where(ok, new_cov, cov), ok, repaired & ok


def initialise_landmark(pose: Array, observation: Array, params: Params) -> tuple[Array, Array, Array]:
    """Landmark mean and covariance from one observation: the unscented transform of
    the inverse observation model over ``z ~ N(observation, R)``.

    The covariance is symmetrised with its smallest eigenvalue lifted to
    :func:`_cov_floor` of itself. Returns ``(mean, cov, ok)``, ``ok`` False where
    the result is not finite (the caller does not store it).
    """
    dtype = pose.dtype
    mean_w, cov_w, _ = ut_weights(2, params.ut_landmark, dtype)
    r_sqrt = jnp.diag(jnp.stack([params.range_std, params.bearing_std]))
    points = sigma_points(observation, r_sqrt, params.ut_landmark)
    offset = jnp.asarray(params.sensor_offset, dtype)
    m = jax.vmap(inverse_observe, (None, 0, None))(pose, points, offset)
    m_mean = _small.wsum(mean_w, m, axis=0)
    dev = m - m_mean
    cov = _small.weighted_outer(cov_w, dev, dev)
    cov, _ = _small.floor_eigenvalues2(cov, _cov_floor(cov, m_mean))
    ok = jnp.all(jnp.isfinite(m_mean)) & jnp.all(jnp.isfinite(cov))
    return m_mean, cov, ok


class _ParticleOut(NamedTuple):
    pose: Array
    pose_sqrt: Array
    log_weight_increment: Array
    landmarks: LandmarkTable
    has_match: Array
    log_det_erb: Array
    log_det_rb: Array
    num_matched: Array
    num_new: Array
    num_dropped: Array
    local_overflow: Array
    finite: Array
    num_rejected_landmarks: Array
    num_cov_repairs: Array
    matched: Array  # (k,) matched observations
    new: Array  # (k,) observations that started a landmark


def _particle_step(
    key: Array,
    pose: Array,
    pose_sqrt: Array,
    table: LandmarkTable,
    controls: Array,
    observation: Observation,
    params: Params,
    config: Config,
) -> _ParticleOut:
    dtype = pose.dtype
    capacity = config.capacity
    z, mask = observation.values, observation.mask
    offset = jnp.asarray(params.sensor_offset, dtype)
    half_fov = 0.5 * params.fov

    # 1. prediction
    pred_mean, pred_sqrt = predict_pose(pose, pose_sqrt, controls, params)

    # 2. association against the local part of the map
    sensor_xy = sensor_position(pred_mean, offset)
    local, local_valid, overflow = local_slots(
        table, sensor_xy, pred_mean[2], params.max_range, half_fov, params.candidate_margin, config.local_size
    )
    assoc = associate(pred_mean, pred_sqrt, table, local, local_valid, z, mask, params, config.candidates)
    matched = assoc.matched
    has_match = jnp.any(matched)
    has_new = jnp.any(assoc.new)

    # 3. proposals (both, from one set of sigma-point predictions in batch mode)
    if config.update == "batch":
        terms_erb = jax.vmap(innovation_terms, (0, 0, None, None))(assoc.sigma_obs, z, params, False)
        terms_rb = jax.vmap(innovation_terms, (0, 0, None, None))(assoc.sigma_obs, z, params, True)
        prop_erb = combine_batch(pred_mean, pred_sqrt, terms_erb, matched)
        prop_rb = combine_batch(pred_mean, pred_sqrt, terms_rb, matched)
        own = prop_erb if config.proposal == "erb" else prop_rb
    else:
        args = (pred_mean, pred_sqrt, assoc.landmark_means, assoc.landmark_chols, z, matched, params, True)
        own = PROPOSAL_FUNCTIONS[config.proposal](*args)
        if config.compare_proposals:
            other = PROPOSAL_FUNCTIONS["rb" if config.proposal == "erb" else "erb"](*args)
        else:
            nan = jnp.full((), jnp.nan, dtype)
            other = Proposal(own.mean, own.sqrt_cov, nan, own.log_likelihood, own.num_used)
        prop_erb, prop_rb = (own, other) if config.proposal == "erb" else (other, own)

    # 3b. sampling, the same normals whatever the proposal; 4. weight (eq. 11)
    eps = jax.random.normal(key, (3,), dtype)
    from_proposal = own.mean + _small.matvec(own.sqrt_cov, eps)
    from_prediction = pred_mean + _small.matvec(pred_sqrt, eps)
    sampled = jnp.where(has_match, from_proposal, jnp.where(has_new, from_prediction, pred_mean))
    sampled = sampled.at[2].set(wrap_angle(sampled[2]))
    reset = params.pose_reset_std * jnp.eye(3, dtype=dtype)
    new_sqrt = jnp.where(has_match | has_new, reset, pred_sqrt)
    log_w_inc = jnp.where(has_match, own.log_likelihood, jnp.zeros((), dtype))
    # A particle whose new pose, factor or weight is not finite (-inf, an underflowed
    # likelihood, is a valid weight) keeps its old pose and map and gets weight zero.
    finite = (
        jnp.all(jnp.isfinite(sampled)) & jnp.all(jnp.isfinite(new_sqrt)) & ~jnp.isnan(log_w_inc) & (log_w_inc < jnp.inf)
    )

    # 5. map. Everything is read from the old table before any slot is written, so the
    # scatters below can update the tables in place.
    # 5a. evidence over the local set: +1 matched, -1 expected visible but missed.
    # Visible: at least `margin` inside the range and inside the field of view's edge
    # (forward >= r cos(half_fov) + margin; no arctangent needed).
    local_means = table.means[jnp.minimum(local, capacity - 1)]
    sensor_xy = sensor_position(sampled, offset)
    cos_h, sin_h = jnp.cos(sampled[2]), jnp.sin(sampled[2])
    rel = local_means - sensor_xy
    dist = jnp.sqrt(rel[:, 0] ** 2 + rel[:, 1] ** 2)
    forward = cos_h * rel[:, 0] + sin_h * rel[:, 1]
    margin = params.visibility_margin
    visible = local_valid & (dist < params.max_range - margin) & (forward >= dist * jnp.cos(half_fov) + margin)
    local_matched = jnp.any((local[:, None] == assoc.slots[None, :]) & matched[None, :], axis=1)
    delta = jnp.where(local_matched, 1.0, jnp.where(visible, -1.0, 0.0)).astype(dtype)
    local_evidence = table.evidence[jnp.minimum(local, capacity - 1)] + delta
    alive = local_evidence >= params.prune_threshold
    num_pruned = jnp.where(finite, jnp.sum(local_valid & ~alive), 0)
    # Writes to slot `capacity` are dropped: that is how a failed particle keeps its map.
    local_written = jnp.where(finite, local, capacity)

    # 5b. matched landmarks: unscented update given the sampled pose (a non-finite
    # update is refused and the landmark kept as it was)
    lm_means, lm_covs, lm_ok, lm_repaired = jax.vmap(update_landmark, (None, 0, 0, 0, None))(
        sampled, assoc.landmark_means, table.covs[jnp.minimum(assoc.slots, capacity - 1)], z, params
    )
    lm_slots = jnp.where(finite & lm_ok, assoc.slots, capacity)
    means = table.means.at[lm_slots].set(lm_means, mode="drop")
    covs = table.covs.at[lm_slots].set(lm_covs, mode="drop")

    evidence = table.evidence.at[local_written].set(local_evidence, mode="drop")
    active = table.active.at[local_written].set(alive & local_valid, mode="drop")

    # 5c. new landmarks in the first free slots (a non-finite one is not stored)
    k = z.shape[0]
    free = free_slots(active, k)
    rank = jnp.cumsum(assoc.new) - 1
    new_means, new_covs, new_ok = jax.vmap(initialise_landmark, (None, 0, None))(sampled, z, params)
    storable = assoc.new & finite & new_ok
    new_slots = jnp.where(storable, free[jnp.clip(rank, 0, k - 1)], capacity)
    means = means.at[new_slots].set(new_means, mode="drop")
    covs = covs.at[new_slots].set(new_covs, mode="drop")
    evidence = evidence.at[new_slots].set(jnp.broadcast_to(params.new_evidence, (k,)), mode="drop")
    active = active.at[new_slots].set(True, mode="drop")
    added = jnp.sum(new_slots < capacity)
    count = table.count + added - num_pruned
    dropped = jnp.sum(storable) - added
    rejected = jnp.sum(finite & ((matched & ~lm_ok) | (assoc.new & ~new_ok)))

    return _ParticleOut(
        pose=jnp.where(finite, sampled, pose),
        pose_sqrt=jnp.where(finite, new_sqrt, pose_sqrt),
        log_weight_increment=jnp.where(finite, log_w_inc, -jnp.inf),
        landmarks=LandmarkTable(means, covs, evidence, active, count.astype(jnp.int32)),
        has_match=has_match & finite,
        log_det_erb=prop_erb.log_det_cov,
        log_det_rb=prop_rb.log_det_cov,
        num_matched=jnp.sum(matched),
        num_new=jnp.sum(assoc.new),
        num_dropped=dropped,
        local_overflow=overflow,
        finite=finite,
        num_rejected_landmarks=rejected,
        num_cov_repairs=jnp.sum(finite & matched & lm_repaired),
        matched=matched,
        new=assoc.new,
    )


# ----------------------------------------------------------------------- the filter


def _disagreement(matched: Array, new: Array, mask: Array) -> Array:
    """Real observations ``(k,)`` whose decision (matched, new or ignored) is not the
    same in every particle (``matched``, ``new``: ``(N, k)``)."""
    decision = matched.astype(jnp.int32) + 2 * new.astype(jnp.int32)
    differs = jnp.any(decision != decision[:1], axis=0)
    return jnp.sum(differs & mask).astype(jnp.int32)


def _weighted_log_det(log_weights: Array, log_dets: Array, used: Array) -> Array:
    """``log(sum_m w_m det_m / sum_m w_m)`` over the used particles; NaN if none."""
    lw = jnp.where(used, log_weights, -jnp.inf)
    total = logsumexp(lw)
    value = logsumexp(jnp.where(used, lw + log_dets, -jnp.inf)) - total
    return jnp.where(jnp.any(used), value, jnp.nan)


def _summary(state: State, log_weights: Array) -> tuple[Array, Array, Array]:
    """Weighted mean pose, covariance of the particle mixture and the weights.

    The mean heading is averaged about the pose of the highest-weight particle (the
    particle nearest the mean, so that the residuals do not wrap); that reference is
    a numerical choice only, not the best particle."""
    weights = jnp.exp(log_weights)
    ref = state.pose_means[jnp.argmax(log_weights)]
    dev = jax.vmap(pose_residual, (0, None))(state.pose_means, ref)
    shift = weights @ dev
    estimate = ref + shift
    estimate = estimate.at[2].set(wrap_angle(estimate[2]))
    dev = dev - shift
    spread = jnp.einsum("m,mi,mj->ij", weights, dev, dev)
    own = jnp.einsum("m,mij,mkj->ik", weights, state.pose_sqrts, state.pose_sqrts)
    return estimate, spread + own, weights


def _finish(
    key: Array,
    state: State,
    out: _ParticleOut | None,
    params: Params,
    config: Config,
    invalid: tuple[Array, Array],
    observation_mask: Array,
) -> tuple[State, Info]:
    dtype = state.pose_means.dtype
    log_w = normalize_log_weights(state.log_weights)
    estimate, cov, weights = _summary(state, log_w)
    best = best_particle(state)
    ess = effective_sample_size(log_w)
    if out is None:
        nan = jnp.full((), jnp.nan, dtype)
        zero = jnp.zeros((), dtype)
        izero = jnp.zeros((), jnp.int32)
        extra = dict(
            log_det_proposal_erb=nan, log_det_proposal_rb=nan, updated=jnp.zeros((), bool),
            num_matched=zero, num_new=zero, num_dropped=izero, local_overflow=izero,
            num_nonfinite_particles=izero, num_rejected_landmarks=izero, num_cov_repairs=izero,
            association_disagreement=izero,
        )
        resampled = jnp.zeros((), bool)
        ancestors = jnp.arange(config.num_particles, dtype=jnp.int32)
        new_state = state._replace(log_weights=log_w)
    else:
        extra = dict(
            log_det_proposal_erb=_weighted_log_det(log_w, out.log_det_erb, out.has_match),
            log_det_proposal_rb=_weighted_log_det(log_w, out.log_det_rb, out.has_match),
            updated=jnp.any(out.has_match),
            num_matched=jnp.mean(out.num_matched.astype(dtype)),
            num_new=jnp.mean(out.num_new.astype(dtype)),
            num_dropped=jnp.sum(out.num_dropped).astype(jnp.int32),
            local_overflow=jnp.max(out.local_overflow).astype(jnp.int32),
            num_nonfinite_particles=jnp.sum(~out.finite).astype(jnp.int32),
            num_rejected_landmarks=jnp.sum(out.num_rejected_landmarks).astype(jnp.int32),
            num_cov_repairs=jnp.sum(out.num_cov_repairs).astype(jnp.int32),
            association_disagreement=_disagreement(out.matched, out.new, observation_mask),
        )
        ancestors, resampled, new_log_w = selective_resample(key, log_w, params.resample_threshold, config.resampler)
        new_state = jax.lax.cond(
            resampled,
            lambda s: jax.tree_util.tree_map(lambda x: x[ancestors], s),
            lambda s: s,
            state._replace(log_weights=new_log_w),
        )
    info = Info(
        pose_estimate=estimate,
        pose_cov=cov,
        ess=ess,
        resampled=resampled,
        ancestors=ancestors.astype(jnp.int32),
        weight_variance=jnp.var(weights),
        num_landmarks=state.landmarks.count[best],
        num_landmarks_mean=weights @ state.landmarks.count.astype(dtype),
        best_particle=best.astype(jnp.int32),
        num_invalid_controls=invalid[0],
        num_invalid_observations=invalid[1],
        weight_entropy=-jnp.sum(jnp.where(weights > 0, weights * log_w, 0.0)),
        num_ancestors=jnp.sum(jnp.zeros(config.num_particles, jnp.int32).at[ancestors].set(1)),
        num_landmarks_min=jnp.min(state.landmarks.count),
        num_landmarks_max=jnp.max(state.landmarks.count),
        **extra,
    )
    return new_state, info


def clean_inputs(control: Array, observation: Observation) -> tuple[Array, Observation, Array, Array]:
    """Apply the input policy (module docstring) to one step's inputs.

    A control row with a non-finite value becomes a zero row (``dt = 0``: skipped);
    a real observation row with a non-finite value or a range ``<= 0`` is masked out
    and zeroed, so no NaN reaches the arithmetic (a masked NaN would still poison
    products such as ``0 * NaN``).

    Returns:
        ``(control, observation, num_invalid_controls, num_invalid_observations)``.
    """
    control_ok = jnp.all(jnp.isfinite(control), axis=-1)
    values, mask = observation.values, observation.mask
    obs_ok = jnp.all(jnp.isfinite(values), axis=-1) & (values[:, 0] > 0)
    control = jnp.where(control_ok[:, None], control, jnp.zeros((), control.dtype))
    values = jnp.where(obs_ok[:, None], values, jnp.zeros((), values.dtype))
    num_controls = jnp.sum(~control_ok).astype(jnp.int32)
    num_observations = jnp.sum(mask & ~obs_ok).astype(jnp.int32)
    return control, Observation(values, mask & obs_ok), num_controls, num_observations


@partial(jax.jit, static_argnames=("config",))
def step(
    key: Array, state: State, control: Array, observation: Observation, params: Params, config: Config
) -> tuple[State, Info]:
    """One scan: predict over the control rows ``(K, 3)``, associate, sample from the
    proposal, weight, update the maps, resample if the ESS is low.

    Args:
        key: PRNG key of this step.
        state: particles.
        control: ``(K, 3)`` rows ``[speed, steering, dt]``; ``dt = 0`` rows are padding.
        observation: :class:`Observation` of this scan.
        params: traced parameters.
        config: static configuration.

    Returns:
        ``(state, info)``; ``info.ancestors`` are the resampling ancestors ``(N,)``
        (the identity when it did not resample).
    """
    dtype = state.pose_means.dtype
    params = cast_params(params, dtype)
    control = jnp.asarray(control, dtype)
    observation = Observation(jnp.asarray(observation.values, dtype), jnp.asarray(observation.mask, bool))
    control, observation, *invalid = clean_inputs(control, observation)
    k_sample, k_resample = jax.random.split(key)
    particle_keys = jax.random.split(k_sample, config.num_particles)

    def particles_step(state, observation):
        return jax.vmap(_particle_step, (0, 0, 0, 0, None, None, None, None))(
            particle_keys, state.pose_means, state.pose_sqrts, state.landmarks, control, observation, params, config
        )

    def active_step(state):
        width = observation.values.shape[0]
        half = (width + 1) // 2
        if width < 8:
            out = particles_step(state, observation)
        else:
            # Most scans fill few of the padded observation slots (Victoria Park: 82%
            # at most 7 of 14); such a scan runs on the first half of the slots. The
            # result is the same: padding slots are masked out everywhere.
            def first_half(state):
                out = particles_step(state, Observation(observation.values[:half], observation.mask[:half]))
                pad = ((0, 0), (0, width - half))
                return out._replace(matched=jnp.pad(out.matched, pad), new=jnp.pad(out.new, pad))

            fits = ~jnp.any(observation.mask[half:])
            out = jax.lax.cond(fits, first_half, lambda s: particles_step(s, observation), state)
        # If every particle failed, the step changes nothing (not even the weights).
        any_finite = jnp.any(out.finite)
        log_weights = jnp.where(any_finite, state.log_weights + out.log_weight_increment, state.log_weights)
        cumulative = jnp.where(
            any_finite, state.cumulative_log_likelihood + out.log_weight_increment, state.cumulative_log_likelihood
        )
        updated = State(out.pose, out.pose_sqrt, log_weights, cumulative, out.landmarks)
        return _finish(k_resample, updated, out, params, config, invalid, observation.mask)

    def idle_step(state):
        return _finish(k_resample, state, None, params, config, invalid, observation.mask)

    if not config.skip_stationary:
        return active_step(state)
    moving = jnp.any((control[:, 2] > 0) & (control[:, 0] != 0))
    return jax.lax.cond(moving, active_step, idle_step, state)


run = scan_runner(step)
run.__doc__ = """Scan :func:`step` over a sequence (:func:`jaxslam.driver.scan_runner`).

Args:
    key: PRNG key; step ``t`` uses ``jaxslam.driver.step_keys(key, T)[t]``.
    state: from :func:`init`.
    controls: ``(T, K, 3)``.
    observations: :class:`Observation` stacked over ``T``: ``values (T, Z, 2)``,
        ``mask (T, Z)``.
    params, config: as for :func:`step`.

Returns:
    ``(final_state, infos)`` with every :class:`Info` field stacked over ``T``.
"""
