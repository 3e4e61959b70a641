r"""The parts of a grid SLAM step that both filters share, and their ``init``.

A step of either filter (:mod:`jaxslam.grid.gmapping`, :mod:`jaxslam.grid.srupf`):

1. proposal (filter specific) and scan matching against each particle's own map,
   read through its page table (:func:`particle_reader`);
2. log-weights ``log w += gain * log p(z | x, m)`` (``params.weights``, see
   :class:`jaxslam.grid.types.WeightParams`);
3. the scan is integrated into every map at the corrected pose
   (:func:`jaxslam.grid.update.update_paged`: tiles allocated or copied on write);
4. selective resampling when ``ESS < resample_threshold * N`` (Grisetti et al.
   2005/2007): particles take their ancestors' page tables; no cell is copied.

Steps 2-4 are :func:`finish_step`. If the maps cannot take the scan (pool full, or a
tile outside the page table) the step is not applied at all: the state is returned
unchanged with ``status`` set, later steps pass through (:func:`guard`), and the
host grows the maps and repeats the step (:func:`jaxslam.grid.driver.run_filter`).

Best particle: the particle with the largest accumulated log-likelihood
(GMapping's ``weightSum``), :func:`jaxslam.runtime.driver.best_particle`, the meaning both
filter families share (see :mod:`jaxslam.runtime.driver`).

One module, at the usual length's edge: what both filters' steps share (the
proposal's scoring, the weights, the map update, resampling and ``init``) is kept
together so that neither filter can drift from the other in one of those parts.
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax import Array

from jaxslam.core.resampling import (
    effective_sample_size,
    log_likelihood_increment,
    normalize_log_weights,
    selective_resample,
)
from jaxslam.runtime.driver import best_particle
from jaxslam.grid.paged import init_maps, ok_status, reader, resample_maps
from jaxslam.grid.matching import (
    Climb, EllipseBound, climbs_in_turn, get_matcher, gmapping_basis, hill_climb, hill_climb_match, search_bound,
)
from jaxslam.grid.score import ScoreModel, beam_points, make_score_fn, scan_log_likelihood
from jaxslam.grid.types import ClosureState, GridSlamConfig, GridSlamInfo, GridSlamParams, GridSlamState, Scan
from jaxslam.grid.types import as_odometry
from jaxslam.grid.update import update_paged


def scan_angles(observation: Scan, params: GridSlamParams) -> Array:
    """Beam angles ``(B,)`` of this scan in the laser frame."""
    return params.sensor.beam_angles + jnp.asarray(observation.angle_offset, params.sensor.beam_angles.dtype)


def score_model(params: GridSlamParams) -> ScoreModel:
    """The traced score settings of ``params``."""
    return ScoreModel(params.map.occ_saturation, params.matcher.score_sigma, params.weights.likelihood_floor)


def scan_score_fn(read, local_points: Array, mask: Array, params: GridSlamParams, config: GridSlamConfig):
    """The match score ``(M, 3) -> (M,)`` of poses against the map of ``read``
    (:func:`jaxslam.grid.score.make_score_fn` with the params' score model and the
    config's kernel): the sum of the beams' weighted evidence."""
    return make_score_fn(read, local_points, mask, params.sensor.laser_offset, config.layout, score_model(params),
                         config.score_kernel, config.free_check)


def scan_likelihood(read, pose: Array, local_points: Array, mask: Array, params: GridSlamParams,
                    config: GridSlamConfig) -> tuple[Array, Array]:
    """``(log p(z | pose, map), score)`` of one pose
    (:func:`jaxslam.grid.score.scan_log_likelihood` under the same model as
    :func:`scan_score_fn`)."""
    return scan_log_likelihood(read, pose, local_points, mask, params.sensor.laser_offset, config.layout,
                               score_model(params), config.score_kernel, config.free_check)


def coarse_start(read, local_points: Array, mask: Array, pose: Array, params: GridSlamParams,
                 config: GridSlamConfig, bound=None) -> Array:
    r"""Where a hill climb starts in a coarse-to-fine match (``config.coarse_iterations``
    :math:`k`; ``pose`` itself when :math:`k = 0`).

    The ``gaussian3`` evidence of a beam, :math:`o(c)\, e^{-d^2/\sigma^2}` at its best
    cell, falls to a third one cell (5 cm) from a wall at ``matcher.score_sigma`` = 0.05 m: the
    narrow kernel makes the match precise, but its score has little slope for a pose
    off by more than a cell or a degree or two. GMapping's own kernel,
    :math:`e^{-d^2 / 0.05\,\mathrm{m}^2}` (``matcher.coarse_sigma`` :math:`\sigma_c` = 0.2236 m),
    still gives 0.95 there. The coarse stage climbs :math:`k` iterations of GMapping's
    hill climb (:func:`jaxslam.grid.matching.hill_climb`, ``linear_step`` /
    ``angular_step`` moves) on the score with :math:`\sigma_c`,

    .. math:: x_c = \operatorname{climb}_k\Big(x \mapsto \sum_b w_b\, o_{\sigma_c}(e_b(x)),\ x_0\Big),

    and the caller's matcher then climbs from :math:`x_c` on the narrow score, whose
    value is the match's score (the tracking's trust, the closure search's trigger,
    the curvature test and the weights are all the narrow kernel's). With ``bound``
    (:func:`jaxslam.grid.matching.search_bound`: for SRUPF-GM's ellipse matcher the
    poses within ``matcher.coarse_radius`` standard deviations of the prediction) the wide
    climb skips every candidate outside it, as the matcher does. Unbounded, the wide
    climbs answer to no motion model and can hand the matcher a start it would never
    have reached itself (a turn of 0.51 rad that the odometry had right, matched as
    0.16 rad). SRUPF-GM's default (:data:`jaxslam.grid.algorithms.GRID_ALGORITHMS`;
    the design notes, ``docs/design.md``, "The coarse stage", have the table).
    """
    if not config.coarse_iterations:
        return pose
    model = score_model(params)._replace(sigma=params.matcher.coarse_sigma)
    wide = make_score_fn(read, local_points, mask, params.sensor.laser_offset, config.layout, model, config.score_kernel,
                         config.free_check)
    moved, _, _ = hill_climb(wide, pose, gmapping_basis(params, pose.dtype), config.coarse_iterations, bound)
    return moved


def coarse_to_fine(read, local_points: Array, mask: Array, start: Array, pose_sqrt_cov: Array,
                   params: GridSlamParams, config: GridSlamConfig, coarse_centre: Array,
                   prior_mean: Array | None = None) -> tuple[Array, Array]:
    """A keyframe's match: ``config.matcher`` from :func:`coarse_start` (whose climb
    keeps to :func:`jaxslam.grid.matching.search_bound` around ``coarse_centre`` at
    ``matcher.coarse_radius``), ``(pose (3,), score ())``, the score a raw sum over the beams.

    Where both are hill climbs (the ``"hill"`` and ``"ellipse"`` matchers without a
    gradient refinement), they run as two passes of one climb
    (:func:`jaxslam.grid.matching.climbs_in_turn`), so the program holds the score
    kernel once for both; the poses are the same bit for bit.
    """
    model = score_model(params)
    score_fn = make_score_fn(read, local_points, mask, params.sensor.laser_offset, config.layout, model,
                             config.score_kernel, config.free_check)
    coarse_bound = search_bound(config.matcher, coarse_centre, pose_sqrt_cov, params, params.matcher.coarse_radius)
    if not (config.coarse_iterations and not config.refine_steps and config.matcher in ("hill", "ellipse")):
        begin = coarse_start(read, local_points, mask, start, params, config, coarse_bound)
        return get_matcher(config.matcher)(score_fn, begin, pose_sqrt_cov, params, config.match_iterations,
                                           config.refine_steps, prior_mean=prior_mean)
    dtype = start.dtype
    coarse_basis = gmapping_basis(params, dtype)
    fine_basis, fine_step = coarse_basis, jnp.ones((), dtype)
    if coarse_bound is not None:  # ellipse_match's steps: the ellipse's marginal deviations
        factor = coarse_bound.sqrt_cov
        fine_basis = jnp.diag(jnp.sqrt(jnp.sum(factor * factor, -1)))
        fine_step = jnp.asarray(params.matcher.ellipse_step, dtype)

    def score_at(poses, sigma):
        return make_score_fn(read, local_points, mask, params.sensor.laser_offset, config.layout,
                             model._replace(sigma=sigma), config.score_kernel, config.free_check)(poses)

    def prepare(i, carry):
        coarse = i == 0
        begin = jnp.where(coarse, start, carry[0])
        bound = None
        if coarse_bound is not None:
            centre = jnp.where(coarse, coarse_centre, begin if prior_mean is None else prior_mean)
            radius = jnp.where(coarse, coarse_bound.radius, jnp.asarray(params.matcher.ellipse_radius, dtype))
            bound = EllipseBound(centre, coarse_bound.sqrt_cov, radius)
        return carry, Climb(
            jnp.asarray(True), begin, jnp.where(coarse, coarse_basis, fine_basis),
            jnp.where(coarse, config.coarse_iterations, config.match_iterations),
            jnp.where(coarse, jnp.asarray(params.matcher.coarse_sigma, dtype), jnp.asarray(model.sigma, dtype)),
            jnp.where(coarse, jnp.ones((), dtype), fine_step), bound)

    def take(i, carry, climb, pose, score):
        return pose, score

    return climbs_in_turn(score_at, 2, prepare, take, (start, jnp.zeros((), dtype)))


def usable_range(params: GridSlamParams, config: GridSlamConfig) -> Array:
    """``params.sensor.usable_range`` cropped to the static ``config.window_range``."""
    return jnp.minimum(params.sensor.usable_range, jnp.asarray(config.window_range, params.sensor.usable_range.dtype))


def beam_weights(ranges: Array, valid: Array, score_range) -> Array:
    r"""The weight of each beam in the match score and the log-likelihood,

    .. math:: w_b = m_b \min\bigl(1, (r_s / r_b)^2\bigr),

    :math:`m_b` the mask of usable beams, :math:`r_s` = ``sensor.score_range``. A beam within
    :math:`r_s` counts fully; one farther counts as :math:`(r_s / r_b)^2` beams. A
    far end point moves :math:`r_b` times a heading error and lands on walls seen
    from afar, at grazing angles and by few scans, so its evidence is the least
    certain; the far field is also where a scan holds the most cells. Beyond
    :math:`r_s` the weights keep the far field's total share of the score about
    constant instead of letting it outvote the near field. With ``sensor.score_range`` at
    or above the usable range every weight is the mask (exactly 1 or 0).
    """
    far = jnp.asarray(score_range, ranges.dtype) ** 2 / jnp.maximum(ranges * ranges, jnp.finfo(ranges.dtype).tiny)
    return jnp.where(valid, jnp.minimum(far, 1.0), 0.0)


def match_geometry(observation: Scan, params: GridSlamParams, config: GridSlamConfig):
    """Local end points ``(M, 2)`` and weights ``(M,)`` (:func:`beam_weights`, 0 for
    unused beams) of the beams used for matching."""
    idx = config.match_beams
    ranges = observation.ranges[idx].astype(params.sensor.beam_angles.dtype)
    valid = observation.valid[idx] & (ranges <= usable_range(params, config)) & (ranges > 0)
    safe = jnp.where(valid, ranges, 0.0)
    return beam_points(safe, scan_angles(observation, params)[idx]), beam_weights(safe, valid, params.sensor.score_range)


def particle_reader(state: GridSlamState, table: Array, config: GridSlamConfig):
    """The cell reader of the particle whose page table is ``table``."""
    return reader(state.maps.pool, table, state.maps.corner, config.layout)


def integrate_scan(maps, poses: Array, observation: Scan, params: GridSlamParams, config: GridSlamConfig):
    """All particles' maps updated with one scan at ``poses``: ``(maps, dropped, status)``."""
    return update_paged(
        maps,
        config.layout,
        poses,
        observation.ranges.astype(poses.dtype),
        observation.valid,
        scan_angles(observation, params).astype(poses.dtype),
        params.sensor.laser_offset,
        config.max_points,
        params.sensor.usable_range,
        config.window_range,
        params.map.l_free,
        params.map.l_occ,
        params.map.l_max,
    )


