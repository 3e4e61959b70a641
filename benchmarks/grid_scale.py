"""Grid SLAM at scale: paged maps on Intel, FR079 and MIT Killian.

For each dataset (full log, defaults, one fresh process per run) it reports the time
per keyframe, peak memory, the final pool size, tiles per particle, tiles shared,
how often the maps grew, and the relations error. With ``--baseline-tree DIR`` the
same runs are repeated with the jaxslam of another source tree (a checkout of the
dense-grid commit) in the same invocation, so that old and new are timed on the same
machine under the same load. ``--resampling`` times :func:`resample_maps` alone
against the page-table size (the cost of a resampling step against map size).

    python benchmarks/grid_scale.py                       # intel fr079 mit-killian, 30 particles
    python benchmarks/grid_scale.py --datasets intel --baseline-tree /path/to/old/checkout
    python benchmarks/grid_scale.py --datasets mit-killian --particles 1000
    python benchmarks/grid_scale.py --datasets --resampling --out grid_scale_resampling

Writes ``benchmarks/results/grid_scale.json``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import machine_info, print_table, write_json  # noqa: E402
from grid_common import run_in_subprocess  # noqa: E402


def resampling_cost(particles: int, table_sides: list[int], repeats: int = 20) -> list[dict]:
    """Seconds per resampling of paged maps against the page-table size (no cells move)."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    from jaxslam.grid.paged import PagedLayout, init_maps, resample_maps

    rows = []
    rng = np.random.default_rng(0)
    for side in table_sides:
        layout = PagedLayout(0.05, 6, 0, 0, side, side, slots=2 * side * side + 1)
        maps = init_maps(particles, layout)
        tables = rng.integers(1, layout.slots, (particles, layout.table_size)).astype(np.int32)
        # The pool only passes through (in a run it is donated and stays in place); a
        # stand-in keeps the copy of an undonated pool out of the timing.
        maps = maps._replace(tables=jnp.asarray(tables), pool=jnp.zeros((2, layout.tile_cells), jnp.int8))
        fn = jax.jit(resample_maps)
        ancestors = jnp.asarray(np.sort(rng.integers(0, particles, particles)), jnp.int32)
        jax.block_until_ready(fn(maps, ancestors, jnp.asarray(True)))
        t0 = time.perf_counter()
        for _ in range(repeats):
            out = fn(maps, ancestors, jnp.asarray(True))
        jax.block_until_ready(out)
        per = (time.perf_counter() - t0) / repeats
        rows.append({"particles": particles, "table_tiles": side * side, "map_area_m2": (side * 3.2) ** 2,
                     "pool_mb": layout.pool_bytes() / 1e6, "resample_ms": 1e3 * per})
    return rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--datasets", nargs="*", default=["intel", "fr079", "mit-killian"])
    parser.add_argument("--algorithm", default="srupf-gm")
    parser.add_argument("--particles", type=int, nargs="+", default=[30])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--baseline-tree", help="source tree of the old (dense) jaxslam to time in the same run")
    parser.add_argument("--resampling", action="store_true", help="also time resampling against map size")
    parser.add_argument("--maps", help="folder for the map images")
    parser.add_argument("--out", default="grid_scale")
    args = parser.parse_args(argv)

    rows = []
    for dataset in args.datasets:
        for particles in args.particles:
            trees = [("paged", None)] + ([("dense (baseline)", args.baseline_tree)] if args.baseline_tree else [])
            for label, tree in trees:
                spec = {"dataset": dataset, "algorithm": args.algorithm, "particles": particles, "seed": args.seed}
                if args.maps and tree is None:
                    spec["map_dir"] = str(Path(args.maps) / f"{dataset}_{args.algorithm}_{particles}")
                    spec["draw_path"] = True
                print(f"{label}: {dataset} N={particles} ...", flush=True)
                rec = run_in_subprocess(spec, tree=tree)
                rec["code"] = label
                maps = rec.get("maps") or {}
                rec.update({f"map_{k}": v for k, v in maps.items()})
                rows.append(rec)
                if "error" in rec:
                    print(f"  failed: {rec['error'][-400:]}", flush=True)
    if rows:
        print_table(rows, ["code", "dataset", "particles", "keyframes", "s_per_keyframe", "wall_s", "compile_s",
                           "peak_rss_mb", "map_pool_slots", "map_tiles_used", "map_tiles_per_particle_mean",
                           "map_tiles_shared", "map_growths", "trans_err_mean_m", "trans_err_median_m"])
    payload = {"machine": machine_info(), "command": " ".join(["python", "benchmarks/grid_scale.py"] + sys.argv[1:]),
               "runs": rows}
    if args.resampling:
        res = resampling_cost(30, [8, 16, 32, 64, 128]) + resampling_cost(300, [8, 16, 32, 64])
        print_table(res, ["particles", "table_tiles", "map_area_m2", "pool_mb", "resample_ms"])
        payload["resampling"] = res
    print("wrote", write_json(args.out, payload))
    return 0


if __name__ == "__main__":
    sys.exit(main())
