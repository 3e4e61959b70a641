r"""Every scan a step: tracking between keyframes and the keyframe rule in the filter.

GMapping (and the keyframe filters :mod:`jaxslam.grid.gmapping`,
:mod:`jaxslam.grid.srupf`) processes only keyframes, chosen from the wheel odometry,
and moves between them on the odometry alone. Where the odometry misses motion (a
robot that turns in place in a doorway while its wheels report almost nothing), the
keyframe rule never fires and the error piles up beyond the reach of the matcher.
:func:`per_scan` turns a keyframe step into a step for *every* scan of the log:

For scan :math:`t` with the odometry increment :math:`u_t` since scan :math:`t-1`
(robot frame) and the state's motion :math:`m_{t-1}` since the last keyframe
(:math:`m = 0` right after one):

.. math::
    b &= \arg\max_i c_i \quad \text{(best particle, accumulated log-likelihood)},
       \qquad a = x_b \quad \text{(its keyframe pose)} \\
    \hat x &= a \oplus (m_{t-1} \oplus u_t) \\
    x^*, s &= \text{hill climb of scan } t \text{ in the map of } b
       \text{ from } \hat x \text{ (GMapping's matcher, lstep/astep)}; \text{ again from }
       \hat x \oplus (0, 0, \pm\delta) \text{ if that scores above } s
       \ (\delta = \texttt{track\_turn}) \\
    x^*, s &\leftarrow \text{the loop-closure search's pose and score, where } s/n <
       \texttt{closure\_trigger} \text{ and it wins (below)} \\
    x^\dagger &= \big(\hat x_{xy} + \Pi\,(x^*_{xy} - \hat x_{xy}),\ x^*_\theta\big)
       \quad (\Pi: \text{the directions the scan constrains, } \texttt{constrained\_shift}) \\
    m_t &= \ominus a \oplus x^\dagger \ \text{if } s / n > \text{track\_min\_score},
       \quad m_{t-1} \oplus u_t \ \text{otherwise} \\
    \delta &= \ominus m_{t-1} \oplus m_t, \quad
       d \mathrel{+}= |\delta_{xy}|,\ r \mathrel{+}= |\delta_\theta|,\
       \tau \mathrel{+}= \Delta t,\ k \mathrel{+}= 1

(:math:`n` the matched beams). The scan is a keyframe when
:math:`d \ge` ``keyframes.linear_update`` or :math:`r \ge` ``keyframes.angular_update`` or
(``keyframes.temporal_update`` :math:`\ge 0` and :math:`\tau >` ``keyframes.temporal_update``):
GMapping's rule (:func:`jaxslam.datasets.keyframes.select_keyframes`) on the
*tracked* motion instead of the odometry. A keyframe runs the filter's own step with
the control :math:`(m_t, k)`, so every particle's proposal is centred on the
laser-corrected motion, and resets :math:`m, d, r, \tau, k` to 0. One matcher for
the whole set, not per particle: between keyframes the particles do not move (their
poses are keyframe poses) and share :math:`m`.

The second climb is for turns the odometry misses (a robot turning in a doorway while
its wheels report little): the hill climb reaches far only while every move improves
the score, and a miss of 0.1-0.2 rad can leave it in a worse optimum with a score that
is still trusted. The second climb runs only when a turned guess, before any
climbing, already beats the converged match: starting every match from the best of
the three guesses instead lets a turned start that happens to score better than the
plain guess climb to a worse optimum than the plain match would have.

A match that scores under ``closure.trigger`` may be a place mapped long ago, met
again beyond the hill climb's reach (after a long loop the guess can be metres and
degrees off the old map): :mod:`jaxslam.grid.closure` then searches wide around it and
takes the best pose it finds where that scores clearly better (its module docstring
has the rule), and takes a closure back where the scans of the next metres keep
ending in space the old map has seen through. An undone closure moves the pose back
whatever the match there scores (it is not refused like an untrusted match below).

A match that is not trusted keeps the odometry: the tracking falls back instead of
jumping. Before that, with ``config.recover_radius`` (SRUPF-GM's default; 0: off), a
refused match is searched again around the guess by :mod:`jaxslam.grid.recovery`, for
an odometry that jumped (its module docstring has the rule); where that finds a
trusted, clearly better pose, it is taken. Untrusted is a score under
``tracking.min_score`` (a featureless or changed scene, a scan that does not overlap the
map, a map of a single scan). The score is the mean occupancy at the beam end points,
and a wall seen once is half occupied, so where the scans are far apart (a metre
apart) even a right match scores 0.1-0.3: the threshold (0.1) sits below that, or
the tracking would refuse most scans of such a log and the filter would follow its
odometry's drift. A trusted match corrects the heading, and the position only along
the directions where the score is curved (:func:`constrained_shift`, eigenvalues of
the score's Hessian at the match at least ``tracking.min_curvature``): in a corridor the
score is flat along its axis, and a hill climb there slides by up to its whole reach
(``match_iterations`` steps of lstep) on map noise, so along that axis the odometry
is kept. SRUPF-GM's keyframe correction moves the position only along constrained
directions too (``config.constrain_matches``), for the same slides one level up. The
heading is not bounded: a missed turn is the case tracking is for. With
``config.tracking = False`` no scan is matched between keyframes and the keyframes
are GMapping's own (odometry) keyframes.

With tracking the keyframe control is laser-corrected motion, so the proposals spread
only ``tracking.noise_scale`` = 0.2 of the odometry model's motion noise
(:func:`tracked_noise_scale`): at a metre per scan GMapping's 0.2 rad/m heading noise
scatters particles beyond their hill climbs, and a lost particle scores well against
its own map. A match counts from any score (``matcher.min_score`` 0, GMapping's
``minimumScore``). After a refused match SRUPF-GM's proposals are wider,
``tracking.refused_noise_scale`` (:func:`keyframe_noise_scale`). What tracking changes
and costs on real logs: the documentation's design notes (``docs/design.md``,
"Per-scan tracking"), reproduced by ``benchmarks/grid_robustness.py``.

The pose of every scan is the filter's own: the best lineage's keyframe pose composed
with the tracked motion :math:`m_t` of the scan (``Info.motion``), see
:func:`scan_trajectory`.

One module of about 400 lines, a third of them the model above: the per-scan step and
the pieces it is made of (the match and its retry, the constrained correction, the
noise scales, the keyframe rule) change together; the closure search and the
recovery it calls are modules of their own.
"""

