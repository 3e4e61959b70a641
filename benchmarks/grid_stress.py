"""Many seeds over one hard stretch of a log, all started from one filter state (issue 10).

The grid filters' failures on Intel are rare (the default ``srupf-gm`` failed 2 of 30
seeds of the whole log, GMapping-style 2 of 15) and all of them happen in one stretch
(the interior excursion at scans ~11500-12620 and the return to the south corridor,
docs/results.md, robustness section). Thirty whole-log runs cannot tell a failure rate of 7 %
from 3 %, and each costs the whole log. This script spends the runs on the stretch:

1. it runs the log once with ``--base-seed`` and keeps the filter state (particles,
   maps, weights, the parameters) when ``--from-scan`` scans are done, as a checkpoint
   (:class:`jaxslam.runtime.checkpoint.Checkpoint`; the state is kept at the end of the chunk
   of 256 scans that reaches ``--from-scan``, and that scan is reported);
2. it resumes from that state with every seed of ``--seeds``: the steps after the
   checkpoint draw their proposal noise and resampling from the new seed's step keys
   (:func:`jaxslam.runtime.driver.step_keys`), the steps before it are the base run's;
3. it scores the whole trajectory on the log's benchmark relations. A run *fails* when
   a relation is off by more than 1 m (issue 10's bar for Intel and FR079). All runs
   share the first part, so the relations there add the same errors to every run and
   the failures come from the stretch.

Variants (``--variant NAME=JSON``, a dict of parameter overrides; repeatable) resume
from the same state with their parameters (the parameters in the checkpoint are
replaced), so they differ only in how they run the stretch; a variant that would have
changed the history before it is not tested on that history: with ``--own-base``
each variant makes its own base run (its parameters from the first scan) and resumes
from its own state, so a setting is judged on the history it makes. A code change is
compared by running the script in a worktree holding it, with the same base run. The
state before the stretch is one history: use several ``--base-seed`` values.

Failure rates come with a Wilson 95 % interval. Writes
``benchmarks/results/grid_stress[_TAG].json`` (after every run) and a plot of the
failure rates (``.png``).

    python benchmarks/grid_stress.py --log intel --algorithm srupf-gm --from-scan 11000 \\
        --base-seed 0 --seeds 0-99 [--variant k05='{"track_noise_scale": 0.5}'] [--tag NAME]
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import sys
import textwrap
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import RESULTS, machine_info, print_table, write_json  # noqa: E402

FAIL_M = 1.0
"""A run fails when a relation is off by more than this (m)."""


def parse_seeds(text: str) -> list[int]:
    """``"0-9,20,30-31"`` -> ``[0, ..., 9, 20, 30, 31]``."""
    seeds: list[int] = []
    for part in text.split(","):
        part = part.strip()
        if not part:
            continue
        if "-" in part:
            lo, hi = (int(p) for p in part.split("-", 1))
            if hi < lo:
                raise SystemExit(f"--seeds: empty range {part!r}")
            seeds.extend(range(lo, hi + 1))
        else:
            seeds.append(int(part))
    if not seeds:
        raise SystemExit("--seeds: no seeds given")
    return seeds


def wilson(failures: int, runs: int, z: float = 1.96) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion."""
    if runs == 0:
        return (math.nan, math.nan)
    p = failures / runs
    centre = (p + z * z / (2 * runs)) / (1 + z * z / runs)
    half = z * math.sqrt(p * (1 - p) / runs + z * z / (4 * runs * runs)) / (1 + z * z / runs)
    return (max(0.0, centre - half), min(1.0, centre + half))


def checkpoints():
    """Checkpoint subclasses: one that keeps only the first state it is asked to save,
    and one that resumes with the run's own parameters and never saves."""
    from jaxslam.runtime.checkpoint import Checkpoint

    class KeepFirst(Checkpoint):
        saved_at: int | None = None

        def save(self, carry, done, output_leaves):
            if self.saved_at is None:
                super().save(carry, done, output_leaves)
                self.saved_at = int(done)

    class ResumeWithParams(Checkpoint):
        def load(self, carry_template):
            # The carry is (state, params): restore the state only (its leaves come
            # first), so a variant may even have other parameter fields (a code change
            # run from a worktree).
            state, done, outputs = self.load_leading(carry_template[0])
            return (state, carry_template[1]), done, outputs

        def save(self, carry, done, output_leaves):
            pass

    return KeepFirst, ResumeWithParams


