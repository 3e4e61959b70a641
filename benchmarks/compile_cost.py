"""What each part of a grid filter's program costs to compile: XLA's compilation of the
chunk runner, one fresh process per variant, variants alternating.

Usage:
    python benchmarks/compile_cost.py [--variants default no_closure ...] [--rounds 3]
        [--algorithm srupf-gm] [--dataset intel] [--keyframes 20] [--cpu 1] [--json NAME]

Each run is ``run_grid_slam(dataset, algorithm, 30, 0, config=VARIANT,
max_keyframes=K)`` in a new Python process with the compilation cache off
(``JAXSLAM_CACHE_DIR=off``, ``jax_enable_compilation_cache`` False). JAX's
``jax_log_compiles`` messages give the seconds of "XLA compilation", "tracing" and
"jaxpr to MLIR module conversion" of the chunk runner (``run_chunk``). The first K
keyframes are enough: the chunk runner is the same program whatever the length of
the run. ``--cpu N`` pins each process to CPU N (``taskset``; XLA then compiles for
one thread), so that two series can run side by side, one per core.

A variant is a dict of :class:`jaxslam.grid.types.GridSlamConfig` overrides
(:data:`VARIANTS`, or ``NAME={"closure": false}`` on the command line). One process of
the same program varies by up to a quarter on a 2-core VM, so compare the medians of
alternating rounds, not single runs.

Writes benchmarks/results/<json>.json (default ``compile_cost``).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import statistics
import subprocess
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _common import print_table, write_json  # noqa: E402

VARIANTS: dict[str, dict] = {
    "default": {},
    "no_closure": {"closure": False},
    "no_recover": {"recover_radius": 0.0},
    "no_coarse": {"coarse_iterations": 0},
    "no_far": {"closure_radius_far": 6.0},
    "none": {"closure": False, "recover_radius": 0.0, "coarse_iterations": 0},
}
"""Named config overrides: SRUPF-GM's defaults, and each of its optional searches off
(the loop-closure search, the recovery from odometry jumps, the coarse stage of the
matches, the closure search's far stage)."""

STAGES = {"XLA compilation": "xla_s", "tracing": "trace_s", "jaxpr to MLIR module conversion": "lower_s"}
"""JAX's compile-log stages and the row keys they are summed into."""

RUNNER = "run_chunk"
"""The chunk runner's function name (`run_chunk` in :func:`jaxslam.runtime.progress.make_chunk_runner`)."""

_CHILD = r'''
import json, logging, sys, time
import jax
jax.config.update("jax_enable_compilation_cache", False)
messages = []

class Collect(logging.Handler):
    def emit(self, record):
        text = record.getMessage()
        if text.startswith("Finished"):
            messages.append(text)

for name in ("jax._src.dispatch", "jax._src.interpreters.pxla", "jax._src.compiler"):
    logging.getLogger(name).addHandler(Collect())
    logging.getLogger(name).setLevel(logging.DEBUG)
jax.config.update("jax_log_compiles", True)
from jaxslam.grid.experiment import run_grid_slam
dataset, algorithm, keyframes, config = sys.argv[1], sys.argv[2], int(sys.argv[3]), json.loads(sys.argv[4])
started = time.perf_counter()
run_grid_slam(dataset, algorithm, 30, 0, config=config, max_keyframes=keyframes, progress=False)
print("RESULT " + json.dumps({"messages": messages, "run_s": time.perf_counter() - started}))
'''


def stage_of(message: str) -> tuple[str, str, float] | None:
    """``(stage, function, seconds)`` of one of JAX's ``jax_log_compiles`` messages
    ("Finished tracing run_chunk for jit in 3.0 sec", "Finished jaxpr to MLIR module
    conversion jit(run_chunk) in 1.3 sec", "Finished XLA compilation of jit(run_chunk)
    in 14.2 sec"), or None for any other message."""
    m = re.search(r"Finished (tracing) (?:\+ transforming )?(\w+) for \w+ in ([0-9.]+) sec", message) or re.search(
        r"Finished (jaxpr to MLIR module conversion|XLA compilation)(?: of)? jit\((\w+)\) in ([0-9.]+) sec", message)
    return (m.group(1), m.group(2), float(m.group(3))) if m else None


def measure(name: str, config: dict, args) -> dict:
    """One fresh process of ``config``: the chunk runner's stage times and the run's."""
    command = [sys.executable, "-c", _CHILD, args.dataset, args.algorithm, str(args.keyframes), json.dumps(config)]
    if args.cpu is not None:
        command = ["taskset", "-c", str(args.cpu), *command]
    started = time.perf_counter()
    done = subprocess.run(command, capture_output=True, text=True, env={**os.environ, "JAXSLAM_CACHE_DIR": "off"})
    lines = [line for line in done.stdout.splitlines() if line.startswith("RESULT ")]
    if done.returncode != 0 or not lines:
        raise RuntimeError(f"variant {name}: the run failed (exit {done.returncode}):\n{done.stderr[-3000:]}")
    result = json.loads(lines[-1][len("RESULT "):])
    row = {"variant": name, "process_s": time.perf_counter() - started, "run_s": result["run_s"]}
    for parsed in filter(None, map(stage_of, result["messages"])):
        stage, function, seconds = parsed
        if function == RUNNER:
            row[STAGES[stage]] = row.get(STAGES[stage], 0.0) + seconds
    return row


def parse_variant(text: str) -> tuple[str, dict]:
    if "=" in text:
        name, _, body = text.partition("=")
        return name, json.loads(body)
    if text not in VARIANTS:
        raise SystemExit(f"unknown variant {text!r}: one of {', '.join(VARIANTS)}, or NAME=JSON")
    return text, VARIANTS[text]


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--variants", nargs="+", default=["default", "no_closure", "no_recover", "no_coarse", "none"])
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--algorithm", default="srupf-gm")
    parser.add_argument("--dataset", default="intel")
    parser.add_argument("--keyframes", type=int, default=20)
    parser.add_argument("--cpu", type=int, default=None, help="pin each process to this CPU (taskset)")
    parser.add_argument("--json", default="compile_cost")
    args = parser.parse_args(argv)
    variants = [parse_variant(v) for v in args.variants]

    runs = []
    for round_ in range(args.rounds):
        for name, config in variants:
            row = {"round": round_, **measure(name, config, args)}
            runs.append(row)
            print(f"round {round_} {name}: XLA {row.get('xla_s', 0):.2f} s, tracing {row.get('trace_s', 0):.2f} s, "
                  f"process {row['process_s']:.1f} s", flush=True)
    summary = []
    for name, config in variants:
        mine = [r for r in runs if r["variant"] == name]
        summary.append({
            "variant": name, "config": json.dumps(config), "rounds": len(mine),
            "xla_median_s": statistics.median(r.get("xla_s", 0.0) for r in mine),
            "xla_min_s": min(r.get("xla_s", 0.0) for r in mine), "xla_max_s": max(r.get("xla_s", 0.0) for r in mine),
            "trace_median_s": statistics.median(r.get("trace_s", 0.0) for r in mine),
            "process_median_s": statistics.median(r["process_s"] for r in mine),
        })
    print()
    print_table(summary, ["variant", "rounds", "xla_median_s", "xla_min_s", "xla_max_s", "trace_median_s",
                          "process_median_s", "config"])
    path = write_json(args.json, {
        "dataset": args.dataset, "algorithm": args.algorithm, "keyframes": args.keyframes, "cpu": args.cpu,
        "summary": summary, "runs": runs,
    })
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
