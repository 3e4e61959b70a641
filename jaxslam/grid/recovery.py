r"""Recovery from an odometry jump: a wide match where the tracking refuses its own.

The tracking (:mod:`jaxslam.grid.tracking`) climbs from the odometry's guess, and a
climb reaches a few tenths of a metre. Where the odometry jumps (a wheel that slips
sideways, a dropped or repeated message, or a corrected log's path that jumps where the
GMapping run that made it corrected its particle), the right pose lies beyond that
reach, the match scores like a scan that fits nowhere, it is refused, and the jump is
kept: the scan is written where it does not belong, and the next matches, against that
map, are refused too. The perturbed Freiburg campus has twelve such jumps of 0.5-1.2 m
sideways in its reference, which its own scans contradict
(``benchmarks/scan_pair_agreement.py --steps-over 0.5``); at the first, scan 238, the tracking's match scored 0.044 of the beams against
0.17-0.26 for its neighbours, and the next five were refused too.

**Which increments are jumps.** A wheeled base (differential drive, Ackermann) cannot
move sideways: over one increment :math:`u = (u_x, u_y, u_\theta)` it drives an arc,
which moves it :math:`u_x \tan(u_\theta / 2)` sideways, and its *slip*

.. math:: \sigma(u) = |u_y - u_x \tan(u_\theta / 2)|

(:func:`slip`) is zero up to the odometry's rounding: at most 0.005 m over Intel's 13,630
increments and MIT Killian's 17,479, 0.012 m on FR079, 0.02 m on the Freiburg clinic.
An increment that slips more than :data:`RECOVER_SLIP` (0.25 m) and more than
:data:`RECOVER_SLIP_SHARE` (0.3) of its length did not come from the wheels' motion
(:func:`jumped`; the share keeps out long steps whose turn was not one arc, such as the
perturbed Orebro's 2-3 m steps turning 20-30 deg, whose slip reaches 0.2-0.3 m): the
perturbed campus has 22-24 of them (its twelve reference jumps and their neighbours),
the perturbed Orebro 5-9, CSAIL 3-6, Intel 1-2, the infinite corridor 2, FHW 0-1, the
other perturbed logs none (high noise, seeds 0-4).

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
slips, and runs the same to the last digit with and without it (raw Intel, seed 0,
checked).

Without the slip test (every refused match searched again), measured on this machine
(``srupf-gm``, 30 particles, seeds 0-4, relations error mean per seed, m):
the campus improved (0.302 / 0.394 / 0.232 / 1.444 / 0.107 against 0.789 / 0.280 / 0.512 /
1.664 / 0.319) but the perturbed infinite corridor got worse (0.177 / 0.129 / 0.376 /
1.131 / 0.140 against a mean of 0.181 and a worst seed of 0.295) and MIT Killian's seed 1
(0.980 against 0.305): there the first searched scans had plain increments (1 m
straight ahead, or a turn in place) and were refused for other reasons, a stretch with
little to match, where a 1.5 m search finds a pose along a corridor that scores well
and is not the place. The slip test keeps the search to the scans whose odometry
cannot be right. With the slip test alone (no share of the length), the perturbed
Orebro got worse (0.200 / 0.075 / 0.136 / 0.095 / 0.074 against 0.138 / 0.075 / 0.137 /
0.070 / 0.060), through searches at long real steps; with the share it runs as main.
Alone, over the coarse-to-fine match (:func:`jaxslam.grid.filter.coarse_start`): at scan
238 every seed takes the scans' step (ten of ten short runs keep their heading within
2 deg to scan 300, against four of ten without it), but the campus's later revisits,
where every match scores 0.003-0.04 of the beams, still lose seeds (seed 5: 9.7 m, its
heading turned 100 deg over scans 1706-1750 by the particles' climbs); elsewhere it
changes two runs (Orebro seeds 1 and 9, 0.049 -> 0.072 and 0.064 -> 0.061 m).
With proposals 2.5 times wider (``tracking.refused_noise_scale``
0.5 against ``tracking.noise_scale`` 0.2) after refused matches
(:func:`jaxslam.grid.tracking.keyframe_noise_scale`): the campus's seeds 0-9 all mapped
(0.080-0.184 m, mean 0.117, against 0.998 and a worst seed of 2.639 m before, and
GMapping C++'s 0.452 and 2.420 m; seeds 10-19 0.850 m mean, three of them 1.7-2.1 m),
and together they are SRUPF-GM's default
(:data:`jaxslam.grid.algorithms.GRID_ALGORITHMS`; ``benchmarks/grid_robustness.py``).

Unlike a loop closure it needs no confirmation and no high score (``closure.min_score``
0.35, which the campus's right matches never reach): its reach is one increment's jump,
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
"""The search radius measured (m per axis, ``config.recover_radius``: SRUPF-GM's default;
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