def base_run(log, algorithm: str, particles: int, seed: int, from_scan: int, path: Path,
             overrides: dict[str, Any] | None = None):
    """Run the whole log with ``seed`` (and the parameters ``overrides`` on the
    defaults), keeping the state at the end of the chunk that reaches ``from_scan``
    steps in ``path``: ``(steps done there, the run's result)``."""
    from jaxslam.grid.experiment import run_grid_slam

    KeepFirst, _ = checkpoints()
    keep = KeepFirst(path.with_name(path.name + ".part.npz"), every=from_scan)
    result = run_grid_slam(log, algorithm, particles, seed, overrides, progress=False, checkpoint=keep)
    keep.path.replace(path)
    return keep.saved_at, result


def resumed_run(log, algorithm: str, particles: int, seed: int, overrides: dict[str, Any], path: Path):
    """The rest of the log from the state in ``path``, with ``seed``'s step keys and the
    parameters ``overrides`` (on the defaults)."""
    from jaxslam.grid.experiment import run_grid_slam

    _, ResumeWithParams = checkpoints()
    return run_grid_slam(log, algorithm, particles, seed, overrides, progress=False,
                         checkpoint=ResumeWithParams(path, resume=True))


def base_path(work: Path, log: str, algorithm: str, particles: int, seed: int, from_scan: int,
              overrides: dict[str, Any]) -> Path:
    """The checkpoint file of a base run; a base run with parameter overrides gets its
    own file, named by a hash of them."""
    name = f"{log}_{algorithm}_{particles}_base{seed}_at{from_scan}"
    if overrides:
        name += "_" + hashlib.sha1(json.dumps(overrides, sort_keys=True).encode()).hexdigest()[:10]
    return work / f"{name}.npz"


def score(relations, result) -> dict[str, Any]:
    from jaxslam.metrics.relations import relation_errors, relations_metric

    metric = relations_metric(relations, result.scan_times, result.trajectory)
    errors = relation_errors(relations, result.scan_times, result.trajectory)
    trans = errors.trans[errors.matched]
    return {
        "mean_m": metric["trans_err_mean_m"],
        "median_m": metric["trans_err_median_m"],
        "max_m": metric["trans_err_max_m"],
        "over_0.5m": metric["n_trans_err_over_0_5m"],
        "over_1m": int(np.sum(trans > FAIL_M)),
        "n_relations": metric["n_relations"],
    }


def summarise(runs: list[dict[str, Any]]) -> list[dict[str, Any]]:
    rows = []
    for variant in dict.fromkeys(r["variant"] for r in runs):
        mine = [r for r in runs if r["variant"] == variant]
        fails = sum(r["failed"] for r in mine)
        lo, hi = wilson(fails, len(mine))
        means = np.array([r["mean_m"] for r in mine])
        rows.append({
            "variant": variant,
            "runs": len(mine),
            "failures": fails,
            "rate": round(fails / len(mine), 3),
            "wilson_95": f"{lo:.3f}-{hi:.3f}",
            "mean_m_median": round(float(np.median(means)), 4),
            "mean_m_worst": round(float(np.max(means)), 4),
            "max_m_worst": round(float(max(r["max_m"] for r in mine)), 2),
            "filter_s_per_run": round(float(np.mean([r["filter_s"] for r in mine])), 1),
        })
    return rows


