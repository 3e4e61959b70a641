r"""Unscented FastSLAM with the RB or the ERB proposal (Kim, Kim & Chung 2011).

One filter, ``init``/``step``/``run``; the proposal is ``Config.proposal``
(``"rb"``: eqs. 1-3, ``"erb"``: Sec. III-A), everything else is shared, including
the random streams: with the same key both filters draw the same normals for
sampling and the same uniforms for resampling.

One step (one laser scan), for every particle (``vmap`` of
:func:`jaxslam.feature.particle.particle_writes`, steps 1-5, whose map writes the step
makes after its branches over the observation width, in place):

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

``init``/``step``/``run`` follow the protocol of every filter (:mod:`jaxslam.runtime.driver`):
step keys ``jaxslam.runtime.driver.step_keys(key, T)``, ``Info`` with ``ess``, ``resampled`` and
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
  NaN) leaves uniform weights (:func:`jaxslam.core.numerics.normalize_log_weights`),
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
  pose factors use clamped closed-form Cholesky factors (``jaxslam.feature._small``).
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax import Array
from jax.scipy.special import logsumexp

from jaxslam.core.resampling import (
    effective_sample_size,
    log_likelihood_increment,
    normalize_log_weights,
    selective_resample,
)
from jaxslam.core.se2 import pose_residual, wrap_angle
from jaxslam.runtime.driver import best_particle, scan_runner
from jaxslam.feature.landmarks import LandmarkTable, empty_table
from jaxslam.feature.params import Config, Params
from jaxslam.feature.particle import Observation, ParticleOut, apply_writes, pad_writes, particle_writes


class State(NamedTuple):
    """Particles.

    Attributes:
        poses: ``(N, 3)`` pose of each particle (a sample once it was updated).
        pose_sqrt_covs: ``(N, 3, 3)`` lower factor of the pose covariance accumulated since
            the last sampling (the predicted covariance ``P-bar``).
        log_weights: ``(N,)`` normalised log-weights.
        cumulative_log_likelihood: ``(N,)`` the sum of the particle's log weight
            increments (eq. 11) over its whole history, carried through resampling;
            its argmax is the best particle (:func:`jaxslam.runtime.driver.best_particle`).
        landmarks: :class:`~jaxslam.feature.landmarks.LandmarkTable` with leading axis ``N``.
    """

    poses: Array
    pose_sqrt_covs: Array
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
    log_likelihood_increment: Array  # log sum_m w_m g_m (eq. 11 increments, weights before the step); 0 if no particle was updated


def cast_params(params: Params, dtype) -> Params:
    """Every leaf of ``params`` as an array of ``dtype``."""
    return jax.tree_util.tree_map(lambda x: jnp.asarray(x, dtype), params)


@partial(jax.jit, static_argnames=("config",))
def init(key: Array, params: Params, config: Config, initial_pose: Array | None = None) -> State:
    """All particles at ``initial_pose`` (default the origin), empty maps, equal weights.

    The dtype of the filter is that of ``initial_pose`` (default float: float32, or
    float64 under ``jax_enable_x64``). Jitted (one compilation per config). ``key`` is
    unused (a deterministic start, as the grid filters' ``init``) but kept first for
    the common signature (:mod:`jaxslam.runtime.driver`).
    """
    del key  # the initial state is deterministic; the key keeps the protocol's signature
    pose = jnp.zeros(3) if initial_pose is None else jnp.asarray(initial_pose)
    if not jnp.issubdtype(pose.dtype, jnp.floating):
        pose = pose.astype(float)
    dtype = pose.dtype
    n = config.num_particles
    reset = jnp.asarray(params.pose_reset_std, dtype)
    return State(
        poses=jnp.broadcast_to(pose, (n, 3)),
        pose_sqrt_covs=jnp.broadcast_to(reset * jnp.eye(3, dtype=dtype), (n, 3, 3)),
        log_weights=jnp.full((n,), -jnp.log(jnp.asarray(n, dtype))),
        cumulative_log_likelihood=jnp.zeros((n,), dtype),
        landmarks=empty_table(config.capacity, dtype, (n,)),
    )




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
    ref = state.poses[jnp.argmax(log_weights)]
    dev = jax.vmap(pose_residual, (0, None))(state.poses, ref)
    shift = weights @ dev
    estimate = ref + shift
    estimate = estimate.at[2].set(wrap_angle(estimate[2]))
    dev = dev - shift
    spread = jnp.einsum("m,mi,mj->ij", weights, dev, dev)
    own = jnp.einsum("m,mij,mkj->ik", weights, state.pose_sqrt_covs, state.pose_sqrt_covs)
    return estimate, spread + own, weights


def _finish(
    key: Array,
    state: State,
    out: ParticleOut | None,
    params: Params,
    config: Config,
    invalid: tuple[Array, Array],
    observation_mask: Array,
    increment: Array,
) -> tuple[State, Info]:
    dtype = state.poses.dtype
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
        log_likelihood_increment=increment,
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


def observation_widths(config: Config, width: int) -> tuple[int, ...]:
    """The observation widths a step of ``width`` padded slots is compiled for:
    ``config.observation_widths`` under ``width``, then ``width`` itself
    (:func:`step` runs a scan on the narrowest that holds its last real observation)."""
    return tuple(sorted({w for w in config.observation_widths if w < width} | {width}))


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
        observation: :class:`~jaxslam.feature.particle.Observation` of this scan.
        params: traced parameters.
        config: static configuration.

    Returns:
        ``(state, info)``; ``info.ancestors`` are the resampling ancestors ``(N,)``
        (the identity when it did not resample).
    """
    dtype = state.poses.dtype
    params = cast_params(params, dtype)
    control = jnp.asarray(control, dtype)
    observation = Observation(jnp.asarray(observation.values, dtype), jnp.asarray(observation.mask, bool))
    control, observation, *invalid = clean_inputs(control, observation)
    k_sample, k_resample = jax.random.split(key)
    particle_keys = jax.random.split(k_sample, config.num_particles)

    def particles_step(state, observation):
        return jax.vmap(particle_writes, (0, 0, 0, 0, None, None, None, None))(
            particle_keys, state.poses, state.pose_sqrt_covs, state.landmarks, control, observation, params, config
        )

    def active_step(state):
        width = observation.values.shape[0]
        widths = observation_widths(config, width)

        def on_width(used, state):
            if used == width:
                return particles_step(state, observation)
            out, writes = particles_step(state, Observation(observation.values[:used], observation.mask[:used]))
            pad = ((0, 0), (0, width - used))
            out = out._replace(matched=jnp.pad(out.matched, pad), new=jnp.pad(out.new, pad))
            return out, pad_writes(writes, width, config.capacity, axis=1)

        # The branches return the maps' writes, made after them: a branch that wrote
        # into the carried tables would make XLA copy them (1.5 MB at 100 particles).
        if len(widths) == 1:
            out, writes = particles_step(state, observation)
        else:
            # Most scans fill few of the padded observation slots (the padded width is the
            # log's most crowded scan); such a scan runs on the narrowest width that
            # holds its last real observation. Padding slots are masked out everywhere,
            # so the result is the same up to float rounding.
            last = jnp.max(jnp.where(observation.mask, jnp.arange(1, width + 1), 0))
            branch = jnp.searchsorted(jnp.asarray(widths), last, side="left")
            out, writes = jax.lax.switch(branch, [partial(on_width, used) for used in widths], state)
        out = out._replace(landmarks=jax.vmap(apply_writes)(state.landmarks, writes))
        # If every particle failed, the step changes nothing (not even the weights).
        any_finite = jnp.any(out.finite)
        log_weights = jnp.where(any_finite, state.log_weights + out.log_weight_increment, state.log_weights)
        cumulative = jnp.where(
            any_finite, state.cumulative_log_likelihood + out.log_weight_increment, state.cumulative_log_likelihood
        )
        updated = State(out.pose, out.pose_sqrt, log_weights, cumulative, out.landmarks)
        increment = jnp.where(any_finite, log_likelihood_increment(state.log_weights, out.log_weight_increment), 0.0)
        return _finish(k_resample, updated, out, params, config, invalid, observation.mask, increment)

    def idle_step(state):
        zero = jnp.zeros((), state.log_weights.dtype)
        return _finish(k_resample, state, None, params, config, invalid, observation.mask, zero)

    if not config.skip_stationary:
        return active_step(state)
    moving = jnp.any((control[:, 2] > 0) & (control[:, 0] != 0))
    return jax.lax.cond(moving, active_step, idle_step, state)


run = scan_runner(step)
run.__doc__ = """Scan :func:`step` over a sequence (:func:`jaxslam.runtime.driver.scan_runner`).

Args:
    key: PRNG key; step ``t`` uses ``jaxslam.runtime.driver.step_keys(key, T)[t]``.
    state: from :func:`init`.
    controls: ``(T, K, 3)``.
    observations: :class:`~jaxslam.feature.particle.Observation` stacked over ``T``: ``values (T, Z, 2)``,
        ``mask (T, Z)``.
    params, config: as for :func:`step`.

Returns:
    ``(final_state, infos)`` with every :class:`Info` field stacked over ``T``.
"""