from __future__ import annotations

import inspect

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from jaxslam.core import se2
from jaxslam.datasets.geometry import se2_compose
from jaxslam.runtime.driver import best_particle
from jaxslam.grid.climbs import Phase, run_phases
from jaxslam.grid.closure import closure_carry, closure_outcome, closure_phases, record_applied, refine_count
from jaxslam.grid.undone_closures import take_back
from jaxslam.grid.filter import coarse_to_fine, empty_info, match_geometry, particle_reader, scan_score_fn, score_model
from jaxslam.grid.recovery import recovery_carry, recovery_phases
from jaxslam.grid.score import make_score_fn
from jaxslam.grid.types import GridSlamConfig, GridSlamParams, GridSlamState, Odometry, Scan, as_odometry


LEVEL_RATE = 0.005
"""Weight of each scan in the running mean of the tracking's scores (about 200 scans)."""


def track(state: GridSlamState, increment: Array, observation: Scan, params: GridSlamParams, config: GridSlamConfig):
    """The tracked motion after one scan: ``(motion (3,), score (), accepted (), closed (),
    conflict (), memory, undo (4,), search (4,))`` (``closed``: the loop-closure search's pose
    replaced the local match, or a closure was undone; ``conflict``: the share of its beams
    ending in known free space; ``memory``: the state's
    :class:`~jaxslam.grid.types.ClosureState` after this scan;
    ``undo``: what an undo took back, zeros otherwise; ``search``: the closure candidate
    judged, zeros where none was (:func:`jaxslam.grid.closure.closure_outcome`); see
    :mod:`jaxslam.grid.closure`)."""
    dtype = state.poses.dtype
    best = best_particle(state)
    anchor = state.poses[best]
    predicted = se2.compose(state.motion, increment.astype(dtype))
    if not config.tracking:
        return (predicted, jnp.zeros((), dtype), jnp.asarray(False), jnp.asarray(False), jnp.zeros((), dtype),
                state.closure, jnp.zeros((4,), dtype), jnp.zeros((4,), dtype))
    guess = se2.compose(anchor, predicted)
    local_points, mask = match_geometry(observation, params, config)
    read = particle_reader(state, state.maps.tables[best], config)
    score_fn = scan_score_fn(read, local_points, mask, params, config)
    model = score_model(params)

    def score_at(poses, sigma):
        return make_score_fn(read, local_points, mask, params.sensor.laser_offset, config.layout,
                             model._replace(sigma=sigma), config.score_kernel, config.free_check)(poses)

    # A turn the odometry missed (a doorway turn: up to 10 deg per scan) can lie beyond
    # the hill climb's reach. If the guess turned by +-track_turn already scores above
    # the converged match, that match is stuck: climb again from the better turned start.
    turns = jnp.asarray([1.0, -1.0], dtype) * jnp.asarray(params.tracking.turn, dtype)
    turned = jnp.broadcast_to(guess, (2, 3)).at[:, 2].add(turns)
    turned = turned.at[:, 2].set(se2.wrap_angle(turned[:, 2]))
    turned_scores = score_fn(turned)
    retry = turned[jnp.argmax(turned_scores)]
    count = jnp.maximum(jnp.sum(mask), 1).astype(dtype)
    memory = state.closure
    if config.closure:
        memory = memory._replace(travelled=memory.travelled + jnp.hypot(increment[0], increment[1]).astype(dtype))
    lanes = refine_count(config)
    carry = {"start": guess, "matched": guess, "score": jnp.full((), -jnp.inf, dtype), "origin": guess,
             "searching": jnp.asarray(False), "candidates": jnp.zeros((lanes, 3), dtype),
             "found": jnp.zeros((), dtype), "found_pose": jnp.zeros((3,), dtype),
             **recovery_carry(dtype), **closure_carry(dtype)}
    # Every climb of the scan is a phase of one climb in the program (jaxslam.grid.climbs).
    phases = match_phases(guess, retry, jnp.max(turned_scores), config)
    if config.recover_radius > 0:  # an odometry glitch: a wide match where this one is refused
        phases += recovery_phases(read, local_points, mask, guess, count, increment, params, config)
    if config.closure:
        phases += closure_phases(read, config.layout, local_points, mask, params.sensor.laser_offset, count, memory,
                                 params, config)
    carry = run_phases(score_at, phases, carry, params, config)
    matched, score, origin = carry["matched"], carry["score"], carry["origin"]
    closed, conflict = jnp.asarray(False), jnp.zeros((), dtype)
    undo = search = jnp.zeros((4,), dtype)
    if config.closure:
        local = matched
        matched, score, closed, undo, conflict, memory, search = closure_outcome(carry, count, memory, params)
        undone = undo[0] > 0
        taken, closed = closed, closed | undone
    score = score / count
    pose = constrained_pose(score_fn, matched, origin, score * count, count, params)
    accepted = score > params.tracking.min_score
    if config.closure:  # an undone closure is taken back whatever the match says
        pose = jnp.where(undone, matched, pose)
        accepted = accepted | undone
        memory = record_applied(memory, taken, se2.compose(pose, se2.inverse(local)))
    if config.closure:  # the recent matches' mean score (closure.trigger_ratio)
        memory = memory._replace(level=memory.level + LEVEL_RATE * (score.astype(dtype) - memory.level))
    motion = jnp.where(accepted, se2.relative(anchor, pose), predicted)
    return motion, score, accepted, closed, conflict, memory, undo, search


