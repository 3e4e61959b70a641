"""Per-scan tracking variants on whole logs: relations error per log, seed and variant.

Each row is one ``run_grid_slam`` (defaults except the variant's settings) scored by
the Kümmerle et al. relations metric: mean, median, max translational error, count
over 0.5 m, keyframes, filter wall time. Variants:

* ``default`` — per-scan tracking as shipped (:mod:`jaxslam.grid.tracking`);
* ``no-tracking`` — ``config.tracking=False`` (GMapping's keyframe rule on odometry);
* ``unconstrained`` — tracking with ``track_min_curvature=0`` (the whole position
  correction of the match is taken);
* ``NAME=VALUE`` — the default with one ``Params`` override.

    python benchmarks/grid_tracking.py --logs intel fr079 --seeds 0 1 \
        --variants default no-tracking unconstrained [--particles 30] [--tag NAME]

Writes ``benchmarks/results/grid_tracking[_TAG].json``; prints the table as it goes.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _common import print_table, write_json  # noqa: E402

from jaxslam.datasets.registry import load_dataset_log  # noqa: E402
from jaxslam.grid.experiment import run_grid_slam  # noqa: E402
from jaxslam.metrics.relations import load_dataset_relations, relations_metric  # noqa: E402

COLUMNS = ["log", "seed", "variant", "mean_m", "median_m", "max_m", "over_0_5m", "keyframes", "wall_s"]


def variant_options(variant: str) -> tuple[dict, dict]:
    """``(params, config)`` overrides of a variant name."""
    if variant == "default":
        return {}, {}
    if variant == "no-tracking":
        return {}, {"tracking": False}
    if variant == "unconstrained":
        return {"track_min_curvature": 0.0}, {}
    if "=" in variant:
        name, value = variant.split("=", 1)
        return {name: float(value)}, {}
    raise SystemExit(f"unknown variant {variant!r}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--logs", nargs="+", default=["intel", "fr079"])
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1])
    parser.add_argument("--variants", nargs="+", default=["default", "no-tracking"])
    parser.add_argument("--algorithm", default="srupf-gm")
    parser.add_argument("--particles", type=int, default=30)
    parser.add_argument("--tag", default="")
    args = parser.parse_args()
    rows = []
    for name in args.logs:
        log = load_dataset_log(name)
        relations = load_dataset_relations(name)
        for variant in args.variants:
            params, config = variant_options(variant)
            for seed in args.seeds:
                started = time.perf_counter()
                result = run_grid_slam(log, args.algorithm, args.particles, seed, params=params, config=config,
                                       progress=False)
                metric = relations_metric(relations, result.scan_times, result.trajectory)
                rows.append({
                    "log": name, "seed": seed, "variant": variant, "mean_m": metric["trans_err_mean_m"],
                    "median_m": metric["trans_err_median_m"], "max_m": metric["trans_err_max_m"],
                    "over_0_5m": int(metric["n_trans_err_over_0_5m"]), "rot_mean_deg": metric["rot_err_mean_deg"],
                    "keyframes": int(result.keyframes.shape[0]), "wall_s": result.wall_s,
                    "compile_s": result.compile_s, "process_s": time.perf_counter() - started,
                    "track_accepted": float(result.info["track_accepted"].mean()),
                })
                print_table(rows[-1:], COLUMNS)
    print_table(rows, COLUMNS)
    name = "grid_tracking" + (f"_{args.tag}" if args.tag else "")
    path = write_json(name, {"command": " ".join(sys.argv), "algorithm": args.algorithm,
                             "particles": args.particles, "rows": rows})
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