def _init(key: Array, params: GridSlamParams, config: GridSlamConfig, observation: Scan, initial_pose: Array,
          start=None):
    del key  # the initial state is deterministic; the key keeps the protocol's signature
    dtype = params.sensor.beam_angles.dtype
    n = config.num_particles
    pose = jnp.asarray(initial_pose, dtype)
    # The barrier keeps XLA from constant-folding the empty maps through the first
    # write (a cumulative sum over every free slot, which took seconds to fold at
    # compile time for large pools).
    one = jax.lax.optimization_barrier(init_maps(1, config.layout) if start is None else start)
    one, _, status = integrate_scan(one, pose[None], observation, params, config)
    tables = jnp.broadcast_to(one.tables, (n, one.tables.shape[1]))
    maps = resample_maps(one._replace(tables=tables), jnp.arange(n), jnp.asarray(True))
    sqrt_cov = jnp.diag(params.srupf.initial_std.astype(dtype))
    return GridSlamState(
        poses=jnp.broadcast_to(pose, (n, 3)),
        pose_sqrt_covs=jnp.broadcast_to(sqrt_cov, (n, 3, 3)),
        log_weights=jnp.full((n,), -jnp.log(jnp.asarray(n, dtype))),
        cumulative_log_likelihood=jnp.zeros((n,), dtype),
        maps=maps,
        status=status,
        motion=jnp.zeros((3,), dtype),
        since_keyframe=jnp.zeros((5,), dtype),
        closure=ClosureState.empty(dtype, map_bound=config.closure_map_bound),
    )


