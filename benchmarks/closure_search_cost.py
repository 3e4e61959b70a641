"""What the loop-closure search's coarse stage costs: the candidate scores of one search
as the sum of shifted blocks (:func:`jaxslam.grid.closure.candidate_scores`) against
the gathers it replaced (one read of the coarse map per candidate and beam, kept here
as :func:`gathered_scores`), on the same inputs, with the scores compared.

Usage:
    python benchmarks/closure_search_cost.py [--beams 90 180] [--repeats 20] [--trials 50]
        [--json NAME]

The inputs have the size of a search with the defaults: a coarse window of 524 x 524
cells (``closure_radius`` 6 m, 10 cm coarse cells), 17 headings (``closure_turn``
0.14 rad, 1 deg steps), 61 x 61 shifts of 20 cm, and the matched beams of a 180- or
361-beam scan (every second one, :data:`jaxslam.grid.closure.BEAM_STRIDE`), with the
coarse values multiples of 1/8 and the weights 0 or 1, as the filters have them. For
each beam count, ``--trials`` random poses and scans are scored both ways and the
share of identical score arrays is reported: the block sum puts every end point in
the cell of the unshifted pose moved by whole steps, the gathers added the shift in
float32, and the two differ where an end point lies within rounding of a cell edge.
Times are the median of ``--repeats`` calls of each compiled program (pin the process
with ``taskset -c 0`` to compare one core). Prints the table and writes
``benchmarks/results/NAME.json`` (default ``closure_search_cost``).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import print_table, write_json  # noqa: E402

from jaxslam.runtime.compiler import options  # noqa: E402
from jaxslam.core import se2  # noqa: E402
from jaxslam.grid.closure import SHIFT_CELLS, TURN_STEP, candidate_scores  # noqa: E402

CELL = 0.1
WINDOW = 524
SHIFTS = 30
TURNS = 8


def gathered_scores(coarse, corner, cell, start, local_points, weights, laser_offset, turns, m):
    """The former candidate scores: every candidate's end points read one by one, the
    shift added to the end point in floating point (``shifts * inv``)."""
    dtype = start.dtype
    n = coarse.shape[0]
    inv = jnp.asarray(1.0 / cell, dtype)
    shifts = jnp.asarray(np.arange(-m, m + 1) * cell * SHIFT_CELLS, dtype)

    def per_turn(turn):
        sensor = se2.compose(start.at[2].add(turn), laser_offset.astype(dtype))
        world = se2.transform_points(sensor, local_points.astype(dtype))
        u = (world[:, 0] - corner[0]) * inv
        v = (world[:, 1] - corner[1]) * inv
        cols = jnp.floor(u[None, None, :] + shifts[None, :, None] * inv).astype(jnp.int32)
        rows = jnp.floor(v[None, None, :] + shifts[:, None, None] * inv).astype(jnp.int32)
        inside = (cols >= 0) & (cols < n) & (rows >= 0) & (rows < n)
        value = coarse[jnp.clip(rows, 0, n - 1), jnp.clip(cols, 0, n - 1)]
        return jnp.sum(jnp.where(inside & (weights > 0), weights * value, 0.0), -1)

    return jax.lax.map(per_turn, turns)


def inputs(rng, beams: int):
    counts = rng.integers(0, 9, (WINDOW, WINDOW)) * (rng.uniform(size=(WINDOW, WINDOW)) < 0.2)
    coarse = jnp.asarray((counts / 8.0).astype(np.float32))
    corner = rng.uniform(-40, 40, 2).astype(np.float32)
    half = WINDOW * CELL / 2
    start = np.r_[corner + half + rng.uniform(-1, 1, 2), rng.uniform(-3, 3)].astype(np.float32)
    angles = np.linspace(-np.pi / 2, np.pi / 2, beams)
    ranges = rng.uniform(0.5, 24.0, beams)
    points = np.stack([ranges * np.cos(angles), ranges * np.sin(angles)], -1).astype(np.float32)
    weights = ((rng.uniform(size=beams) < 0.9) & (ranges <= 20.0)).astype(np.float32)
    return (coarse, jnp.asarray(corner), jnp.asarray(start), jnp.asarray(points), jnp.asarray(weights),
            jnp.asarray([0.1, 0.0, 0.0], jnp.float32))


def timed(fn, args, repeats: int) -> float:
    jax.block_until_ready(fn(*args))
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn(*args))
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--beams", type=int, nargs="+", default=[90, 180])
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--trials", type=int, default=50)
    parser.add_argument("--json", default="closure_search_cost")
    args = parser.parse_args(argv)

    turns = jnp.asarray(np.arange(-TURNS, TURNS + 1) * TURN_STEP, jnp.float32)
    programs = {
        name: jax.jit(lambda c, co, s, p, w, o, f=f: f(c, co, CELL, s, p, w, o, turns, SHIFTS),
                      compiler_options=options())
        for name, f in (("gathers", gathered_scores), ("blocks", candidate_scores))
    }
    rng = np.random.default_rng(0)
    rows = []
    for beams in args.beams:
        same = 0
        for _ in range(args.trials):
            case = inputs(rng, beams)
            same += bool(np.array_equal(np.asarray(programs["gathers"](*case)), np.asarray(programs["blocks"](*case))))
        case = inputs(rng, beams)
        before, after = (timed(programs[name], case, args.repeats) for name in ("gathers", "blocks"))
        rows.append({"beams": beams, "candidates": (2 * TURNS + 1) * (2 * SHIFTS + 1) ** 2,
                     "gathers_ms": round(before * 1e3, 3), "blocks_ms": round(after * 1e3, 3),
                     "speed_up": round(before / after, 2), "identical": f"{same}/{args.trials}"})
    print_table(rows, ["beams", "candidates", "gathers_ms", "blocks_ms", "speed_up", "identical"])
    path = write_json(args.json, {"command": " ".join(["python", *sys.argv]), "rows": rows})
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
