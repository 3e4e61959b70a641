r"""Loop-closure search: a wide, coarse scan match where the tracking's local match fails.

The tracking (:mod:`jaxslam.grid.tracking`) matches every scan by hill climbing from
the odometry guess, which reaches a few tenths of a metre and a few degrees. Coming
back to a place mapped long ago after a long loop, the guess can be metres and
degrees off the old map (a few metres and degrees where a long loop returns). The
local match then finds little (its score falls from
0.45-0.6 to 0.1-0.25 of the beams), the robot maps a second copy of the place, and
from then on it matches its own copy. This module searches wide when that happens.

For a start pose :math:`x_0` (the local match), the search scores every candidate

.. math:: x_{k,i,j} = x_0 + (i h, j h, k \delta), \qquad |i|, |j| \le R/h,\ |k| \le \Theta/\delta,

(``R`` = ``config.closure_radius``, ``Θ`` = ``config.closure_turn``, :math:`h`
:data:`SHIFT_CELLS` coarse cells, :math:`\delta` = :data:`TURN_STEP`) on a coarse map:
the best particle's occupancy :math:`o(c) = \mathrm{clip}(\ell(c), 0, \ell_{sat}) /
\ell_{sat}` in a window around :math:`x_0`, max-pooled over :data:`POOL` x
:data:`POOL` cells and then over the 3 x 3 coarse neighbours, so that a candidate
within :math:`h/2` of the true pose finds every wall it should:

.. math:: S(x) = \sum_b w_b\, \bar o(e_b(x)) \quad (\bar o \text{ the coarse map, } e_b
    \text{ the end point of beam } b,\ w_b \text{ the matching weights}).

The best candidate of each heading is kept, and the :data:`REFINE` best of those are
refined with GMapping's hill climb on the full map (:func:`jaxslam.grid.matching.hill_climb_match`,
the tracking's own matcher and score). The best refined pose
:math:`x^*` with score :math:`s^*` is a *candidate* for the local match
:math:`(x_0, s_0)` when

.. math:: s_0 < \tau_{trigger}, \qquad f_0 \ge f_{min}, \qquad s^* \ge s_{min},
    \qquad s^* \ge g\, s_0, \qquad |x^*_{xy} - x_{0,xy}| \le \max(j, \beta d)

(scores as fractions of the matched beams; ``closure.trigger``, ``closure.conflict``,
``closure.min_score``, ``closure.gain``, ``closure.jump``, ``closure.drift``), with
:math:`f_0` the fraction of beams whose end point at :math:`x_0` lies in known free
space (:func:`conflict_fraction`, recorded for every scan as ``Info.track_conflict``)
and :math:`d` the odometry distance since the last closure. The search runs only
under the trigger (a ``lax.cond``), so a scan that matches well costs nothing more.
The gain keeps a corridor's equally good poses along its axis from winning (they
score like the local match), the minimum keeps sparse scenes, where even right
matches score 0.1-0.3, from taking a chance alignment.

A candidate is *held* (its world correction :math:`C = x^* \ominus_w x_0`, that is
:math:`x^* = C \oplus x_0`, in the state's ``closure``, a
:class:`~jaxslam.grid.types.ClosureState`) and confirmed by the
scans that follow: each of them climbs from :math:`C \oplus x_0'` (its own local
match moved by the held correction) and must pass the same tests (with
``closure.confirm_gain`` in place of the gain where that is set; off by default: at
1.2 every MIT Killian seed of 20 scores under 0.3 m, but the perturbed corridor's
aliases close and its worst seed goes from 0.57 to 1.56 m; ``docs/benchmarks.md``,
"Confirmation at a lower gain"). After ``closure.confirm`` (3) wins in a row the
candidate replaces the local match; one loss drops it (:func:`closure_phases`). The
bound on the jump is the drift the tracking can have gathered since the last closure,
:math:`\beta` = 0.5 m per metre of odometry, and at least :math:`j` = 0.5 m: right
after a closure the robot is on the old map, so a second jump of metres within a few
metres of travel is an alias (a corridor's doors, repeated every few metres), not
drift. The tracking then keeps of the closure's position correction only the part the
scan constrains, as for any match
(:func:`jaxslam.grid.tracking.constrained_pose`).

**The trigger** (``closure.trigger``, 0.25, raised by ``closure.trigger_ratio``, 0.8).
Back at a place mapped long ago after a long loop, the robot has drawn a copy of it a
few metres off the old map by the time its beams reach the old walls, and the local
match fits that copy: on MIT Killian's return at scan 11,000, 270-280 m after the last
closure, it scores 0.35-0.56 of the beams (means over 100 scans), and the search ran on
4-5 scans of the return in the runs that lost it. A fixed trigger of 0.35 runs it
there, and over 20 MIT Killian seeds the seeds over twice the median seed go from 7 to
1; but on the perturbed Freiburg campus, outdoors, the right matches score 0.27 in the
median scan and 71 % of them under 0.35 (3 % on MIT Killian; seed 0), the search runs
on most of the log, and the worst of 10 seeds goes from 1.74 to 5.60 m. So the trigger
follows the log: the search also runs under ``closure.trigger_ratio`` times the running
mean of the tracking's scores (``ClosureState.level``), 0.39
in the median scan of MIT Killian's second half and 0.25 on most of the campus. Over
the same seeds MIT Killian's seeds over twice the median seed go from 7 to 2 (at 0.7
and 0.8; the mean over the seeds from 0.367 to 0.211 and 0.188 m), the perturbed
corridor's worst seed from 0.976 m (at 0 and 0.7) to 0.570 m at 0.8, and the
campus draws the same runs bit for bit (``docs/benchmarks.md``, "The trigger follows
the log's matches").

**The first closure** (``closure.first_drift``, 0.02 m per m by default). Until a
closure is taken the map is one drawing, off from the path by the tracking's own
drift only, so the first closure's jump is bounded by :math:`\max(j, \gamma_1 d)`,
:math:`d` the odometry since the start, where :math:`\beta d` would let an alias metres
away (a corridor's doors) pass after a few dozen metres. Over 220 runs of nine logs
no right first closure jumped more than 0.74 of :math:`0.02\, d`; on MIT Killian the
ones it refuses made the worst seed and another over 0.8 m (``docs/benchmarks.md``,
"A bound on the first closure").

**The map's offset** (``config.closure_map_bound``, off by default). A closure moves
the pose, not the map already written, so the place a return matches may have been
drawn before earlier closures moved the path, and be off by up to the sum
:math:`\Sigma` of their corrections; the tracking itself drifts by about
:math:`\gamma d` (``closure.reach_rate``). With the option the jump is bounded by
:math:`\min(\beta d, \gamma d + \Sigma)` (:func:`closure_outcome`): before the first
closure by the tracking's drift alone, where :math:`\beta d` lets an alias metres away
pass after a hundred metres of travel.

Why a jump bound and confirmation: a single scan's wide match finds aliases (a
corridor's doors, repeated every few metres, or a stretch along a corridor's axis), and
without the bound a run that took one went on jumping at the same place, metres every
few dozen scans. A false closure that passes every test at the candidate still shows
itself afterwards, which the watch below uses. Three tests at the candidate do not
separate false closures from right ones (right and wrong judged by a benchmark's
relations), so they are off or absent: the conflict test
(``closure.conflict``, default 0), a margin over the best candidate at least 1 m away,
and the share of beams in known free space at the candidate. A refused right closure
leaves the drift in place until the next chance, which may be far.

**Watch and undo** (``closure.undo``; 1: off). Averaged over ``closure.watch`` m of
odometry after a closure, the share of beams ending in known free space separates
false closures from right ones far better than any test at the candidate: the scans
that show an alias come after the jump. So a closure taken is watched and undone where
that mean exceeds ``closure.undo`` (0.11: lower thresholds undo right closures along
long corridors, whose kept closures watch at up to about 0.11); the undo takes back the
correction the tracking applied (the closure's, less what
:func:`jaxslam.grid.tracking.constrained_pose` dropped), whatever the match at the
undone pose scores, and refuses the same candidate afterwards. The map keeps what the
scans in between wrote. The search, with its watch and undo, is SRUPF-GM's default
(:data:`jaxslam.grid.algorithms.GRID_ALGORITHMS`); the GMapping-style filter, a baseline
for GMapping, which has no such search, keeps it off.

**Fast undo** (``closure.undo_fast``; 1: off, the default) undoes a closure before the
watch ends, once the watched share averages over it on at least two scans and
:data:`FAST_SHARE` of the watch. It undoes false closures a few scans sooner but also
right ones in sparse scenes, so it is an option.

**The path reported** takes an undone closure back
(:func:`jaxslam.grid.undone_closures.take_back`): the scans between the closure and its
undo were tracked in the closure's frame, which the filter has since rejected, so their
poses are reported in the frame it kept, :math:`A^{-1} \oplus x_s` (as the path of a
lineage is reported after the resamplings that chose it). The filter itself is
unchanged; ``Info.track_undo`` records what each undo took back.

**No closure inside a watch** (``closure.nest``; 0: the default). After a false closure
the tracking's matches score low and the search starts again; a closure taken inside
the watch would restart it, and the first one would never be judged. So the search
waits until the watch has ended (kept or undone); ``closure.nest`` 1 lets it nest.

**The end of the run** (:func:`jaxslam.grid.undone_closures.judge_at_end`,
``closure.undo_end``). A log can end inside a watch; the path reported judges such a
closure on the scans it had, with a higher bar (0.2) because fewer scans are averaged.
Only the reported path and keyframe poses move; the filter is unchanged.

**Reach.** ``closure_radius`` is 6 m: the drift met at a long loop's return
reaches 4-6 m, and a search that cannot reach the right pose finds an alias instead;
at 8 m the window holds more aliases than right closures gain. The candidates grow as
:math:`R^2` (63,000 at 6 m against 29,000 at 4 m), on the scans under the trigger only.

**Reach that grows with the distance since the last closure.** Where
``closure.reach_rate`` :math:`\gamma` times the odometry distance :math:`d` since the
last closure exceeds ``R``, a second coarse stage (``config.closure_radius_far``,
10 m) scores the candidates of the near search's square and those within
:math:`\min(\gamma d, R_{far})` of :math:`x_0` (a disc: the drift it bounds has no
preferred axis); both stages feed one refinement (:func:`coarse_candidates`,
:func:`closure_phases`), so the program holds the refinement once. :math:`\gamma` = 0.02 m
per m bounds the drift of the tracking over a long loop without a closure. Below
:math:`R / \gamma` = 300 m the far stage never runs, and a run whose searches all start
within 300 m of the last closure is the same to the last digit with and without it. A
closure moves the pose, not the map already written: after a large right closure the
map keeps the copy of the place that the drifted scans wrote, and the tracking can
later slide onto it; the larger the jump, the larger the copy.

What the search gives on a log with a long loop, and what it costs: the design notes
(``docs/design.md``, "The loop-closure search and its watch"), reproduced by
``benchmarks/grid_robustness.py``.

Cost: one window of :math:`(2(r + R)/\rho)^2` cells (``r`` =
:data:`SEARCH_REACH`; beams beyond it take no part in the coarse stage), about
:math:`1.1 \cdot 10^6` reads at 5 cm, and
:math:`(2\Theta/\delta + 1)(2R/h + 1)^2` candidates of half the matched beams, scored as
sums of shifted blocks of the coarse map (:func:`candidate_scores`): 1.3-2.3 ms for
63,000 candidates on one core of the 2-core machine, where reading each candidate's
end points one by one took 9-18 ms, for the scans under the trigger
only. Logs whose matches score low for long stretches trigger it on a large share of
their scans: on fr-clinic (long-range scans, matches at 0.1-0.3 of the beams, no
closure taken in the whole log) the filter loop took 160.6 s before and 90.1 s after
(30 particles, one core each, the two runs side by side), and 60.0 s with the search
off, the same run bit for bit.

What the reports do on the host with the undos recorded here (the path reported after
an undone closure, the judgment of a closure still watched at the end) is
:mod:`jaxslam.grid.undone_closures`.

One module of about 540 lines, a quarter of them the rules above: the search, its
confirmation and its watch share the candidate window and the layout of the closure
memory they carry from scan to scan; judging a closure at the end of a run and the
path it takes back are in :mod:`jaxslam.grid.undone_closures`.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from jaxslam.core import se2
from jaxslam.grid.map import CellReader
from jaxslam.grid.climbs import Phase, best_of
from jaxslam.grid.score import cell_coords
from jaxslam.grid.types import ClosureState

POOL = 2
"""Fine cells per coarse cell along each axis (10 cm coarse cells at 5 cm)."""

SHIFT_CELLS = 2
"""Translation step of the candidates in coarse cells (20 cm at 5 cm); with the 3 x 3
dilation every point within half a step of a wall still reads it."""

TURN_STEP = math.radians(1.0)
"""Heading step of the candidates (rad)."""

SEARCH_REACH = 20.0
"""Beams longer than this (m) take no part in the coarse stage (they do in the
refinement); it bounds the window of cells the search reads."""

BEAM_STRIDE = 2
"""The coarse stage scores every second matched beam."""

REFINE = 4
"""Headings whose best candidate is refined on the full map."""

FAST_SHARE = 0.2
"""Share of ``closure.watch`` after which ``closure.undo_fast`` can undo a closure (with
at least two scans watched: a robot standing still repeats one scan's conflict)."""

REFUSED_SCORE = 1
"""``Info.track_search``'s refusal bit: the candidate scored under ``closure.min_score``."""
REFUSED_GAIN = 2
"""... it scored under ``closure.gain`` times the local match."""
REFUSED_JUMP = 4
"""... it lay farther from the local match than the jump bound allows."""
REFUSED_ALIAS = 8
"""... its correction is that of a closure undone before (an alias)."""


def coarse_window(read: CellReader, frame, centre: Array, half: int, saturation) -> tuple[Array, Array]:
    r"""The coarse map around ``centre (2,)`` (world, m): ``(coarse (n, n) [row, col],
    corner (2,))``, with ``corner`` the world position of coarse cell ``(0, 0)``'s corner.

    ``half`` (static) is the window's half side in fine cells, a multiple of
    :data:`POOL`; ``n = 2 half / POOL``.
    """
    dtype = centre.dtype
    res = frame.resolution
    origin = jnp.asarray([frame.origin_x, frame.origin_y], dtype)
    c0 = jnp.floor(cell_coords(centre, frame)).astype(jnp.int32) - half
    cols = c0[0] + jnp.arange(2 * half, dtype=jnp.int32)
    rows = c0[1] + jnp.arange(2 * half, dtype=jnp.int32)
    sat = jnp.asarray(saturation, dtype)
    occ = jnp.clip(read(cols[None, :], rows[:, None]).astype(dtype), 0, sat) / sat
    n = 2 * half // POOL
    coarse = occ.reshape(n, POOL, n, POOL).max(axis=(1, 3))
    coarse = jax.lax.reduce_window(coarse, jnp.asarray(0, dtype), jax.lax.max, (3, 3), (1, 1), "SAME")
    return coarse, origin + c0.astype(dtype) * jnp.asarray(res, dtype)


def window_half(frame, radius: float) -> int:
    """Static half side (fine cells) of the window that holds every end point of a beam
    up to :data:`SEARCH_REACH` from any candidate within ``radius``."""
    cells = math.ceil((SEARCH_REACH + radius) / frame.resolution) + 2 * POOL
    return POOL * math.ceil(cells / POOL)


def candidate_scores(coarse: Array, corner: Array, cell: float, start: Array, local_points: Array, weights: Array,
                     laser_offset: Array, turns: Array, m: int) -> Array:
    r"""``S`` of every candidate, ``(turns, 2m + 1, 2m + 1)`` ``[turn, y shift, x shift]``
    (unnormalised): the shifts are ``-m`` to ``m`` steps of :data:`SHIFT_CELLS` coarse cells.

    For a heading, end point :math:`b` lies in coarse cell :math:`(c_b, r_b)` at the
    unshifted pose; at the shift of :math:`(i, j)` steps (:math:`|i|, |j| \le m`) it lies in
    :math:`(c_b + h i,\ r_b + h j)`, :math:`h` = :data:`SHIFT_CELLS` (the candidates
    move by whole coarse cells), so

    .. math:: S_{j,i} = \sum_b w_b\, \bar o(r_b + h j,\ c_b + h i)
        = \sum_b w_b\, T_b[j + m, i + m],

    with :math:`T_b` the :math:`(2m+1)^2` block of the coarse map from
    :math:`(r_b - hm, c_b - hm)` with stride :math:`h`. The coarse map is split into its
    :math:`h^2` phases (every :math:`h`-th row and column from each offset), where that
    block is contiguous, and zero-padded so that every block lies inside (cells outside
    the window read 0, as unknown). The scores are a sum of :math:`B` slices instead of
    :math:`(2m+1)^2 B` gathers: 63,000 candidates of 90 (180) beams took 8.9 (18.0) ms
    as gathers and 1.3 (2.3) ms so on one core of the 2-core machine
    (``python benchmarks/closure_search_cost.py``, which keeps the gathers). Under the
    defaults (weights 0 or 1 within :data:`SEARCH_REACH`, the coarse values multiples of
    ``1 / occ_saturation`` = 1/8) every partial sum is exact, so the order of the sum
    does not change a score; and an end point moved by whole cells lies where the
    gathers, which added the shift to it in floating point, found it, except within
    rounding of a cell edge, so whole runs are the same bit for bit as with the
    gathers.
    """
    dtype = start.dtype
    n = coarse.shape[0]
    h = SHIFT_CELLS
    side = 2 * m + 1
    margin = h * side  # a block that starts in the margin lies wholly in it or in the window
    padded_side = n + 2 * margin
    padded_side += (-padded_side) % h
    padded = jnp.zeros((padded_side, padded_side), coarse.dtype).at[margin:margin + n, margin:margin + n].set(coarse)
    q = padded_side // h
    phases = padded.reshape(q, h, q, h).transpose(1, 3, 0, 2).reshape(h * h, q, q)
    inv = jnp.asarray(1.0 / cell, dtype)
    w = jnp.where(weights > 0, weights, 0.0).astype(dtype)

    def per_turn(turn):
        sensor = se2.compose(start.at[2].add(turn), laser_offset.astype(dtype))
        world = se2.transform_points(sensor, local_points.astype(dtype))
        col = jnp.floor((world[:, 0] - corner[0]) * inv).astype(jnp.int32) - h * m
        row = jnp.floor((world[:, 1] - corner[1]) * inv).astype(jnp.int32) - h * m
        # a block that starts farther out than the margin lies wholly outside the window
        col = jnp.clip(col, -margin, n) + margin
        row = jnp.clip(row, -margin, n) + margin
        phase = h * (row % h) + col % h

        def add(b, total):
            block = jax.lax.dynamic_slice(phases[phase[b]], (row[b] // h, col[b] // h), (side, side))
            return total + w[b] * block

        # six beams per iteration of the loop: 2.2 -> 1.3 ms for 90 beams (one core)
        return jax.lax.fori_loop(0, w.shape[0], add, jnp.zeros((side, side), dtype), unroll=6)

    return jax.lax.map(per_turn, turns)


def coarse_candidates(read: CellReader, frame, local_points: Array, weights: Array, laser_offset: Array,
                      start: Array, params, config, radius: float | None = None,
                      reach: Array | None = None) -> Array:
    """The coarse stage: the best candidate of each of the :data:`REFINE` best headings
    around ``start``, ``(REFINE, 3)`` poses (see the module docstring).

    ``radius`` (static, m; default ``config.closure_radius``) sizes the candidate grid
    and the window; ``reach`` (traced, m), where given, keeps the candidates of the near
    search's square (``config.closure_radius`` on each axis) and those whose shift lies
    within ``reach`` (the far search, :func:`closure_phases`)."""
    dtype = start.dtype
    radius = float(config.closure_radius) if radius is None else float(radius)
    cell = frame.resolution * POOL
    step = cell * SHIFT_CELLS
    m = max(int(round(radius / step)), 1)
    k = max(int(round(float(config.closure_turn) / TURN_STEP)), 0)
    shifts = jnp.asarray(np.arange(-m, m + 1) * step, dtype)
    turns = jnp.asarray(np.arange(-k, k + 1) * TURN_STEP, dtype)

    coarse, corner = coarse_window(read, frame, start[:2], window_half(frame, radius), params.map.occ_saturation)
    idx = np.arange(0, local_points.shape[0], BEAM_STRIDE)
    points = local_points[idx]
    ranges = jnp.sqrt(jnp.sum(points * points, -1))
    w = jnp.where(ranges <= SEARCH_REACH, jnp.asarray(weights, dtype)[idx], 0.0)
    scores = candidate_scores(coarse, corner, cell, start, points, w, laser_offset, turns, m)
    if reach is not None:  # the near search's square, and the disc of the reach around it
        near = jnp.abs(shifts) <= float(config.closure_radius)
        within = (near[:, None] & near[None, :]) | (jnp.hypot(shifts[:, None], shifts[None, :]) <= reach)
        scores = jnp.where(within[None], scores, -jnp.inf)

    per_heading = scores.reshape(turns.shape[0], -1)
    flat_best = jnp.argmax(per_heading, -1)  # best translation of each heading
    heading_best = jnp.take_along_axis(per_heading, flat_best[:, None], -1)[:, 0]
    chosen = jnp.argsort(-heading_best)[: min(REFINE, turns.shape[0])]
    yi, xi = jnp.unravel_index(flat_best[chosen], (shifts.shape[0], shifts.shape[0]))
    return jnp.stack([start[0] + shifts[xi], start[1] + shifts[yi], se2.wrap_angle(start[2] + turns[chosen])], -1)


def refine_count(config) -> int:
    """How many candidates :func:`coarse_candidates` returns (and the hill climb refines)."""
    k = max(int(round(float(config.closure_turn) / TURN_STEP)), 0)
    return min(REFINE, 2 * k + 1)


def conflict_fraction(read: CellReader, frame, pose: Array, local_points: Array, weights: Array,
                      laser_offset: Array, count: Array) -> Array:
    """The fraction of the matched beams whose end point at ``pose`` lies in known free
    space: its cell and the 8 around it all have negative log-odds (the map has seen
    through them). A scan of new ground ends in unknown cells and scores 0 here."""
    dtype = pose.dtype
    sensor = se2.compose(pose, laser_offset.astype(dtype))
    world = se2.transform_points(sensor, local_points.astype(dtype))
    cell = jnp.floor(cell_coords(world, frame)).astype(jnp.int32)
    highest = read(cell[:, 0] - 1, cell[:, 1] - 1)
    for dc, dr in ((i, j) for i in (-1, 0, 1) for j in (-1, 0, 1) if (i, j) != (-1, -1)):
        highest = jnp.maximum(highest, read(cell[:, 0] + dc, cell[:, 1] + dr))
    return jnp.sum(jnp.where((jnp.asarray(weights) > 0) & (highest < 0), 1.0, 0.0).astype(dtype)) / count


class Watch(NamedTuple):
    """The closure state read for one scan, before its climbs (:func:`watch_closure`)."""

    conflict: Array  # () conflict_fraction at the local match
    held: Array  # (3,) the held candidate's correction C
    held_scans: Array  # () the scans it won
    travelled: Array  # () odometry since the last closure
    applied: Array  # (3,) the last closure's correction A
    watching: Array  # () bool, still watched after this scan
    conflict_sum: Array  # ()
    conflict_count: Array  # ()
    before: Array  # () the distance before the last closure
    refused: Array  # () bool, its correction refused (undone)
    undo: Array  # () bool, undo it on this scan
    holding: Array  # () bool, a candidate is held

    @staticmethod
    def empty(dtype) -> "Watch":
        zero, no = jnp.zeros((), dtype), jnp.asarray(False)
        pose = jnp.zeros((3,), dtype)
        return Watch(zero, pose, zero, zero, pose, no, zero, zero, zero, no, no, no)


def watch_closure(read: CellReader, frame, matched: Array, local_points: Array, weights: Array,
                  laser_offset: Array, count: Array, memory: ClosureState, params) -> Watch:
    """The watch of the last closure and the held candidate, read from ``memory`` with
    the local match's conflict (see :func:`closure_phases`)."""
    dtype = matched.dtype
    conflict = conflict_fraction(read, frame, matched, local_points, weights, laser_offset, count)
    travelled = memory.travelled
    applied = memory.applied
    watching = memory.watch > 0
    conflict_sum = memory.conflict_sum + jnp.where(watching, conflict, 0.0)
    conflict_count = memory.conflict_count + jnp.where(watching, 1.0, 0.0)
    before = memory.before
    refused = memory.watch < 0
    undo = watching & (
        ((travelled >= jnp.asarray(params.closure.watch, dtype))
         & (conflict_sum > jnp.asarray(params.closure.undo, dtype) * conflict_count))
        | ((conflict_count >= 2) & (travelled >= FAST_SHARE * jnp.asarray(params.closure.watch, dtype))
           & (conflict_sum > jnp.asarray(params.closure.undo_fast, dtype) * conflict_count)))
    watching = watching & ~undo & (travelled < jnp.asarray(params.closure.watch, dtype))
    return Watch(conflict, memory.held, memory.held_scans, travelled, applied.astype(dtype), watching, conflict_sum,
                 conflict_count, before, refused, undo, memory.held_scans > 0)


def closure_carry(dtype) -> dict:
    """The keys :func:`closure_phases` adds to the tracking's carry, empty."""
    return {"watch": Watch.empty(dtype), "followed": jnp.zeros((3,), dtype), "followed_score": jnp.zeros((), dtype),
            "travelled": jnp.zeros((), dtype)}


def closure_phases(read: CellReader, frame, local_points: Array, weights: Array, laser_offset: Array,
                   count: Array, memory: ClosureState, params, config) -> list[Phase]:
    r"""The climbs of the loop-closure search for the local match in ``carry``
    (``matched``, ``score``: raw score over ``count`` beams), as phases of the
    tracking's one climb (:mod:`jaxslam.grid.climbs`); :func:`closure_outcome` then
    gives the local match or the closure that replaces it, ``(pose, score, closed,
    undo, conflict, memory)``
    (``undo (4,)``: zeros, or where the pose is the last closure taken back, which the
    tracking applies whatever its score, the number of scans since that closure was
    taken and its correction :math:`A`, for :func:`jaxslam.grid.undone_closures.take_back`).

    ``memory`` (the state's :class:`~jaxslam.grid.types.ClosureState`, this scan's
    odometry included) holds the candidate held from the scans before, the world correction
    :math:`C` (pose ``(x, y, θ)``, the candidate :math:`C \oplus x_0`), the number of
    scans it won (0: none), the odometry distance :math:`d` since the last closure, the
    correction :math:`A` of the last closure taken (as the tracking applied it; set by
    :func:`jaxslam.grid.tracking.track`), whether it is still watched, the sum and
    count of its scans' conflicts, the distance before it, and the correction the
    search found for it (:func:`record_applied`). ``conflict`` is
    :func:`conflict_fraction` at the local match. The phases: the undo's climb, the
    held candidate's, and one climb from each of the coarse stage's candidates. Without a held
    candidate, a match under the trigger starts the search; with one, the hill climb
    refines :math:`C \oplus x_0` instead. The candidate :math:`x` wins a scan when

    .. math:: s(x) \ge s_{min}\, n, \qquad s(x) \ge g\, s_0, \qquad
        |x_{xy} - x_{0,xy}| \le \max(j, \beta d), \qquad |C_{xy} - A_{xy}| > j \text{ after an undo}

    (``closure.min_score``, ``closure.gain``, ``closure.jump``, ``closure.drift``), and
    replaces the match once it has won ``closure.confirm`` scans in a row; the held
    candidate returned is then empty again, as it is after a loss, and :math:`d`
    restarts from 0.

    Watch and undo: over the ``closure.watch`` m of odometry after a closure, the
    conflicts of the local matches (in the closed frame) are averaged; where the mean
    exceeds ``closure.undo`` the beams keep ending in space the old map has seen
    through, the closure was an alias, and it is undone: the match climbs again from
    :math:`A^{-1} \oplus x_0`, :math:`d` is restored, and candidates whose correction
    lies within ``closure.jump`` of the one the search found for it are refused from
    then on (the same alias would win again).
    """
    dtype = memory.travelled.dtype
    lanes = refine_count(config)

    def undo_prepare(lane, carry):
        watch = watch_closure(read, frame, carry["matched"], local_points, weights, laser_offset, count, memory, params)
        return {**carry, "watch": watch}, watch.undo, se2.compose(se2.inverse(watch.applied), carry["matched"])

    def undo_take(lane, carry, active, pose, score):
        return {**carry, "matched": jnp.where(active, pose, carry["matched"]),
                "score": jnp.where(active, score, carry["score"])}

    def follow_prepare(lane, carry):
        watch = carry["watch"]
        return carry, watch.holding, se2.compose(watch.held.astype(dtype), carry["matched"])

    def follow_take(lane, carry, active, pose, score):
        return {**carry, "followed": jnp.where(active, pose, carry["matched"]),
                "followed_score": jnp.where(active, score, carry["score"])}

    def search_prepare(lane, carry):
        watch, matched, score = carry["watch"], carry["matched"], carry["score"]
        travelled = jnp.where(watch.undo, watch.travelled + watch.before, watch.travelled)
        # No search while the last closure is watched (unless ``closure.nest``): a closure
        # taken inside another's watch would restart it, and the first would never be judged.
        nest_ok = ~watch.watching | (jnp.asarray(params.closure.nest, dtype) > 0)
        trigger = jnp.maximum(jnp.asarray(params.closure.trigger, dtype),
                              jnp.asarray(params.closure.trigger_ratio, dtype) * memory.level)
        triggered = ~watch.undo & ~watch.holding & nest_ok & (score / count < trigger) & (
            watch.conflict >= jnp.asarray(params.closure.conflict, dtype))

        def coarse(radius=None, reach=None):
            return coarse_candidates(read, frame, local_points, weights, laser_offset, matched, params, config,
                                     radius=radius, reach=reach)

        def wide():  # the near coarse stage, or the far one where the drift bound reaches past it
            far_radius = float(config.closure_radius_far)
            if far_radius <= float(config.closure_radius):
                return coarse()
            reach = jnp.minimum(jnp.asarray(params.closure.reach_rate, dtype) * travelled, far_radius)
            return jax.lax.cond(reach > float(config.closure_radius), lambda: coarse(far_radius, reach), coarse)

        candidates = jax.lax.cond(triggered, wide, lambda: jnp.zeros((lanes, 3), dtype))
        carry = {**carry, "travelled": travelled, "searching": triggered, "candidates": candidates,
                 "found": jnp.full((), -jnp.inf, dtype), "found_pose": candidates[0]}
        return carry, triggered, candidates[0]

    def next_prepare(lane, carry):
        return carry, carry["searching"], carry["candidates"][lane + 1]

    def search_take(lane, carry, active, pose, score):
        return best_of(carry, active, pose, score)

    return [Phase(1, False, undo_prepare, undo_take), Phase(1, False, follow_prepare, follow_take),
            Phase(1, False, search_prepare, search_take), Phase(lanes - 1, False, next_prepare, search_take)]


def closure_outcome(carry: dict, count: Array, memory: ClosureState,
                    params) -> tuple[Array, Array, Array, Array, Array, ClosureState, Array]:
    r"""The local match after :func:`closure_phases` (``carry``), or the closure that
    replaces it: ``(pose, score, closed, undo, conflict, memory, search)`` (see
    :func:`closure_phases`; ``search (4,)``: the candidate this scan judged, recorded
    for every scan as ``Info.track_search``: 1 where the search ran, 2 where a held
    candidate climbed, 0 neither (and the rest 0); its score as a fraction of the
    matched beams; its distance from the local match (m); and the tests that refused
    it, a sum of :data:`REFUSED_SCORE`, :data:`REFUSED_GAIN`, :data:`REFUSED_JUMP` and
    :data:`REFUSED_ALIAS`, 0 where it won the scan).

    With ``config.closure_map_bound``, ``memory.kept`` holds :math:`\Sigma`, the sum of the position
    corrections :math:`|A_{xy}|` of the closures taken and not undone, and bounds the
    jump by the map's own offset as well:

    .. math:: |x^*_{xy} - x_{0,xy}| \le \max\big(j,\ \min(\beta d,\ \gamma d + \Sigma)\big)

    (:math:`\gamma` = ``closure.reach_rate``). The tracking drifts by at most about
    :math:`\gamma d` between closures; the place matched may have been drawn before
    earlier closures moved the path, which can put it off by at most their sum. Before
    the first closure the map is one drawing and the bound is the tracking's drift
    alone, where an alias metres away (a corridor's doors) would pass the loose
    :math:`\beta d`; right after a closure :math:`\beta d` stays the tighter bound.

    ``closure.first_drift`` :math:`\gamma_1` (0.02 by default; 0: off) bounds the first closure alone,
    without the static option: until a closure is taken (:math:`A` = 0) the jump is
    at most :math:`\max(j, \min(\beta d, \gamma_1 d))`, :math:`d` the odometry since the
    start; on or off is the same compiled program."""
    watch, matched, score, travelled = carry["watch"], carry["matched"], carry["score"], carry["travelled"]
    dtype = matched.dtype
    holding, triggered, undo = watch.holding, carry["searching"], watch.undo
    pose = jnp.where(holding, carry["followed"], jnp.where(triggered, carry["found_pose"], matched))
    found = jnp.where(holding, carry["followed_score"], jnp.where(triggered, carry["found"], score))
    applied, watching = watch.applied, watch.watching
    conflict_sum, conflict_count, before, refused = watch.conflict_sum, watch.conflict_count, watch.before, watch.refused
    correction = se2.compose(pose, se2.inverse(matched))
    jump = jnp.asarray(params.closure.jump, dtype)
    candidate = memory.found
    alias = (refused | undo) & (jnp.hypot(correction[0] - candidate[0], correction[1] - candidate[1]) <= jump)
    bound = jnp.asarray(params.closure.drift, dtype) * travelled
    offset = None
    if memory.kept is not None:  # the sum of the kept corrections, less the one this scan undoes
        offset = memory.kept - jnp.where(undo, jnp.hypot(applied[0], applied[1]), 0.0)
        bound = jnp.minimum(bound, jnp.asarray(params.closure.reach_rate, dtype) * travelled + offset)
    first_drift = jnp.asarray(params.closure.first_drift, dtype)
    first = jnp.all(applied == 0) & (first_drift > 0)  # no closure taken yet
    bound = jnp.where(first, jnp.minimum(bound, first_drift * travelled), bound)
    distance = jnp.hypot(pose[0] - matched[0], pose[1] - matched[1])
    limit = jnp.maximum(jump, bound)
    low = found / count < jnp.asarray(params.closure.min_score, dtype)
    gain = jnp.asarray(params.closure.gain, dtype)
    confirm_gain = jnp.asarray(params.closure.confirm_gain, dtype)
    gain = jnp.where(holding & (confirm_gain > 0), confirm_gain, gain)
    flat = found < gain * score
    far = distance > limit
    ran = holding | triggered
    wins = ran & ~alias & ~low & ~flat & ~far
    scans = jnp.where(wins, watch.held_scans + 1, 0.0)
    closed = wins & (scans >= jnp.asarray(params.closure.confirm, dtype))
    keep = wins & ~closed
    # watch state: 1 watching the last closure, -1 its correction refused (undone), 0 neither
    state = jnp.where(closed, 1.0, jnp.where(undo | refused, -1.0, jnp.where(watching, 1.0, 0.0)))
    memory = ClosureState(
        held=jnp.where(keep, correction, jnp.zeros((3,), dtype)),
        held_scans=jnp.where(keep, scans, jnp.zeros((), dtype)),
        travelled=jnp.where(closed, 0.0, travelled).astype(dtype),
        applied=jnp.where(closed, correction, applied),
        watch=state.astype(dtype),
        conflict_sum=jnp.where(closed | ~watching, 0.0, conflict_sum),
        conflict_count=jnp.where(closed | ~watching, 0.0, conflict_count),
        before=jnp.where(closed, travelled, jnp.where(undo, 0.0, before)),
        found=jnp.where(closed, correction, candidate),
        kept=offset,  # record_applied adds a closure's correction
        level=memory.level,
    )
    # what an undo takes back, for the path reported
    # (:func:`jaxslam.grid.undone_closures.take_back`): the scans since the closure, A
    taken_back = jnp.where(undo, jnp.concatenate([conflict_count[None], applied.astype(dtype)]), jnp.zeros((4,), dtype))
    refused = sum(jnp.where(test, float(bit), 0.0) for test, bit in
                  ((low, REFUSED_SCORE), (flat, REFUSED_GAIN), (far, REFUSED_JUMP), (alias, REFUSED_ALIAS)))
    search = jnp.where(ran, jnp.stack([jnp.where(holding, 2.0, 1.0), found / count, distance, refused]).astype(dtype),
                       jnp.zeros((4,), dtype))
    return (jnp.where(closed, pose, matched), jnp.where(closed, found, score), closed, taken_back, watch.conflict,
            memory, search)


def record_applied(memory: ClosureState, taken: Array, correction: Array) -> ClosureState:
    """``memory`` with :math:`A`, the correction the tracking applied for a closure
    just ``taken`` (its pose over the local match, after the tracking's constraint),
    which an undo takes back."""
    memory = memory._replace(applied=jnp.where(taken, correction, memory.applied))
    if memory.kept is not None:  # the sum of the kept corrections (closure_outcome)
        memory = memory._replace(kept=memory.kept + jnp.where(taken, jnp.hypot(correction[0], correction[1]), 0.0))
    return memory


__all__ = [
    "BEAM_STRIDE", "FAST_SHARE", "POOL", "REFINE", "REFUSED_ALIAS", "REFUSED_GAIN", "REFUSED_JUMP", "REFUSED_SCORE",
    "SEARCH_REACH", "SHIFT_CELLS", "TURN_STEP",
    "Watch", "candidate_scores", "closure_carry", "closure_outcome", "closure_phases", "coarse_candidates",
    "coarse_window", "conflict_fraction", "record_applied", "refine_count", "watch_closure",
    "window_half",
]