@partial(jax.jit, static_argnames=("config",))
def init(
    key: Array,
    params: GridSlamParams,
    config: GridSlamConfig,
    observation: Scan,
    initial_pose: Array,
    start=None,
) -> GridSlamState:
    """All particles at ``initial_pose`` sharing one map built from the first scan.

    ``start``: one particle's :class:`~jaxslam.grid.paged.PagedMaps` (a saved map,
    :func:`jaxslam.grid.startmap.paged_start`) that the first scan is written into, in
    place of empty maps; every particle then shares its tiles. The pose factor starts
    at ``diag(params.srupf.initial_std)``. Jitted (one compilation per config). If the first scan does not fit the layout, ``status`` says so and the
    caller grows the layout (:func:`jaxslam.grid.paged.grow`) and calls again.
    """
    return _init(key, params, config, observation, initial_pose, start)


@partial(jax.jit, static_argnames=("config",))
def match_start(start, observation: Scan, pose: Array, params: GridSlamParams,
                config: GridSlamConfig) -> tuple[Array, Array, Array]:
    """The first scan of a continued run matched in the saved map, before it is written:
    ``(pose, score at the given pose, score at the returned pose)``.

    ``start`` is the saved map as one particle's paged maps
    (:func:`jaxslam.grid.startmap.paged_start`), ``pose`` where the run is told to
    start (``--initial-pose``, the saved run's last pose or the localizer's estimate).
    A fresh run's first scan makes the map and needs no match; a continued run's
    first scan lands in a map that already has walls, and a start pose a few
    centimetres or a degree off would write it beside them. The match is the
    keyframe matcher's unbounded form: the coarse stage (:func:`coarse_start`, GMapping's
    wide kernel) then GMapping's hill climb on the narrow score, from ``pose``. A climb
    only moves to a better score, so where the scan sees nothing of the saved map
    (scores 0) the pose is kept."""
    points, weights = match_geometry(observation, params, config)
    points = points.astype(pose.dtype)
    read = reader(start.pool, start.tables[0], start.corner, config.layout)
    score_fn = scan_score_fn(read, points, weights, params, config)
    begin = coarse_start(read, points, weights, pose, params, config)
    best, score = hill_climb_match(score_fn, begin, None, params, config.match_iterations)
    before = score_fn(pose[None])[0]
    better = score > before
    return jnp.where(better, best, pose), before, jnp.where(better, score, before)


