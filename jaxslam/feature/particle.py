r"""One particle's part of a landmark SLAM step, and the landmark kernels.

:func:`particle_step` is steps 1-5 of :mod:`jaxslam.feature.filter` for one particle
(``vmap``-ed over the particles by :func:`jaxslam.feature.filter.step`): the unscented
prediction through the car model (:func:`predict_pose`), association against the
local part of the particle's map, the RB or ERB proposal and the sample drawn from it,
the weight increment (eq. 11), and the map update given the sampled pose: an
unscented Kalman update of each matched landmark (:func:`update_landmark`, 2 sigma
dimensions, additive :math:`R`), new landmarks from the inverse observation model
(:func:`initialise_landmark`), evidence and pruning. The models themselves are those
of :mod:`jaxslam.models.vehicle` and :mod:`jaxslam.models.range_bearing`.
:func:`particle_writes` is the same step with the map update returned as the writes to
make (:class:`TableWrites`), which the filter applies (:func:`apply_writes`) after its
branches over the observation width: written inside a branch, the carried tables
would be copied whole on every scan.

Landmark covariances are symmetrised and their smallest eigenvalue lifted to a floor
(``_cov_floor``: ``max(16 eps tr(cov), (4 eps (|mean| + 1 m))^2)`` with the dtype's
machine epsilon ``eps``), so a downdate that would lose positive definiteness is
repaired; an update or a new landmark that is not finite is not stored. A particle
whose sampled pose, factor or weight increment is not finite keeps its pose and map
(writes to slot ``capacity`` are dropped) and is flagged in :class:`ParticleOut`.

The weight increment is the paper's (``Config.likelihood = "gated"``),
:math:`\log \mathcal N(\nu_M; 0, \mathcal S_M)` of the matched observations
:math:`M` jointly, 0 without a match; observations outside the association gate
contribute nothing. As a likelihood of the noise levels this is biased towards small
noise: the gate is a fixed Mahalanobis distance, so shrinking :math:`R` shrinks the
gate, the innovations that would count against the smaller noise fall out of it, and
the matched ones alone are better explained by a smaller :math:`R` (with a 95% gate
on two degrees of freedom the matched innovations have :math:`E[d^2] = 1.69`, not 2).
``Config.likelihood = "mixture"`` scores every observation :math:`j` of the scan
under a detection/clutter mixture,

.. math:: \log g = \sum_j \log\big(P_D\,\mathcal N(\nu_j; 0, \mathcal S_j)
          + (1 - P_D)\,\lambda\big), \qquad \lambda = \frac{1}{r_{max}\,\mathrm{fov}},

with :math:`\nu_j, \mathcal S_j` of its most likely candidate (gate or no gate;
:class:`jaxslam.feature.association.Association` ``log_density``) and the uniform
density :math:`\lambda` of a new landmark or a false detection in range and bearing.
Innovations far out count against a small noise through the mixture, smoothly, so
its gradient has no such bias; the observations are scored one by one (their
correlation through the shared pose is left out: a composite likelihood). The
association, proposal and map update are the same under both.

One module of about 400 lines: the particle's step and the landmark kernels it calls
(prediction, landmark update and initialisation, the table writes) are steps 1-5 of
the paper in order, and read best side by side.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from jaxslam.core.se2 import wrap_angle
from jaxslam.core.sigma import sigma_points, ut_weights
from jaxslam.feature import _small
from jaxslam.feature.association import associate
from jaxslam.feature.landmarks import LandmarkTable, free_slots, local_slots
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
    lifted to the floor (``_cov_floor``) of the prior, so a downdate that would lose positive
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
    the floor (``_cov_floor``) of itself. Returns ``(mean, cov, ok)``, ``ok`` False where
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


class ParticleOut(NamedTuple):
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


def particle_writes(
    key: Array,
    pose: Array,
    pose_sqrt: Array,
    table: LandmarkTable,
    controls: Array,
    observation: Observation,
    params: Params,
    config: Config,
) -> tuple[ParticleOut, TableWrites]:
    """Steps 1-5 for one particle, the map update as the writes to make
    (:class:`TableWrites`, :func:`apply_writes`) rather than a new table: the filter
    applies them after its branches over the observation width, so that no branch
    writes into (and XLA does not copy) the carried tables. ``out.landmarks`` is None."""
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
    if config.likelihood == "mixture":
        log_clutter = jnp.log1p(-params.detection_probability) - jnp.log(params.max_range * params.fov)
        per_obs = jnp.logaddexp(jnp.log(params.detection_probability) + assoc.log_density, log_clutter)
        log_w_inc = jnp.sum(jnp.where(mask, per_obs, 0.0)).astype(dtype)
    else:
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
    local_active = alive & local_valid
    active = table.active.at[local_written].set(local_active, mode="drop")

    # 5c. new landmarks in the first free slots (a non-finite one is not stored)
    k = z.shape[0]
    free = free_slots(active, k)
    rank = jnp.cumsum(assoc.new) - 1
    new_means, new_covs, new_ok = jax.vmap(initialise_landmark, (None, 0, None))(sampled, z, params)
    storable = assoc.new & finite & new_ok
    new_slots = jnp.where(storable, free[jnp.clip(rank, 0, k - 1)], capacity)
    added = jnp.sum(new_slots < capacity)
    count = table.count + added - num_pruned
    dropped = jnp.sum(storable) - added
    rejected = jnp.sum(finite & ((matched & ~lm_ok) | (assoc.new & ~new_ok)))
    writes = TableWrites(
        update_slots=lm_slots, update_means=lm_means, update_covs=lm_covs,
        local_slots=local_written, local_evidence=local_evidence, local_active=local_active,
        new_slots=new_slots, new_means=new_means, new_covs=new_covs,
        new_evidence=jnp.asarray(params.new_evidence, dtype),
        count=count.astype(jnp.int32),
    )

    return ParticleOut(
        pose=jnp.where(finite, sampled, pose),
        pose_sqrt=jnp.where(finite, new_sqrt, pose_sqrt),
        log_weight_increment=jnp.where(finite, log_w_inc, -jnp.inf),
        landmarks=None,
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
    ), writes


class TableWrites(NamedTuple):
    """The writes of one particle's map update (step 5), in the order
    :func:`apply_writes` makes them; a slot ``C`` (the capacity) is not written.

    ``update_*`` ``(k,)``: matched landmarks after their Kalman update; ``local_*``
    ``(L,)``: evidence and the active flag of the local set (pruned ones inactive);
    ``new_*`` ``(k,)``: new landmarks in free slots, each with the evidence
    ``new_evidence`` ``()``; ``count``: active landmarks after.
    """

    update_slots: Array
    update_means: Array
    update_covs: Array
    local_slots: Array
    local_evidence: Array
    local_active: Array
    new_slots: Array
    new_means: Array
    new_covs: Array
    new_evidence: Array
    count: Array


def pad_writes(writes: TableWrites, width: int, capacity: int, axis: int = 0) -> TableWrites:
    """``writes`` of a step run on fewer observation slots, padded along ``axis`` (1
    for a batch of particles) to ``width`` slots with writes that are dropped (slot
    ``capacity``)."""
    def pad(x, fill):
        widths = [(0, 0)] * x.ndim
        widths[axis] = (0, width - x.shape[axis])
        return jnp.pad(x, widths, constant_values=fill)

    return writes._replace(
        update_slots=pad(writes.update_slots, capacity), update_means=pad(writes.update_means, 0),
        update_covs=pad(writes.update_covs, 0), new_slots=pad(writes.new_slots, capacity),
        new_means=pad(writes.new_means, 0), new_covs=pad(writes.new_covs, 0),
    )


def apply_writes(table: LandmarkTable, writes: TableWrites) -> LandmarkTable:
    """One particle's table after its step's :class:`TableWrites` (scatters that can
    update the table in place)."""
    w = writes
    means = table.means.at[w.update_slots].set(w.update_means, mode="drop")
    covs = table.covs.at[w.update_slots].set(w.update_covs, mode="drop")
    evidence = table.evidence.at[w.local_slots].set(w.local_evidence, mode="drop")
    active = table.active.at[w.local_slots].set(w.local_active, mode="drop")
    means = means.at[w.new_slots].set(w.new_means, mode="drop")
    covs = covs.at[w.new_slots].set(w.new_covs, mode="drop")
    evidence = evidence.at[w.new_slots].set(jnp.broadcast_to(w.new_evidence, w.new_slots.shape), mode="drop")
    active = active.at[w.new_slots].set(True, mode="drop")
    return LandmarkTable(means, covs, evidence, active, w.count)


def particle_step(key: Array, pose: Array, pose_sqrt: Array, table: LandmarkTable, *inputs) -> ParticleOut:
    """Steps 1-5 for one particle (module docstring), its table updated:
    :func:`particle_writes` (the same arguments: ``controls, observation, params,
    config`` follow ``table``) with its writes applied."""
    out, writes = particle_writes(key, pose, pose_sqrt, table, *inputs)
    return out._replace(landmarks=apply_writes(table, writes))
