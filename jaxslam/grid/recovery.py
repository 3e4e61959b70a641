r"""Recovery from an odometry jump: a wide match where the tracking refuses its own.

The tracking (:mod:`jaxslam.grid.tracking`) climbs from the odometry's guess, and a
climb reaches a few tenths of a metre. Where the odometry jumps (a wheel that slips
sideways, a dropped or repeated message, or a corrected log's path that jumps where the
GMapping run that made it corrected its particle), the right pose lies beyond that
reach, the match scores like a scan that fits nowhere, it is refused, and the jump is
kept: the scan is written where it does not belong, and the next matches, against that
map, are refused too. A corrected log's reference can carry such jumps of 0.5-1.2 m
sideways that its own scans contradict (``benchmarks/scan_pair_agreement.py
--steps-over 0.5`` finds them); at such a scan the tracking's match scores a fraction
of its neighbours' scores, and the next matches are refused too.

**Which increments are jumps.** A wheeled base (differential drive, Ackermann) cannot
move sideways: over one increment :math:`u = (u_x, u_y, u_\theta)` it drives an arc,
which moves it :math:`u_x \tan(u_\theta / 2)` sideways, and its *slip*

.. math:: \sigma(u) = |u_y - u_x \tan(u_\theta / 2)|

(:func:`slip`) is zero up to the odometry's rounding (a centimetre or two on the raw
logs of wheeled robots). An increment that slips more than :data:`RECOVER_SLIP`
(0.25 m) and more than :data:`RECOVER_SLIP_SHARE` (0.3) of its length did not come
from the wheels' motion (:func:`jumped`; the share keeps out long steps whose turn was
not one arc, such as steps of 2-3 m turning 20-30 deg, whose slip reaches 0.2-0.3 m).

**The rule.** Where this scan's increment jumped and the tracking's match :math:`(x^*, s)` is refused (:math:`s/n \le` ``tracking.min_score``), the
loop-closure search's coarse stage searches around the guess :math:`\hat x` at a small
radius (:func:`jaxslam.grid.closure.coarse_candidates`, ``config.recover_radius`` m on
each axis, ``config.closure_turn`` either way, then GMapping's hill climb from the best
candidates, :func:`recovery_phases`), and its best pose :math:`x^r`
with score :math:`s^r` replaces the match where

.. math:: s^r / n > \texttt{track\_min\_score}, \qquad s^r \ge g\, s \quad (g = \texttt{RECOVER\_GAIN}):

a match the tracking would trust, clearly better than the refused one. The recovered
pose is taken whole: the odometry it replaces is what failed, so the constrained
correction (:func:`jaxslam.grid.tracking.constrained_pose`) is taken from :math:`x^r`
itself rather than from the guess. A scan that fits nowhere scores under the bar
everywhere and stays refused: the odometry is kept, no jump. The search runs only on
refused scans whose increment jumped (a ``lax.cond``): a log of wheel odometry never
slips, and runs the same to the last digit with and without it.

Why the slip test: a refused match is mostly a stretch with little to match, where a
search of a metre and a half finds a pose along a corridor that scores well and is
not the place; the test keeps the search to the scans whose odometry cannot be right,
and the share of the length keeps it off long real steps. Why wider proposals after a
refused match (``tracking.refused_noise_scale``, 2.5 times ``tracking.noise_scale``,
:func:`jaxslam.grid.tracking.keyframe_noise_scale`): the recovery alone puts the scan
back, but sparse revisits, where every match scores a few percent of the beams, still
lose particles to the climbs. Together they are SRUPF-GM's default
(:data:`jaxslam.grid.algorithms.GRID_ALGORITHMS`); the table with and without both is
in the design notes (``docs/design.md``, "The recovery, and wider proposals after a
refused match"), reproduced by ``benchmarks/grid_robustness.py``.

Unlike a loop closure it needs no confirmation and no high score (``closure.min_score``
0.35, which right matches in sparse scenes do not reach): its reach is one increment's jump,
not the drift of a loop.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax import Array

from jaxslam.grid.climbs import Phase, best_of
from jaxslam.grid.closure import coarse_candidates, refine_count

RECOVER_GAIN = 2.0
"""How much better than the refused match a recovered one must score."""

RECOVER_SLIP = 0.25
"""The sideways slip (m, :func:`slip`) of an odometry increment beyond which it is taken
for a jump and a refused match is searched again."""

RECOVER_SLIP_SHARE = 0.3
"""... and beyond which share of the increment's length (long steps slip more from
their rounding and from a turn that is not one arc)."""

RECOVER_RADIUS = 1.5
"""The search radius (m per axis, ``config.recover_radius``: SRUPF-GM's default;
0 leaves the recovery off)."""


def slip(increment: Array) -> Array:
    r"""How far the odometry increment :math:`u = (u_x, u_y, u_\theta)` (robot frame) moves
    sideways beyond the arc of a wheeled base, :math:`|u_y - u_x \tan(u_\theta / 2)|` (m):
    a base that drives along an arc of chord :math:`u_x` turning by :math:`u_\theta`
    moves :math:`u_x \tan(u_\theta/2)` sideways, and no more."""
    return jnp.abs(increment[1] - increment[0] * jnp.tan(0.5 * increment[2]))


def jumped(increment: Array) -> Array:
    """Whether the increment slips (:func:`slip`) more than :data:`RECOVER_SLIP` and more
    than :data:`RECOVER_SLIP_SHARE` of its length: an odometry that jumped."""
    sideways = slip(increment)
    return (sideways > RECOVER_SLIP) & (sideways > RECOVER_SLIP_SHARE * jnp.hypot(increment[0], increment[1]))


def recovery_phases(read, local_points: Array, weights: Array, guess: Array, count: Array, increment: Array,
                    params, config) -> list[Phase]:
    """The recovery's climbs as phases of the tracking's one climb
    (:mod:`jaxslam.grid.climbs`): where the match in the carry (``matched``, ``score``: a
    raw sum over the ``count`` matched beams) is refused and the increment jumped, one
    climb from each candidate of the search around ``guess`` (module docstring). After
    them the carry holds the tracking's match, or the recovered one where the search
    found a trusted, clearly better pose, and ``origin``: the pose the constrained
    correction is taken from (``guess``, or the recovered pose)."""
    dtype = guess.dtype
    bar = jnp.asarray(params.tracking.min_score, dtype)
    lanes = refine_count(config)

    def open_prepare(lane, carry):
        refused = (carry["score"] / count <= bar) & jumped(increment.astype(dtype))
        candidates = jax.lax.cond(
            refused,
            lambda: coarse_candidates(read, config.layout, local_points, weights, params.sensor.laser_offset, guess,
                                      params, config, radius=config.recover_radius),
            lambda: jnp.zeros((lanes, 3), dtype))
        carry = {**carry, "tracked": carry["matched"], "tracked_score": carry["score"], "searching": refused,
                 "candidates": candidates, "found": jnp.full((), -jnp.inf, dtype), "found_pose": candidates[0]}
        return carry, refused, candidates[0]

    def next_prepare(lane, carry):
        return carry, carry["searching"], carry["candidates"][lane + 1]

    def take(lane, carry, active, pose, score):
        carry = best_of(carry, active, pose, score)
        found_pose, found, score = carry["found_pose"], carry["found"], carry["tracked_score"]
        recovered = carry["searching"] & (found / count > bar) & (found >= RECOVER_GAIN * score)
        return {**carry, "matched": jnp.where(recovered, found_pose, carry["tracked"]),
                "score": jnp.where(recovered, found, score), "origin": jnp.where(recovered, found_pose, guess)}

    return [Phase(1, False, open_prepare, take), Phase(lanes - 1, False, next_prepare, take)]


def recovery_carry(dtype) -> dict:
    """The keys :func:`recovery_phases` adds to the tracking's carry, empty."""
    return {"tracked": jnp.zeros((3,), dtype), "tracked_score": jnp.zeros((), dtype)}


__all__ = ["RECOVER_GAIN", "RECOVER_RADIUS", "RECOVER_SLIP", "RECOVER_SLIP_SHARE", "jumped", "recovery_carry", "recovery_phases", "slip"]