class ParticleUpdate(NamedTuple):
    """What a keyframe's proposal gives for each particle (``(N, ...)`` over the
    particles, or one particle's inside ``propose``, :func:`keyframe_update`).

    Attributes:
        map_poses: where the scan is written into the particle's map ``(N, 3)``.
        next_poses: the particle's pose after the keyframe ``(N, 3)``.
        next_sqrt_covs: its square-root pose covariance ``(N, 3, 3)``.
        scores: the matching score, mean occupancy over the matched beams ``(N,)``.
        log_likelihoods: ``log p(z | x, m)`` of the scan at ``map_poses`` ``(N,)``.
        pd_ok: the square-root update stayed positive definite ``(N,)``.
    """

    map_poses: Array
    next_poses: Array
    next_sqrt_covs: Array
    scores: Array
    log_likelihoods: Array
    pd_ok: Array


def finish_step(
    key: Array,
    state: GridSlamState,
    update: ParticleUpdate,
    observation: Scan,
    params: GridSlamParams,
    config: GridSlamConfig,
) -> tuple[GridSlamState, GridSlamInfo]:
    """Weights, map update at ``update.map_poses``, selective resampling (shared by
    filters)."""
    map_poses, next_poses, next_sqrt_covs, scores, log_likelihoods, pd_ok = update
    log_weights = normalize_log_weights(state.log_weights + params.weights.gain * log_likelihoods)
    cumulative = state.cumulative_log_likelihood + log_likelihoods
    # A data dependency from every read of the maps (matching, likelihoods) to the
    # map update, so that XLA orders the reads before the in-place write. (Float
    # ``x * 0`` is not folded away, and the where keeps NaNs out.)
    tie = jnp.sum(log_likelihoods) * 0.0 + jnp.sum(scores) * 0.0
    tie = jnp.where(jnp.isfinite(tie), tie, 0.0)
    maps, dropped, status = integrate_scan(state.maps, map_poses + tie, observation, params, config)
    applied = status.code == 0
    ess = effective_sample_size(log_weights)
    increment = log_likelihood_increment(state.log_weights, params.weights.gain * log_likelihoods)
    ancestors, resampled, new_log_weights = selective_resample(
        key, log_weights, params.weights.resample_threshold, config.resampler
    )
    identity = jnp.arange(config.num_particles, dtype=ancestors.dtype)
    ancestors = jnp.where(applied, ancestors, identity)
    resampled = resampled & applied

    def keep(new, old):
        return jnp.where(applied, new, old)

    new_state = GridSlamState(
        poses=keep(next_poses[ancestors], state.poses),
        pose_sqrt_covs=keep(next_sqrt_covs[ancestors], state.pose_sqrt_covs),
        log_weights=keep(new_log_weights, state.log_weights),
        cumulative_log_likelihood=keep(cumulative[ancestors], state.cumulative_log_likelihood),
        maps=resample_maps(maps, ancestors, resampled),
        status=status,
        motion=state.motion,
        since_keyframe=state.since_keyframe,
        closure=state.closure,
    )
    info = GridSlamInfo(
        poses=map_poses,
        log_weights=log_weights,
        scores=scores,
        log_likelihoods=log_likelihoods,
        ancestors=ancestors,
        resampled=resampled,
        ess=ess,
        dropped_points=dropped,
        pd_ok=pd_ok,
        status=status.code,
        keyframe=jnp.asarray(True),
        motion=jnp.zeros_like(state.motion),
        track_score=jnp.zeros((), log_weights.dtype),
        track_accepted=jnp.asarray(False),
        track_closed=jnp.asarray(False),
        track_conflict=jnp.zeros((), log_weights.dtype),
        track_undo=jnp.zeros((4,), log_weights.dtype),
        track_search=jnp.zeros((4,), log_weights.dtype),
        log_likelihood_increment=jnp.where(applied, increment, 0.0),
    )
    return new_state, info


