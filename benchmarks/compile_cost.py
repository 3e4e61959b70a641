"""What each part of a grid filter's program costs to compile: XLA's compilation of the
chunk runner, one fresh process per variant, variants alternating.

Usage:
    python benchmarks/compile_cost.py [--variants default no_closure ...] [--rounds 3]
        [--algorithm srupf-gm] [--dataset intel] [--keyframes 20] [--cpu 1] [--json NAME]
        [--tree old=/path/to/checkout --tree new=.]

Each run is ``run_grid_slam(dataset, algorithm, 30, 0, config=VARIANT,
max_keyframes=K)`` in a new Python process with the compilation cache off
(``JAXSLAM_CACHE_DIR=off``, ``jax_enable_compilation_cache`` False). JAX's
``jax_log_compiles`` messages give the seconds of "XLA compilation", "tracing" and
"jaxpr to MLIR module conversion" of the chunk runner (``run_chunk``). The first K
keyframes are enough: the chunk runner is the same program whatever the length of
the run. ``--cpu N`` pins each process to CPU N (``taskset``; XLA then compiles for
one thread), so that two series can run side by side, one per core. Each row also has
the CPU seconds (user + system) of the runner's stages (``trace_cpu_s``,
``lower_cpu_s``, ``xla_cpu_s``: the process's CPU time between the compile call and
the stages' messages) and of the whole child process (``cpu_s``), which a loaded
machine inflates far less than wall time.

``--tree NAME=PATH`` (repeatable) runs every variant with each checkout in turn
(``PYTHONPATH=PATH``), alternating within each round: old and new code measured in
one run.

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
"""The chunk runner's function name (`run_chunk` in :func:`jaxslam.runtime.driver.chunk_runner`)."""

_CHILD = r'''
import json, logging, resource, sys, time
import jax
jax.config.update("jax_enable_compilation_cache", False)
messages = []

def cpu():
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime

class Collect(logging.Handler):
    def emit(self, record):
        text = record.getMessage()
        if text.startswith("Finished"):
            messages.append((text, cpu()))

for name in ("jax._src.dispatch", "jax._src.interpreters.pxla", "jax._src.compiler"):
    logging.getLogger(name).addHandler(Collect())
    logging.getLogger(name).setLevel(logging.DEBUG)
jax.config.update("jax_log_compiles", True)
import jaxslam.runtime.progress as progress
compile_runner = progress.compile_runner
starts = []

def timed_compile_runner(*args, **kwargs):
    starts.append(cpu())
    return compile_runner(*args, **kwargs)

progress.compile_runner = timed_compile_runner
from jaxslam.grid.experiment import run_grid_slam
dataset, algorithm, keyframes, config = sys.argv[1], sys.argv[2], int(sys.argv[3]), json.loads(sys.argv[4])
started = time.perf_counter()
run_grid_slam(dataset, algorithm, 30, 0, config=config, max_keyframes=keyframes, progress=False)
print("RESULT " + json.dumps({"messages": messages, "starts": starts, "run_s": time.perf_counter() - started}))
'''


def stage_of(message: str) -> tuple[str, str, float] | None:
    """``(stage, function, seconds)`` of one of JAX's ``jax_log_compiles`` messages
    ("Finished tracing run_chunk for jit in 3.0 sec", "Finished jaxpr to MLIR module
    conversion jit(run_chunk) in 1.3 sec", "Finished XLA compilation of jit(run_chunk)
    in 14.2 sec"), or None for any other message."""
    m = re.search(r"Finished (tracing) (?:\+ transforming )?(\w+) for \w+ in ([0-9.]+) sec", message) or re.search(
        r"Finished (jaxpr to MLIR module conversion|XLA compilation)(?: of)? jit\((\w+)\) in ([0-9.]+) sec", message)
    return (m.group(1), m.group(2), float(m.group(3))) if m else None