def plot(summary: list[dict[str, Any]], path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(max(4.5, 1.6 + 1.2 * len(summary)), 3.8))
    x = np.arange(len(summary))
    rates = np.array([s["rate"] for s in summary])
    bounds = np.array([[float(v) for v in s["wilson_95"].split("-")] for s in summary])
    ax.bar(x, rates, color="#4878a8", width=0.6)
    ax.errorbar(x, rates, yerr=[rates - bounds[:, 0], bounds[:, 1] - rates], fmt="none", ecolor="k", capsize=4)
    for i, s in enumerate(summary):
        ax.text(i, bounds[i, 1] + 0.01, f"{s['failures']}/{s['runs']}", ha="center", va="bottom", fontsize=8)
    ax.set_xticks(x, [s["variant"] for s in summary], rotation=20, ha="right")
    ax.set_ylabel(f"runs with a relation > {FAIL_M:g} m")
    ax.set_ylim(0, max(0.2, float(bounds[:, 1].max()) + 0.06))
    ax.set_title(textwrap.fill(title, 60), fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def title(settings: dict[str, Any], bases: list[dict[str, Any]]) -> str:
    """The plot's title: log, filter, the stretch and the base states."""
    return (f"{settings['log']}, {settings['algorithm']}, {settings['particles']} particles: scans "
            f"{bases[0]['saved_at_scan']}-end from base seed(s) {settings['base_seeds']}"
            + (", each variant's own" if settings.get("own_base") else ""))


def merge(paths: list[str], tag: str) -> int:
    """One JSON and plot from several results of the same log, filter and kind of base
    state (the defaults' or, with ``--own-base``, each variant's own)."""
    parts = [json.loads(Path(p).read_text()) for p in paths]
    keys = ("log", "algorithm", "particles", "from_scan", "own_base")
    first = parts[0]["settings"]
    for path, part in zip(paths, parts):
        if any(part["settings"].get(k, False) != first.get(k, False) for k in keys):
            raise SystemExit(f"{path}: another log, filter or kind of base state than {paths[0]}")
    runs = [dict(r) for part in parts for r in part["runs"]]
    variants = {name: v for part in parts for name, v in part["settings"]["variants"].items()}
    bases = [b for i, part in enumerate(parts) for b in part["bases"]
             if b not in [c for other in parts[:i] for c in other["bases"]]]
    base_seeds = sorted({s for part in parts for s in part["settings"]["base_seeds"]})
    settings = {**first, "variants": variants, "base_seeds": base_seeds}
    name = "grid_stress" + (f"_{tag}" if tag else "")
    payload = {"note": parts[0]["note"], "machine": machine_info(), "merged_from": [Path(p).name for p in paths],
               "settings": settings, "bases": bases, "runs": runs, "summary": summarise(runs)}
    write_json(name, payload)
    print_table(payload["summary"], list(payload["summary"][0]))
    plot(payload["summary"], RESULTS / f"{name}.png", title(settings, bases))
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("--log", default="intel", help="a dataset with benchmark relations (intel, fr079, mit-killian)")
    parser.add_argument("--algorithm", default="srupf-gm", choices=["srupf-gm", "gmapping"])
    parser.add_argument("--particles", type=int, default=30)
    parser.add_argument("--from-scan", type=int, default=11000, help="scans run by the base run before the stretch")
    parser.add_argument("--base-seed", type=int, action="append", default=None,
                        help="seed of the run up to --from-scan (repeatable; default 0)")
    parser.add_argument("--seeds", default="0-99", help="seeds of the stretch, e.g. 0-99 or 0,3,7")
    parser.add_argument("--variant", action="append", default=[], metavar="NAME=JSON",
                        help="parameter overrides resumed from the same state (repeatable; "
                             "the defaults always run as 'defaults')")
    parser.add_argument("--no-defaults", action="store_true", help="run only the --variant settings")
    parser.add_argument("--own-base", action="store_true",
                        help="each variant makes its own base run with its parameters (from the first scan) "
                             "and resumes from that state, instead of all resuming from the defaults' state")
    parser.add_argument("--work", default="/tmp/grid_stress", help="folder of the base checkpoints")
    parser.add_argument("--tag", default="")
    parser.add_argument("--merge", nargs="+", metavar="JSON", default=None,
                        help="join the runs of earlier results (same log, filter and base state) into "
                             "grid_stress_TAG.json and its plot, instead of running")
    args = parser.parse_args(argv)
    if args.merge:
        return merge(args.merge, args.tag)

    from jaxslam.datasets.registry import load_dataset_log
    from jaxslam.metrics.relations import DATASET_RELATIONS, load_dataset_relations

    if args.log not in DATASET_RELATIONS:
        raise SystemExit(f"--log {args.log!r} has no benchmark relations; known: {', '.join(DATASET_RELATIONS)}")
    variants: dict[str, dict[str, Any]] = {} if args.no_defaults else {"defaults": {}}
    for spec in args.variant:
        name, _, text = spec.partition("=")
        try:
            overrides = json.loads(text)
        except json.JSONDecodeError as err:
            raise SystemExit(f"--variant {spec!r}: not JSON ({err})") from None
        if not name or not isinstance(overrides, dict):
            raise SystemExit(f"--variant {spec!r}: expected NAME=JSON object")
        variants[name] = overrides
    if not variants:
        raise SystemExit("nothing to run: --no-defaults without --variant")
    seeds = parse_seeds(args.seeds)
    base_seeds = args.base_seed or [0]
    log = load_dataset_log(args.log)
    if not 0 < args.from_scan < log.num_scans - 1:
        raise SystemExit(f"--from-scan must lie inside the log's {log.num_scans} scans")
    relations = load_dataset_relations(args.log)
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    name = "grid_stress" + (f"_{args.tag}" if args.tag else "")
    payload: dict[str, Any] = {
        "note": __doc__.split("\n\n")[0],
        "machine": machine_info(),
        "settings": {"log": args.log, "algorithm": args.algorithm, "particles": args.particles,
                     "from_scan": args.from_scan, "base_seeds": base_seeds, "seeds": seeds,
                     "variants": variants, "own_base": args.own_base, "fail_m": FAIL_M},
        "bases": [],
        "runs": [],
    }
    total = len(base_seeds) * len(seeds) * len(variants)
    started = time.perf_counter()
    for base_seed in base_seeds:
        for variant, overrides in variants.items():
            made_with = overrides if args.own_base else {}
            path = base_path(work, args.log, args.algorithm, args.particles, base_seed, args.from_scan, made_with)
            meta = path.with_suffix(".json")
            if not (path.exists() and meta.exists()):
                saved_at, result = base_run(log, args.algorithm, args.particles, base_seed, args.from_scan, path,
                                            made_with)
                meta.write_text(json.dumps({"saved_at_scan": saved_at, **score(relations, result)}))
            base = json.loads(meta.read_text())
            base.update(base_seed=base_seed, made_with=made_with)
            if base not in payload["bases"]:
                payload["bases"].append(base)
                print(f"base seed {base_seed}{f' ({variant})' if made_with else ''}: state kept at scan "
                      f"{base['saved_at_scan']}; the base run itself: {base['mean_m']:.3f} m mean, "
                      f"worst {base['max_m']:.2f} m", flush=True)
            for seed in seeds:
                result = resumed_run(log, args.algorithm, args.particles, seed, overrides, path)
                row = {"variant": variant, "base_seed": base_seed, "seed": seed, "filter_s": result.wall_s,
                       "compile_s": result.compile_s, **score(relations, result)}
                row["failed"] = bool(row["over_1m"] > 0)
                payload["runs"].append(row)
                done = len(payload["runs"])
                eta = (time.perf_counter() - started) / done * (total - done)
                print(f"[{done}/{total}, ETA {eta / 60:.0f} min] {variant} base {base_seed} seed {seed}: "
                      f"{row['mean_m']:.3f} m, worst {row['max_m']:.2f} m, {row['over_1m']} over 1 m"
                      + ("  FAILED" if row["failed"] else ""), flush=True)
                payload["summary"] = summarise(payload["runs"])
                write_json(name, payload)
    print_table(payload["summary"], list(payload["summary"][0]))
    png = RESULTS / f"{name}.png"
    plot(payload["summary"], png, title(payload["settings"], payload["bases"]))
    print(f"wrote {RESULTS / (name + '.json')} and {png}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