def keyframe_update(propose):
    """The keyframe update of a grid filter whose particles move by ``propose``: a
    ``step(key, state, control, observation, params, config) -> (State, Info)``.

    ``propose(key, read, pose, sqrt_cov, control, local_points, mask, params, config)``
    is one particle's part, with its own map (``read``), its pose and square-root
    covariance, the :class:`~jaxslam.grid.types.Odometry` since the previous keyframe
    and the scan's beams in the laser frame (:func:`match_geometry`); it returns a
    :class:`ParticleUpdate` for :func:`finish_step`. Its nine arguments are the one
    signature that every proposal shares (GMapping's, SRUPF-GM's, a user's own), so
    that swapping it is one argument; none of them travels elsewhere as a group. The step splits its key into the particles' keys and the
    resampling key, runs ``propose`` over the particles (``vmap``) and finishes with
    the weights, the map update and the resampling."""

    def step(
        key: Array,
        state: GridSlamState,
        control,
        observation: Scan,
        params: GridSlamParams,
        config: GridSlamConfig,
    ) -> tuple[GridSlamState, GridSlamInfo]:
        key_particles, key_resample = jax.random.split(key)
        control = as_odometry(control)
        keys = jax.random.split(key_particles, config.num_particles)
        local_points, mask = match_geometry(observation, params, config)

        def particle(k, table, pose, sqrt_cov):
            read = particle_reader(state, table, config)
            return propose(k, read, pose, sqrt_cov, control, local_points, mask, params, config)

        update = jax.vmap(particle)(keys, state.maps.tables, state.poses, state.pose_sqrt_covs)
        return finish_step(key_resample, state, update, observation, params, config)

    return step