def measure(name: str, config: dict, args, tree: tuple[str, str] | None = None) -> dict:
    """One fresh process of ``config`` (with the checkout ``tree = (name, path)``, or
    this one): the chunk runner's stage times and the run's."""
    command = [sys.executable, "-c", _CHILD, args.dataset, args.algorithm, str(args.keyframes), json.dumps(config)]
    if args.cpu is not None:
        command = ["taskset", "-c", str(args.cpu), *command]
    env = {**os.environ, "JAXSLAM_CACHE_DIR": "off"}
    if tree is not None:
        env["PYTHONPATH"] = os.path.abspath(tree[1])
    started = time.perf_counter()
    before = os.times()
    done = subprocess.run(command, capture_output=True, text=True, env=env)
    after = os.times()
    lines = [line for line in done.stdout.splitlines() if line.startswith("RESULT ")]
    if done.returncode != 0 or not lines:
        raise RuntimeError(f"variant {name}: the run failed (exit {done.returncode}):\n{done.stderr[-3000:]}")
    result = json.loads(lines[-1][len("RESULT "):])
    row = {"variant": name, "tree": None if tree is None else tree[0], "process_s": time.perf_counter() - started,
           "cpu_s": (after.children_user - before.children_user) + (after.children_system - before.children_system),
           "run_s": result["run_s"]}
    # CPU seconds of the runner's stages: tracing from the compile call to its message,
    # each later stage from the message before it (the stages run one after another).
    last = result["starts"][0] if result["starts"] else None
    for text, cpu_at in result["messages"]:
        parsed = stage_of(text)
        if parsed is None or parsed[1] != RUNNER:
            continue
        stage, _, seconds = parsed
        row[STAGES[stage]] = row.get(STAGES[stage], 0.0) + seconds
        if last is not None:
            key = STAGES[stage].replace("_s", "_cpu_s")
            row[key] = row.get(key, 0.0) + cpu_at - last
        last = cpu_at
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
    parser.add_argument("--tree", action="append", default=[], metavar="NAME=PATH",
                        help="a checkout to measure (repeatable; alternating with the others)")
    args = parser.parse_args(argv)
    variants = [parse_variant(v) for v in args.variants]
    trees = [tuple(t.split("=", 1)) for t in args.tree] or [None]
    for tree in trees:
        if tree is not None and (len(tree) != 2 or not os.path.isdir(tree[1])):
            raise SystemExit(f"--tree {'='.join(tree)}: expected NAME=PATH of a checkout")

    runs = []
    for round_ in range(args.rounds):
        for name, config in variants:
            for tree in trees:
                row = {"round": round_, **measure(name, config, args, tree)}
                runs.append(row)
                print(f"round {round_} {name} {row['tree'] or ''}: CPU s: XLA {row.get('xla_cpu_s', 0):.2f}, "
                      f"tracing {row.get('trace_cpu_s', 0):.2f}, lowering {row.get('lower_cpu_s', 0):.2f}; wall: "
                      f"XLA {row.get('xla_s', 0):.2f} s, "
                      f"tracing {row.get('trace_s', 0):.2f} s, lowering {row.get('lower_s', 0):.2f} s, "
                      f"process {row['process_s']:.1f} s ({row['cpu_s']:.1f} s CPU)", flush=True)
    summary = []
    for name, config in variants:
        for tree in trees:
            mine = [r for r in runs if r["variant"] == name and r["tree"] == (None if tree is None else tree[0])]
            summary.append({
                "variant": name, "tree": None if tree is None else tree[0], "config": json.dumps(config),
                "rounds": len(mine),
                "xla_median_s": statistics.median(r.get("xla_s", 0.0) for r in mine),
                "xla_min_s": min(r.get("xla_s", 0.0) for r in mine), "xla_max_s": max(r.get("xla_s", 0.0) for r in mine),
                "trace_median_s": statistics.median(r.get("trace_s", 0.0) for r in mine),
                "xla_cpu_median_s": statistics.median(r.get("xla_cpu_s", 0.0) for r in mine),
                "trace_cpu_median_s": statistics.median(r.get("trace_cpu_s", 0.0) for r in mine),
                "lower_cpu_median_s": statistics.median(r.get("lower_cpu_s", 0.0) for r in mine),
                "lower_median_s": statistics.median(r.get("lower_s", 0.0) for r in mine),
                "process_median_s": statistics.median(r["process_s"] for r in mine),
                "cpu_median_s": statistics.median(r["cpu_s"] for r in mine),
            })
    print()
    print_table(summary, ["variant", "tree", "rounds", "xla_cpu_median_s", "trace_cpu_median_s", "lower_cpu_median_s",
                          "xla_median_s", "xla_min_s", "xla_max_s", "trace_median_s", "lower_median_s",
                          "process_median_s", "cpu_median_s", "config"])
    path = write_json(args.json, {
        "dataset": args.dataset, "algorithm": args.algorithm, "keyframes": args.keyframes, "cpu": args.cpu,
        "trees": [None if t is None else list(t) for t in trees],
        "summary": summary, "runs": runs,
    })
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
