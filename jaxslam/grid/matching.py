r"""Scan matchers (pose correctors) for one particle, fixed iteration counts.

All matchers share one signature,

``matcher(score_fn, pose, pose_sqrt_cov, params, iterations, refine_steps, prior_mean=None)
-> (pose, score)``

where ``score_fn`` maps candidate poses ``(C, 3)`` to scores ``(C,)`` (one particle's
map and scan, see :func:`jaxslam.grid.score.make_score_fn`) and ``params`` is any
object with the fields of :class:`MatchParams` (the filters pass their ``Params``).
Candidates are written as :math:`x = \mu + B u`, with a basis :math:`B` and a search
coordinate :math:`u` that starts at 0:

* :func:`hill_climb_match` — GMapping's ``ScanMatcher::optimize`` (Grisetti et al.
  2007): from the start pose try the six moves :math:`\pm\delta` along ``x``, ``y``
  (world axes, ``linear_step``) and :math:`\theta` (``angular_step``), move to the
  best if it beats the current score, otherwise halve :math:`\delta`.
  ``B = diag(linear_step, linear_step, angular_step)``.
* :func:`ellipse_match` — the pose correction of SRUPF-GM (Zandara & Nicholson
  2009, Sec. 3.2, Fig. 1b): the same deterministic moves, but the step
  :math:`\delta` comes from the predicted covariance :math:`P = S S^T`
  (``B = ellipse_step * diag(sqrt(diag P))``) and candidates outside the
  ellipse :math:`\lVert S^{-1}(x - \mu)\rVert \le` ``matcher.ellipse_radius`` are not
  considered. (Moving along the columns of :math:`S` instead couples heading and
  position in one move, and coordinate-wise hill climbing then stalls on the
  resulting ridges of the score.)
* :func:`gradient_refine` — a few ``optax.adam`` steps on :math:`-s(\mu + B u)`
  (the bilinear map is differentiable almost everywhere), keeping the best pose seen.
* ``refine_steps > 0`` follows either search with the gradient refinement.

A climb of ``iterations`` evaluates 6 candidates per iteration, and 6 copies of the
start first (one score kernel in the program for both), so the cost per particle is
``6 * (iterations + 1)`` scans, fixed (static shapes under ``vmap``). Climbs that run
one after another share one kernel through :func:`climbs_in_turn`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax import Array

from jaxslam.core import se2
from jaxslam.core.spec import choose
from jaxslam.core.sqrt import tria

ScoreFn = Callable[[Array], Array]


class MatchParams(NamedTuple):
    """Traced matcher settings (the filters' Params carry the same fields)."""

    linear_step: Array | float = 0.05
    angular_step: Array | float = 0.05
    ellipse_radius: Array | float = 5.0
    ellipse_step: Array | float = 1.0
    ellipse_floor: Array | float = 0.005
    learning_rate: Array | float = 0.3


def _poses(center: Array, basis: Array, u: Array) -> Array:
    p = center + u @ basis.T
    return p.at[..., 2].set(se2.wrap_angle(p[..., 2]))


class EllipseBound(NamedTuple):
    """Candidates must satisfy ``|S^{-1} (x - mean)| <= radius`` (wrapped heading)."""

    mean: Array  # (3,)
    sqrt_cov: Array  # (3, 3) lower
    radius: Array  # ()


def hill_climb(
    score_fn: ScoreFn,
    center: Array,
    basis: Array,
    iterations: int | Array,
    bound: EllipseBound | None = None,
    initial_step: Array | float = 1.0,
) -> tuple[Array, Array, Array]:
    """Hill climbing with step halving in ``u``, ``x = center + basis @ u``.

    The start is scored first (in the loop's first pass, so that the program holds one
    score kernel); then each iteration scores the six moves ``u +- step e_i``; the best
    replaces ``u`` if it beats the current score, else ``step`` halves. With ``bound``,
    candidates outside the ellipse are skipped. ``iterations`` may be traced.

    Returns:
        ``(pose (3,), score (), u (3,))``.
    """
    dtype = center.dtype
    eye = jnp.eye(3, dtype=dtype)
    moves = jnp.concatenate([eye, -eye])  # (6, 3)
    u0 = jnp.zeros((3,), dtype)
    if bound is not None:
        # |S^-1 (center + B u - mean)| = |a + M u|, precomputed once.
        offset = center - bound.mean
        offset = offset.at[2].set(se2.wrap_angle(offset[2]))
        a = jax.scipy.linalg.solve_triangular(bound.sqrt_cov, offset, lower=True)
        m = jax.scipy.linalg.solve_triangular(bound.sqrt_cov, basis, lower=True)
        radius_sq = jnp.asarray(bound.radius, dtype) ** 2

    def body(i, carry):
        # Pass 0 scores the start itself (six copies of it, the first taken): the
        # program holds one score kernel per climb, not one for the start and one for
        # the moves.
        u, score, step = carry
        first = i == 0
        cand_u = u + step * moves
        scores = score_fn(jnp.where(first, jnp.broadcast_to(center, (6, 3)), _poses(center, basis, cand_u)))
        if bound is not None:
            w = a + cand_u @ m.T
            scores = jnp.where(first | (jnp.sum(w * w, -1) <= radius_sq), scores, -jnp.inf)
        best = jnp.argmax(scores)
        better = ~first & (scores[best] > score)
        u = jnp.where(better, cand_u[best], u)
        score = jnp.where(first, scores[0], jnp.where(better, scores[best], score))
        step = jnp.where(better | first, step, 0.5 * step)
        return u, score, step

    step0 = jnp.asarray(initial_step, dtype)
    u, score, _ = jax.lax.fori_loop(0, iterations + 1, body, (u0, jnp.full((), -jnp.inf, dtype), step0))
    return _poses(center, basis, u), score, u


class Climb(NamedTuple):
    """One hill climb of :func:`climbs_in_turn`: whether it runs, where it starts, its
    move basis, iterations, the width of the score kernel and the first step."""

    active: Array  # () bool; a climb that does not run returns its start with score -inf
    start: Array  # (3,)
    basis: Array  # (3, 3)
    iterations: Array  # () int32
    sigma: Array  # () the score's kernel width (``ScoreModel.sigma``)
    initial_step: Array  # ()
    bound: EllipseBound | None = None


def climbs_in_turn(score_at, stages: int, prepare, take, carry):
    """Hill climbs one after another, written once in the program.

    Every climb of a matcher scores its candidates with the same kernel; written out
    climb by climb, the program holds that kernel once per climb (for XLA to compile
    each time). Here one loop of ``stages`` passes runs one :func:`hill_climb` per
    pass: ``prepare(i, carry) -> (carry, Climb)`` says what pass ``i`` climbs (the
    stage-specific pieces, a ``lax.switch`` where stages differ), and
    ``take(i, carry, climb, pose, score) -> carry`` what it does with the result.

    Args:
        score_at: ``(poses (C, 3), sigma) -> scores (C,)``.
        stages: the number of passes (static).
        prepare, take: see above; ``i`` is the traced pass index.
        carry: the loop's state (any pytree).

    Returns:
        The carry after the last pass.
    """

    def body(i, carry):
        carry, climb = prepare(i, carry)

        def run():
            pose, score, _ = hill_climb(lambda poses: score_at(poses, climb.sigma), climb.start, climb.basis,
                                        climb.iterations, climb.bound, climb.initial_step)
            return pose, score

        def rest():
            return climb.start, jnp.full((), -jnp.inf, climb.start.dtype)

        pose, score = jax.lax.cond(climb.active, run, rest)
        return take(i, carry, climb, pose, score)

    return jax.lax.fori_loop(0, stages, body, carry)


def gradient_refine(
    score_fn: ScoreFn, center: Array, basis: Array, steps: int, learning_rate
) -> tuple[Array, Array]:
    """Maximise ``score_fn(center + basis @ u)`` with ``optax.adam``; best pose seen."""
    import optax  # here, not at module level: 0.06 s of every run's start-up, used only with refine_steps > 0

    dtype = center.dtype
    optimizer = optax.adam(learning_rate)
    u0 = jnp.zeros((3,), dtype)

    def loss(u):
        return -score_fn(_poses(center, basis, u)[None])[0]

    value_and_grad = jax.value_and_grad(loss)

    def body(_, carry):
        u, opt_state, best_u, best_score = carry
        value, grad = value_and_grad(u)
        better = -value > best_score
        best_u = jnp.where(better, u, best_u)
        best_score = jnp.where(better, -value, best_score)
        updates, opt_state = optimizer.update(grad, opt_state, u)
        u = optax.apply_updates(u, updates)
        return u, opt_state, best_u, best_score

    init = (u0, optimizer.init(u0), u0, -jnp.inf * jnp.ones((), dtype))
    u, _opt_state, best_u, best_score = jax.lax.fori_loop(0, steps, body, init)
    last = -loss(u)
    best_u = jnp.where(last > best_score, u, best_u)
    best_score = jnp.maximum(last, best_score)
    return _poses(center, basis, best_u), best_score


def gmapping_basis(params, dtype) -> Array:
    return jnp.diag(
        jnp.stack(
            [
                jnp.asarray(params.matcher.linear_step, dtype),
                jnp.asarray(params.matcher.linear_step, dtype),
                jnp.asarray(params.matcher.angular_step, dtype),
            ]
        )
    )


def ellipse_factor(pose_sqrt_cov: Array, params) -> Array:
    """``S`` with a small floor so that a collapsed covariance still searches a little."""
    dtype = pose_sqrt_cov.dtype
    floor = jnp.broadcast_to(jnp.asarray(params.matcher.ellipse_floor, dtype), (3,))
    return tria(jnp.concatenate([pose_sqrt_cov, jnp.diag(floor)], -1))


def ellipse_basis(pose_sqrt_cov: Array, params) -> Array:
    """World-axis moves scaled by the marginal standard deviations of the ellipse."""
    factor = ellipse_factor(pose_sqrt_cov, params)
    return jnp.diag(jnp.sqrt(jnp.sum(factor * factor, -1)))


def hill_climb_match(
    score_fn, pose, pose_sqrt_cov, params, iterations: int, refine_steps: int = 0, prior_mean=None
):
    """GMapping's hill climbing (world-axis moves, step halving); see module docstring."""
    basis = gmapping_basis(params, pose.dtype)
    best, score, _ = hill_climb(score_fn, pose, basis, iterations)
    if refine_steps:
        best, score = gradient_refine(score_fn, best, basis, refine_steps, params.matcher.learning_rate)
    return best, score


def ellipse_match(
    score_fn, pose, pose_sqrt_cov, params, iterations: int, refine_steps: int = 0, prior_mean=None
):
    """SRUPF-GM pose correction: GMapping's moves with steps from the covariance,
    inside the covariance ellipse.

    The steps along ``x``, ``y`` and ``theta`` are ``ellipse_step`` marginal standard
    deviations of ``S`` (GMapping uses fixed lstep/astep), and a candidate must lie
    within ``matcher.ellipse_radius`` (Mahalanobis) of ``prior_mean`` (the predicted mean;
    default ``pose``), so a search started from a sample of the prediction covers
    the same region as one started from its mean.
    """
    bound = search_bound("ellipse", pose if prior_mean is None else prior_mean, pose_sqrt_cov, params)
    basis = jnp.diag(jnp.sqrt(jnp.sum(bound.sqrt_cov * bound.sqrt_cov, -1)))
    best, score, _ = hill_climb(score_fn, pose, basis, iterations, bound, params.matcher.ellipse_step)
    if refine_steps:
        best, score = gradient_refine(score_fn, best, basis, refine_steps, params.matcher.learning_rate)
    return best, score


def gradient_match(
    score_fn, pose, pose_sqrt_cov, params, iterations: int, refine_steps: int = 0, prior_mean=None
):
    """Gradient ascent only (``iterations + refine_steps`` adam steps) in the ellipse basis."""
    basis = ellipse_basis(pose_sqrt_cov, params)
    return gradient_refine(score_fn, pose, basis, iterations + refine_steps, params.matcher.learning_rate)


MATCHERS = {
    "hill": hill_climb_match,
    "ellipse": ellipse_match,
    "gradient": gradient_match,
}


def search_bound(
    matcher: str | Callable, centre: Array, pose_sqrt_cov: Array, params, radius=None
) -> EllipseBound | None:
    r"""The region a matcher may search: for ``"ellipse"`` the poses within
    ``radius`` (default ``matcher.ellipse_radius``) standard deviations of ``centre`` under
    the prediction's covariance (with the floor of :func:`ellipse_factor`),
    :math:`\|S^{-1}(x - \mu)\| \le r`; ``None`` (anywhere) for the others, whose
    climbs are GMapping's unbounded ones. The coarse stage that climbs before the
    matcher (:func:`jaxslam.grid.filter.coarse_start`) takes the same ellipse with
    ``params.matcher.coarse_radius``.
    """
    if matcher not in ("ellipse", ellipse_match):  # the name or the function (get_matcher takes both)
        return None
    factor = ellipse_factor(pose_sqrt_cov, params)
    r = params.matcher.ellipse_radius if radius is None else radius
    return EllipseBound(centre, factor, jnp.asarray(r, centre.dtype))


def get_matcher(name: str | Callable) -> Callable:
    """A matcher of ``MATCHERS`` by name, or ``name`` itself when it is one."""
    return choose(MATCHERS, name, "matcher")


__all__ = [
    "MATCHERS",
    "EllipseBound",
    "Climb",
    "MatchParams",
    "ellipse_basis",
    "ellipse_factor",
    "climbs_in_turn",
    "ellipse_match",
    "get_matcher",
    "gmapping_basis",
    "gradient_match",
    "gradient_refine",
    "hill_climb",
    "hill_climb_match",
    "search_bound",
]
