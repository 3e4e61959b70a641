"""Where a filter run's time goes, by XLA operation.

Runs the case once to compile (and warm the caches), then again under
``jax.profiler`` with the Python tracer off, reads the trace back and sums each XLA
operation's *exclusive* time (its own duration less that of the operations nested in
it on the same thread: a ``while`` loop's time is its condition and bookkeeping, its
body's kernels count apart). Fused kernels are named as in the compiled HLO
(``multiply_select_fusion.6``); dump the HLO (``XLA_FLAGS=--xla_dump_to=DIR
--xla_dump_hlo_as_text``, with ``JAXSLAM_CACHE_DIR=off`` so that the program is
compiled) to see their shapes and the source lines in their metadata.

    python benchmarks/diagnostics/profile_ops.py --case intel-srupf-30 --steps 40
    python benchmarks/diagnostics/profile_ops.py --case vp-erb-100 --steps 400

``--steps`` bounds the run (keyframes for the grid filters, scans for the landmark
filter): the profiler keeps at most about a million events, and a trace that hits
that cap covers only the start of the run (the script says so). Tracing slows the run
(the untraced and traced wall times are both reported), so read the shares, not the
absolute times. Prints the table and writes ``benchmarks/results/NAME.json``.
"""

from __future__ import annotations

import argparse
import collections
import glob
import gzip
import json
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _common import print_table, write_json  # noqa: E402

CASES = {
    "intel-srupf-30": ("grid", "intel", "srupf-gm", 30),
    "intel-gmapping-30": ("grid", "intel", "gmapping", 30),
    "killian-srupf-30": ("grid", "mit-killian", "srupf-gm", 30),
    "vp-erb-100": ("landmark", "victoria-park", "erb-upf", 100),
    "vp-erb-1000": ("landmark", "victoria-park", "erb-upf", 1000),
}

EVENT_CAP = 1_000_000
"""The profiler's event limit: a trace with this many events was cut short."""

WRAPPERS = ("ThunkExecutor", "PjitFunction", "ExecuteHelper", "block_until_ready")
"""Host-side spans around the kernels (waits, dispatch), left out of the kernel total."""


def exclusive_times(events: list[dict]) -> tuple[dict[str, float], dict[str, float], dict[str, int]]:
    """``(exclusive, inclusive, count)`` per name, in microseconds, of complete
    (``"ph": "X"``) trace events. An event's name is its ``args.hlo_op`` where it has
    one. Nesting is per thread (``pid``, ``tid``) by time: an event inside another's
    span is its child, and its duration is taken off the parent's exclusive time."""
    by_thread = collections.defaultdict(list)
    for event in events:
        if event.get("ph") == "X":
            by_thread[(event.get("pid"), event.get("tid"))].append(event)
    exclusive: dict[str, float] = collections.Counter()
    inclusive: dict[str, float] = collections.Counter()
    count: dict[str, int] = collections.Counter()
    for thread_events in by_thread.values():
        thread_events.sort(key=lambda e: (e["ts"], -e.get("dur", 0.0)))
        stack: list[tuple[str, float]] = []
        for event in thread_events:
            start, duration = event["ts"], event.get("dur", 0.0)
            while stack and stack[-1][1] <= start:
                stack.pop()
            name = event.get("args", {}).get("hlo_op", event["name"])
            if stack:
                exclusive[stack[-1][0]] -= duration
            exclusive[name] += duration
            inclusive[name] += duration
            count[name] += 1
            stack.append((name, start + duration))
    return dict(exclusive), dict(inclusive), dict(count)


def run_case(case: str, steps: int | None):
    kind, dataset, algorithm, particles = CASES[case]
    from jaxslam.runtime.compiler import set_threads

    threads = set_threads(None, algorithm, particles)["threads"]
    if kind == "grid":
        from jaxslam.grid.experiment import run_grid_slam

        def once():
            return run_grid_slam(dataset, algorithm, particles=particles, seed=0, progress=False,
                                 max_keyframes=steps).wall_s
    else:
        from jaxslam.datasets import victoria_park
        from jaxslam.feature.experiment import run_landmark_slam

        sequence = victoria_park.load_sequence("detections", max_range=30.0, max_steps=steps)

        def once():
            return run_landmark_slam(sequence, algorithm, particles=particles, seed=0, progress=False).wall_s
    return once, threads


def profile(once, folder: Path) -> tuple[list[dict], float]:
    import jax

    options = jax.profiler.ProfileOptions()
    options.python_tracer_level = 0
    options.host_tracer_level = 2
    jax.profiler.start_trace(str(folder), profiler_options=options)
    try:
        wall = once()
    finally:
        jax.profiler.stop_trace()
    traces = sorted(glob.glob(str(folder / "plugins" / "profile" / "*" / "*.trace.json.gz")))
    if not traces:
        raise SystemExit(f"the profiler wrote no trace under {folder}")
    with gzip.open(traces[-1]) as fh:
        return json.load(fh)["traceEvents"], wall


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--case", choices=sorted(CASES), default="intel-srupf-30")
    ap.add_argument("--steps", type=int, default=None, help="keyframes (grid) or scans (landmark); default all")
    ap.add_argument("--top", type=int, default=30, help="operations in the table")
    ap.add_argument("--name", default=None, help="JSON name (default profile_ops_CASE)")
    args = ap.parse_args(argv)

    once, threads = run_case(args.case, args.steps)
    first = time.perf_counter()
    once()
    compile_and_run_s = time.perf_counter() - first
    untraced_s = once()
    with tempfile.TemporaryDirectory() as folder:
        events, traced_s = profile(once, Path(folder))
    complete = [e for e in events if e.get("ph") == "X"]
    exclusive, inclusive, count = exclusive_times(complete)
    kernels = {n: t for n, t in exclusive.items() if not n.startswith(WRAPPERS) and n in inclusive}
    total = sum(kernels.values())
    rows = [{"op": n, "exclusive_ms": t / 1e3, "share": t / total if total else float("nan"),
             "inclusive_ms": inclusive[n] / 1e3, "calls": count[n], "us_per_call": t / count[n]}
            for n, t in sorted(kernels.items(), key=lambda kv: -kv[1])]
    truncated = len(complete) >= EVENT_CAP
    print(f"{args.case}: untraced run {untraced_s:.2f} s, traced {traced_s:.2f} s, {len(complete)} events, "
          f"operations' exclusive time {total / 1e3:.0f} ms, XLA threads {threads}")
    if truncated:
        print(f"the trace hit the profiler's {EVENT_CAP} events: it covers only the start of the run "
              "(pass a smaller --steps)")
    print_table(rows[: args.top], ["op", "exclusive_ms", "share", "inclusive_ms", "calls", "us_per_call"])
    out = write_json(args.name or f"profile_ops_{args.case}", {
        "case": args.case, "steps": args.steps, "xla_threads": threads, "first_run_s": compile_and_run_s,
        "untraced_s": untraced_s, "traced_s": traced_s, "events": len(complete), "truncated": truncated,
        "kernel_exclusive_ms": total / 1e3, "ops": rows,
    })
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