def match_phases(guess: Array, retry: Array, turned_score: Array, config: GridSlamConfig) -> list[Phase]:
    """The tracking's own climbs as phases (:mod:`jaxslam.grid.climbs`): the match from
    ``guess``, then, where the better turned guess ``retry`` scored ``turned_score``
    above it, the match from ``retry`` in its place (each match the coarse climb, with
    ``config.coarse_tracking``, then the narrow one from where it ended)."""
    coarse = bool(config.coarse_tracking and config.coarse_iterations)

    def match(first: bool) -> list[Phase]:
        start = guess if first else retry

        def active(carry):  # the first match always; the second where a turned guess beats it
            return jnp.asarray(True) if first else turned_score > carry["score"]

        def coarse_prepare(lane, carry):
            return carry, active(carry), start

        def coarse_take(lane, carry, ran, pose, score):
            return {**carry, "start": pose}

        def fine_prepare(lane, carry):
            return carry, active(carry), carry["start"] if coarse else start

        def fine_take(lane, carry, ran, pose, score):
            return {**carry, "matched": jnp.where(ran, pose, carry["matched"]),
                    "score": jnp.where(ran, score, carry["score"])}

        return [Phase(1, True, coarse_prepare, coarse_take)] * coarse + [Phase(1, False, fine_prepare, fine_take)]

    return match(True) + match(False)