def empty_info(state: GridSlamState, config: GridSlamConfig) -> GridSlamInfo:
    """The :class:`~jaxslam.grid.types.GridSlamInfo` of a step that updated nothing: zeros, the state's
    weights, identity ancestors, ``keyframe`` False and the state's map status."""
    n, dtype = config.num_particles, state.poses.dtype
    zero = jnp.zeros((), dtype)
    return GridSlamInfo(
        poses=jnp.zeros((n, 3), dtype),
        log_weights=state.log_weights,
        scores=jnp.zeros((n,), dtype),
        log_likelihoods=jnp.zeros((n,), dtype),
        ancestors=jnp.arange(n, dtype=jnp.int32),
        resampled=jnp.asarray(False),
        ess=zero,
        dropped_points=jnp.zeros((), jnp.int32),
        pd_ok=jnp.ones((n,), bool),
        status=state.status.code,
        keyframe=jnp.asarray(False),
        motion=state.motion,
        track_score=zero,
        track_accepted=jnp.asarray(False),
        track_closed=jnp.asarray(False),
        track_conflict=zero,
        track_undo=jnp.zeros((4,), dtype),
        track_search=jnp.zeros((4,), dtype),
        log_likelihood_increment=zero,
    )


def guard(step_fn):
    """``step_fn`` that passes the state through once a step was refused (status set)."""

    def guarded(key, state: GridSlamState, control, observation, params, config):
        def halted(key, state, control, observation, params):
            return state, empty_info(state, config)

        def live(key, state, control, observation, params):
            return step_fn(key, state, control, observation, params, config)

        return jax.lax.cond(state.status.code == 0, live, halted, key, state, control, observation, params)

    guarded.__doc__ = step_fn.__doc__
    guarded.__name__ = getattr(step_fn, "__name__", "step")
    guarded.__wrapped__ = step_fn
    return guarded


def reset_status(state: GridSlamState) -> GridSlamState:
    """The state with its map status cleared (after the host grew the maps)."""
    return state._replace(status=ok_status())


__all__ = [
    "beam_weights",
    "coarse_to_fine",
    "best_particle",
    "empty_info",
    "finish_step",
    "guard",
    "init",
    "integrate_scan",
    "keyframe_update",
    "ParticleUpdate",
    "match_geometry",
    "match_start",
    "particle_reader",
    "reset_status",
    "scan_angles",
    "scan_likelihood",
    "scan_score_fn",
    "score_model",
    "usable_range",
]
