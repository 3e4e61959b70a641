"""The tracking's hill climbs as one program: phases of one climb, written once.

A scan's tracking climbs up to a dozen times: the coarse and the narrow climb of its
match and of the retry from a turned guess (:mod:`jaxslam.grid.tracking`), the climbs
from the candidates of the recovery's search (:mod:`jaxslam.grid.recovery`), the undo
of a closure, the follow-up of a held candidate and the climbs from the candidates of
the loop-closure search (:mod:`jaxslam.grid.closure`). Each climb written out on its own
puts another copy of the score kernel into the compiled program, about a second of
XLA's compilation each. Here each of them is a :class:`Phase`: a number of lanes (one
climb each, in turn), whether it climbs the coarse score (``matcher.coarse_sigma``,
``coarse_iterations``) or the narrow one (``matcher.score_sigma``, ``match_iterations``), and
two small functions, ``prepare(lane, carry) -> (carry, active, start)`` and
``take(lane, carry, active, pose, score) -> carry``, over a carry (a dict) the phases
share. :func:`run_phases` runs them all in one loop around one climb
(:func:`jaxslam.grid.matching.climbs_in_turn`): GMapping's hill climb with
``linear_step`` / ``angular_step`` moves, unbounded, on the score of one map.

A climb that does not run (``active`` False) returns its start with a score of
``-inf``, and costs a branch; the result of each climb is that of the same climb
written out, bit for bit.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxslam.grid.matching import Climb, climbs_in_turn, gmapping_basis


class Phase(NamedTuple):
    """Climbs of one kind in a :func:`run_phases` program (see the module docstring)."""

    lanes: int
    coarse: bool
    prepare: Callable
    take: Callable


def run_phases(score_at, phases: list[Phase], carry: dict, params, config) -> dict:
    """Every lane of every phase in turn, one climb each, in one loop (module docstring).

    Args:
        score_at: ``(poses (C, 3), sigma) -> scores (C,)`` on the map climbed.
        phases: the phases, in order; a phase without lanes is left out.
        carry: the phases' shared state; every key any phase writes must be in it,
            with its final shape and dtype.
        params: the filter's traced parameters (the steps, widths and iterations).
        config: the static configuration (``match_iterations``, ``coarse_iterations``).

    Returns:
        The carry after the last climb.
    """
    phases = [phase for phase in phases if phase.lanes > 0]
    if not phases:
        return carry
    kind = np.concatenate([np.full(phase.lanes, k) for k, phase in enumerate(phases)]).astype(np.int32)
    lane = np.concatenate([np.arange(phase.lanes) for phase in phases]).astype(np.int32)
    coarse = np.asarray([phase.coarse for phase in phases])
    dtype = jax.tree_util.tree_leaves(carry)[0].dtype
    basis = gmapping_basis(params, dtype)
    sigma = (jnp.asarray(params.matcher.score_sigma, dtype), jnp.asarray(params.matcher.coarse_sigma, dtype))

    def prepare(i, carry):
        k, ln = jnp.asarray(kind)[i], jnp.asarray(lane)[i]
        carry, active, start = jax.lax.switch(
            k, [lambda c, ln, p=phase: p.prepare(ln, c) for phase in phases], carry, ln)
        wide = jnp.asarray(coarse)[k]
        return carry, Climb(
            jnp.asarray(active), start, basis,
            jnp.where(wide, config.coarse_iterations, config.match_iterations),
            jnp.where(wide, sigma[1], sigma[0]), jnp.ones((), dtype))

    def take(i, carry, climb, pose, score):
        k, ln = jnp.asarray(kind)[i], jnp.asarray(lane)[i]
        return jax.lax.switch(
            k, [lambda c, ln, a, x, s, p=phase: p.take(ln, c, a, x, s) for phase in phases],
            carry, ln, climb.active, pose, score)

    return climbs_in_turn(score_at, int(kind.shape[0]), prepare, take, carry)


def best_of(carry: dict, active, pose, score) -> dict:
    """``carry`` with ``found_pose`` / ``found`` replaced where this climb ran and scores
    above the best so far (the first best wins, as ``argmax`` picks)."""
    better = active & (score > carry["found"])
    return {**carry, "found_pose": jnp.where(better, pose, carry["found_pose"]),
            "found": jnp.where(better, score, carry["found"])}


__all__ = ["Phase", "best_of", "run_phases"]