def keyframe_match(score_fn, read, local_points: Array, mask: Array, start: Array, center: Array,
                   sqrt_cov: Array, params: GridSlamParams, config: GridSlamConfig,
                   prior_mean: Array | None = None) -> tuple[Array, Array, Array]:
    """The keyframe corrector of both filters for one particle: the coarse stage
    (within ``matcher.coarse_radius`` of ``center`` for a bounded matcher) and the config's
    matcher from there (:func:`jaxslam.grid.filter.coarse_to_fine`), and with
    ``config.constrain_matches`` :func:`constrained_pose` from ``start``.

    Returns:
        ``(pose, score, count)``: the match, its raw score (a sum over the beams) and
        the number of matched beams (at least 1).
    """
    best, best_score = coarse_to_fine(read, local_points, mask, start, sqrt_cov, params, config, center,
                                      prior_mean=prior_mean)
    count = jnp.maximum(jnp.sum(mask), 1).astype(start.dtype)
    if config.constrain_matches:
        best = constrained_pose(score_fn, best, start, best_score, count, params)
    return best, best_score, count


def constrained_pose(score_fn, matched: Array, start: Array, score: Array, count: Array,
                     params: GridSlamParams) -> Array:
    """``matched`` with its heading, and of its position correction from ``start`` only
    the part the scan constrains (:func:`constrained_shift`): the tracking's pose and
    the keyframe correctors' with ``config.constrain_matches``."""
    shift = constrained_shift(score_fn, matched, start, score, count, params)
    return jnp.concatenate([start[:2] + shift, matched[2:]])


def constrained_shift(score_fn, matched: Array, guess: Array, score: Array, count: Array,
                      params: GridSlamParams) -> Array:
    r"""The part of the match's position correction ``matched - guess`` (world frame)
    that the scan constrains.

    The curvature of the score at the match, by central differences with step
    :math:`d` = ``linear_step`` (eight poses around it),

    .. math:: A = -\nabla^2_{xy} s / n,

    is the information of the match about the position (per m^2, score as a fraction
    of the beams). Along an eigenvector of :math:`A` whose eigenvalue is under
    ``tracking.min_curvature`` the score is flat (a corridor along its axis, a single
    wall), and the correction along it is dropped: the odometry keeps that direction.
    """
    dtype = matched.dtype
    d = jnp.asarray(params.matcher.linear_step, dtype)
    offsets = jnp.array([[1, 0], [-1, 0], [0, 1], [0, -1], [1, 1], [1, -1], [-1, 1], [-1, -1]], dtype) * d
    poses = jnp.concatenate([matched[None, :2] + offsets, jnp.broadcast_to(matched[2:], (8, 1))], -1)
    around = score_fn(poses)  # raw scores (sums over the beams), like ``score``
    hxx = (around[0] + around[1] - 2 * score) / d**2
    hyy = (around[2] + around[3] - 2 * score) / d**2
    hxy = (around[4] - around[5] - around[6] + around[7]) / (4 * d**2)
    information = -jnp.array([[hxx, hxy], [hxy, hyy]]) / count
    values, vectors = jnp.linalg.eigh(information)
    correction = matched[:2] - guess[:2]
    along = vectors.T @ correction
    keep = values >= params.tracking.min_curvature
    return vectors @ jnp.where(keep, along, 0.0)


