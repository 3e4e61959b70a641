"""Map consistency on MIT CSAIL, FR079 and Intel (the paper's Experiment 3 and more):
one run per dataset and filter, the best particle's map written as PNG (with the
path drawn) into ``benchmarks/results/grid_maps/``, plus the relations error where
the benchmark has relations (Intel, FR079), in ``grid_maps.json``.

    python benchmarks/grid_maps.py [--datasets intel fr079 mit-csail] [--particles 30]
        [--algorithms srupf-gm gmapping srupf-gm-npc] [--pgm DIR]

``--pgm DIR`` also keeps the ROS map_server PGM + YAML (large) under ``DIR``. Runs
of other datasets or filters already in ``grid_maps.json`` (same particle count) are
kept, so ``--datasets fr079`` refreshes only FR079's entries.
"""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path

from grid_common import RESULTS, machine_info, run_in_subprocess, save_json


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--datasets", nargs="+", default=["intel", "fr079", "mit-csail"])
    ap.add_argument("--algorithms", nargs="+", default=["srupf-gm", "gmapping", "srupf-gm-npc"])
    ap.add_argument("--particles", type=int, default=30)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--pgm", default=None)
    args = ap.parse_args()

    out_dir = RESULTS / "grid_maps"
    out_dir.mkdir(parents=True, exist_ok=True)
    records = []
    for dataset in args.datasets:
        for algorithm in args.algorithms:
            tmp = Path(args.pgm or "/tmp/jaxslam_grid_maps") / f"{dataset}_{algorithm}_{args.particles}"
            rec = run_in_subprocess({"dataset": dataset, "algorithm": algorithm, "particles": args.particles,
                                     "seed": args.seed, "map_dir": str(tmp), "draw_path": True})
            if "map_files" in rec:
                png = out_dir / f"{dataset}_{algorithm}_{args.particles}.png"
                shutil.copy(rec["map_files"]["png"], png)
                rec["png"] = str(png.relative_to(RESULTS))
                if not args.pgm:
                    shutil.rmtree(tmp, ignore_errors=True)
                    rec.pop("map_files")
            print(dataset, algorithm, {k: rec.get(k) for k in ("wall_s", "trans_err_mean_m", "rot_err_mean_deg",
                                                                "png", "error")}, flush=True)
            records.append(rec)
    path = RESULTS / "grid_maps.json"
    done = {(r["dataset"], r["algorithm"]) for r in records}
    machines = {"machine": machine_info()}
    if path.exists():
        old = json.loads(path.read_text())
        if old.get("particles") == args.particles:
            kept = [r for r in old["runs"] if (r["dataset"], r["algorithm"]) not in done]
            if kept:
                machines["machine_of_kept_runs"] = old.get("machine_of_kept_runs", old.get("machine"))
            records = kept + records
    save_json(path, {"runs": records, "particles": args.particles, **machines})


if __name__ == "__main__":
    main()
