"""Speed of the landmark filter, this tree against an older revision, in one run.

Each case runs in a fresh subprocess (``run_landmark_slam`` on Victoria Park, one
seed), alternating between the revisions so that both see the same machine load:
filter wall time after compilation, compilation time, microseconds per particle and
scan, and the GPS error (float32 results of two revisions differ by rounding, which
resampling amplifies: compare the GPS error with the seed spread of
``erb_particles.py``, not bit for bit). The old revision is exported with
``git archive`` into a temporary folder.

    python benchmarks/erb_speed.py [--baseline 57eaeea] [--particles 100] [--repeats 2] [--steps N]

``--baseline ''`` times this tree alone (the cost against the particle count). Each
child sizes XLA's thread pool as ``jaxslam run`` does
(:func:`jaxslam.runtime.compiler.set_threads`; ``xla_threads`` in the rows).

Writes ``benchmarks/results/erb_speed.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import print_table, write_json  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]

CHILD = """
import json, sys
import jaxslam
assert jaxslam.__file__.startswith(sys.argv[4]), (jaxslam.__file__, sys.argv[4])
algorithm, particles, steps = sys.argv[1], int(sys.argv[2]), (None if sys.argv[3] == "all" else int(sys.argv[3]))
try:  # XLA's thread pool as `jaxslam run` sizes it (revisions before jaxslam.runtime.compiler.set_threads: XLA's default)
    from jaxslam.runtime.compiler import set_threads
    threads = set_threads(None, algorithm, particles)["threads"]
except ImportError:
    threads = "default"
from jaxslam.datasets import victoria_park
from jaxslam.feature.experiment import run_landmark_slam
from jaxslam.metrics.gps import gps_error
seq = victoria_park.load_sequence("detections", max_range=30.0, max_steps=steps)
res = run_landmark_slam(seq, algorithm, particles=particles, seed=0, progress=False)
err = gps_error(res.times, res.trajectory, seq.gps_times, seq.gps_xy)
print(json.dumps(dict(wall_s=res.wall_s, compile_s=res.compile_s, steps=res.steps, gps_mean_m=err["gps_mean_m"], xla_threads=threads)))
"""


def export(revision: str, into: Path) -> Path:
    archive = into / "src.tar"
    subprocess.run(["git", "-C", str(ROOT), "archive", "-o", str(archive), revision, "jaxslam"], check=True)
    with tarfile.open(archive) as tar:
        tar.extractall(into, filter="data")
    return into


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", default="57eaeea")
    parser.add_argument("--particles", type=int, nargs="+", default=[100])
    parser.add_argument("--algorithm", default="erb-upf")
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--steps", type=int, default=None)
    parser.add_argument("--name", default="erb_speed")
    args = parser.parse_args()

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        trees = {"this tree": ROOT}
        if args.baseline:
            trees = {"baseline " + args.baseline: export(args.baseline, Path(tmp)), **trees}
        for n in args.particles:
            for repeat in range(args.repeats):
                for label, tree in trees.items():
                    env = dict(os.environ, PYTHONPATH=str(tree))
                    # cwd: no jaxslam package of its own (sys.path[0]), datasets found from there
                    out = subprocess.run(
                        [sys.executable, "-c", CHILD, args.algorithm, str(n), str(args.steps or "all"), str(tree)],
                        env=env, capture_output=True, text=True, cwd=ROOT / "benchmarks",
                    )
                    if out.returncode:
                        raise RuntimeError(f"{label} N={n} failed:\n{out.stderr[-3000:]}")
                    r = json.loads(out.stdout.strip().splitlines()[-1])
                    r.update(revision=label, particles=n, repeat=repeat,
                             us_per_particle_scan=1e6 * r["wall_s"] / (r["steps"] * n))
                    rows.append(r)
                    print(f"{label} N={n}: wall {r['wall_s']:.1f} s, compile {r['compile_s']:.1f} s, "
                          f"GPS {r['gps_mean_m']:.2f} m", flush=True)
                    write_json(args.name, dict(dataset="victoria-park", algorithm=args.algorithm,
                                               baseline=args.baseline, steps=args.steps, runs=rows, complete=False))
    ratios = {}
    for n in args.particles if args.baseline else []:
        base = min(r["wall_s"] for r in rows if r["particles"] == n and r["revision"] != "this tree")
        new = min(r["wall_s"] for r in rows if r["particles"] == n and r["revision"] == "this tree")
        base_c = min(r["compile_s"] for r in rows if r["particles"] == n and r["revision"] != "this tree")
        new_c = min(r["compile_s"] for r in rows if r["particles"] == n and r["revision"] == "this tree")
        ratios[n] = dict(filter_speedup=base / new, compile_ratio=new_c / base_c, best_wall_s=new, baseline_best_wall_s=base)
    path = write_json(args.name, dict(dataset="victoria-park", algorithm=args.algorithm, baseline=args.baseline,
                                      steps=args.steps, runs=rows, ratios=ratios, complete=True))
    print_table(rows, ["revision", "particles", "repeat", "xla_threads", "wall_s", "compile_s", "us_per_particle_scan",
                       "gps_mean_m"])
    print("ratios (best of repeats):", ratios)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