def tracked_noise_scale(params: GridSlamParams, config: GridSlamConfig) -> Array:
    r"""The factor on the proposal's motion noise at a keyframe of the per-scan step
    (:class:`jaxslam.grid.types.Odometry` ``noise_scale``): ``tracking.noise_scale``
    (:math:`\kappa`) with tracking, 1 without (GMapping's odometry keyframes keep
    GMapping's noise).

    The filters' motion noise models raw wheel odometry: GMapping's srr/srt/str/stt
    (its defaults draw 0.2 rad of heading noise per metre) and SRUPF-GM's
    motion-proportional Q. With tracking the keyframe control is the tracked motion, a
    laser measurement wherever the tracking match was trusted. Proposals drawn with
    the odometry's full noise around it scatter the particles far beyond the reach of
    their hill climbs (at 1 m per scan, 11 deg of heading noise per draw); a particle
    that lands in a wrong optimum builds its map there and, scored against its own
    map, is hardly worse than the others. So with tracking the motion-proportional
    noise of every keyframe is scaled by :math:`\kappa`, also where matches were
    refused: refused matches are mostly sparse scenes, where wide proposals lose
    particles. The default 0.2 is a fifth of the odometry's noise: large enough
    values bring the scatter back, and the value is not a sharp optimum
    (``docs/design.md``, "Per-scan tracking").
    """
    if not config.tracking:
        return jnp.ones((), params.tracking.noise_scale.dtype)
    return params.tracking.noise_scale


def keyframe_noise_scale(params: GridSlamParams, config: GridSlamConfig, refused: Array) -> Array:
    r"""The motion-noise scale of a keyframe's proposals, given the number of tracking
    matches refused since the previous keyframe: :math:`\kappa`
    (:func:`tracked_noise_scale`), or ``tracking.refused_noise_scale`` where at least one
    was refused and that parameter is not negative (negative: :math:`\kappa`
    everywhere; 0.5 for SRUPF-GM, :data:`jaxslam.grid.algorithms.GRID_ALGORITHMS`).

    A trusted match makes the keyframe's control a laser measurement; a refused one
    leaves the odometry's increment in it, with the odometry's error, and
    :math:`\kappa` = 0.2 draws proposals a fifth as wide as that error. Where the
    odometry jumped (a sideways step of a metre that the scans do not show) the place
    where the scan fits can lie many standard deviations from such a proposal, and the
    bounded matcher turns the heading instead; sparse revisits, where every match
    scores a few percent of the beams, lose particles the same way. The odometry's
    full noise (1) is too wide the other way: in sparse stretches, whose scans cannot
    pull a particle back, keyframes land degrees off. Half the noise lies between the
    two ends; it is not a sharp optimum. With the recovery from odometry jumps
    (``config.recover_radius``) it is the SRUPF-GM default; the table is in
    ``docs/design.md`` ("The recovery, and wider proposals after a refused match").
    """
    kappa = tracked_noise_scale(params, config)
    if not config.tracking:
        return kappa
    wide = (refused > 0) & (params.tracking.refused_noise_scale >= 0)
    return jnp.where(wide, params.tracking.refused_noise_scale, kappa)


def is_keyframe(since: Array, params: GridSlamParams) -> Array:
    """GMapping's rule on ``since = (distance, rotation, time, scans, refused)``."""
    temporal = params.keyframes.temporal_update
    return (
        (since[0] >= params.keyframes.linear_update)
        | (since[1] >= params.keyframes.angular_update)
        | ((temporal >= 0) & (since[2] > temporal))
    )


def per_scan(keyframe_step):
    """The per-scan step of a filter whose (unguarded) keyframe step is ``keyframe_step``
    (see the module docstring). Same signature; ``control`` is the odometry
    :class:`~jaxslam.grid.types.Odometry` ``(increment, 1, dt)`` since the previous scan."""

    def step(key: Array, state: GridSlamState, control, observation: Scan, params: GridSlamParams,
             config: GridSlamConfig):
        control = as_odometry(control)
        dtype = state.poses.dtype
        motion, score, accepted, closed, conflict, memory, undo, search = track(state, control.increment,
                                                                                observation, params, config)
        delta = se2.relative(state.motion, motion)
        since = state.since_keyframe + jnp.stack([
            jnp.hypot(delta[0], delta[1]), jnp.abs(delta[2]), jnp.asarray(0.0 if control.dt is None else control.dt, dtype),
            jnp.ones((), dtype), jnp.logical_not(accepted).astype(dtype),
        ])

        def keyframe(key, state):
            odometry = Odometry(motion, since[3], since[2], keyframe_noise_scale(params, config, since[4]))
            new, info = keyframe_step(key, state, odometry, observation, params, config)
            applied = new.status.code == 0
            new = new._replace(
                motion=jnp.where(applied, jnp.zeros_like(motion), state.motion),
                since_keyframe=jnp.where(applied, jnp.zeros_like(since), state.since_keyframe),
                closure=jax.tree_util.tree_map(lambda a, b: jnp.where(applied, a, b), memory, state.closure),
            )
            return new, info._replace(track_score=score, track_accepted=accepted, track_closed=closed,
                                      track_conflict=conflict, track_undo=undo, track_search=search)

        def between(key, state):
            state = state._replace(motion=motion, since_keyframe=since, closure=memory)
            return state, empty_info(state, config)._replace(track_score=score, track_accepted=accepted,
                                                             track_closed=closed, track_conflict=conflict,
                                                             track_undo=undo, track_search=search)

        return jax.lax.cond(is_keyframe(since, params), keyframe, between, key, state)

    step.__doc__ = (
        "Every scan a step (:mod:`jaxslam.grid.tracking`) around the keyframe step:\n\n"
        + inspect.cleandoc(keyframe_step.__doc__ or "")
    )
    step.__name__ = "scan_step"
    return step


def scan_trajectory(first_pose: np.ndarray, keyframe_flags: np.ndarray, keyframe_poses: np.ndarray,
                    motions: np.ndarray, undo: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Host: a pose for every scan from a per-scan run.

    Args:
        first_pose: ``(3,)`` the pose of scan 0 (the filter's initial pose).
        keyframe_flags: ``(S-1,)`` ``Info.keyframe`` of scans ``1..S-1``.
        keyframe_poses: ``(K-1, 3)`` the chosen lineage's poses at those keyframes.
        motions: ``(S-1, 3)`` ``Info.motion`` (tracked motion since the last keyframe).
        undo: ``(S-1, 4)`` ``Info.track_undo``, or None: the closures undone are taken
            back on the scans they had moved (:func:`jaxslam.grid.undone_closures.take_back`).

    Returns:
        ``(keyframes (K,), trajectory (S, 3))``: scan indices of the keyframes (0
        first) and ``pose_s = keyframe pose (+) motion_s`` for every scan.
    """
    flags = np.asarray(keyframe_flags, bool)
    keyframes = np.concatenate([[0], np.flatnonzero(flags) + 1]).astype(np.int64)
    anchors = np.concatenate([np.asarray(first_pose, np.float64)[None], np.asarray(keyframe_poses, np.float64)], 0)
    # Scan s (1..S-1) belongs to the last keyframe at or before it.
    slot = np.cumsum(np.concatenate([[0], flags.astype(np.int64)]))
    motion = np.concatenate([np.zeros((1, 3)), np.asarray(motions, np.float64)], 0)
    trajectory = se2_compose(anchors[slot], motion)
    if undo is not None:
        trajectory = take_back(trajectory, np.arange(trajectory.shape[0]), undo)
    return keyframes, trajectory


__all__ = [
    "constrained_pose", "constrained_shift", "is_keyframe", "keyframe_match", "per_scan", "scan_trajectory", "track",
    "keyframe_noise_scale",
    "tracked_noise_scale",
]
