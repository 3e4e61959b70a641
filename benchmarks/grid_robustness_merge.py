"""Merge the JSON files of several ``grid_robustness.py`` runs into one table and plot.

A full suite (every log, both levels, 5 seeds, three filters) takes hours on a 2-core
machine, so it is run in parts (``--tag``). This script reads the parts in the order
given; a run of the same ``(log, filter, seed)`` in a later file replaces the earlier
one (so a part re-run after a change of defaults supersedes the old runs; runs under
another code split, ``grid_robustness.py --code-split``, are other runs), and every
run keeps the name of the file it came from. It prints the per-run and per-cell
tables (:func:`grid_robustness.summarize`: the worst seed counts, and the share of
seeds over twice the median seed), writes
``benchmarks/results/grid_robustness_merged[_NAME].json`` (``--out OUT``:
``OUT.json``) and a plot of the relations
error of every seed, log by log, one marker per filter (logs without ground truth
are listed, not plotted).

    python benchmarks/grid_robustness_merge.py benchmarks/results/grid_robustness_{defaults,perturbed_high}.json
    python benchmarks/grid_robustness_merge.py OLD.json:gmapping-cpp NEW.json   # C++ runs of OLD, the rest of NEW
    python benchmarks/grid_robustness_merge.py 'VARIANTS.json:srupf-gm[l05]=srupf-gm' NEW.json

The last form takes a variant's runs under another name: a variant whose settings
have since become the defaults (``l05`` ran ``linear_update`` 0.5 before that was
the default) counts as the defaults' run. Each renamed run keeps its old name in
``renamed_from``, and the merged JSON lists the sources as given. ``--common`` keeps
only the runs that compare arms: the logs and code splits two or more filters ran, on
the seeds all of them ran (:func:`common`).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import machine_info, print_table  # noqa: E402
from grid_robustness import FILTERS, RESULTS, summarize  # noqa: E402


def parse_source(spec: str) -> tuple[Path, dict[str, str] | None]:
    """``PATH`` (every run) or ``PATH:FILTER[,FILTER..]`` (only those filters' runs),
    where ``FILTER=NAME`` takes that filter's runs under ``NAME``. Returns the path
    and ``{filter: name in the merge}`` (``None``: every run, under its own name)."""
    path, _, names = spec.partition(":")
    if not names:
        return Path(path), None
    picked: dict[str, str] = {}
    for item in names.split(","):
        name, sep, new = item.partition("=")
        if not name or (sep and not new):
            raise SystemExit(f"{spec}: empty filter name in {item!r} (PATH:FILTER[=NAME][,...])")
        picked[name] = new or name
    return Path(path), picked


def run_cpu(machine: dict | None) -> str | None:
    """The CPU a part's runs were made on, ``"AMD EPYC 26/2"`` (name, family/model):
    XLA compiles code for the CPU it runs on, and another CPU draws other runs from the
    same seeds, so a merged file records it per run."""
    if not machine or "cpu" not in machine:
        return None
    return f"{machine['cpu']} {machine.get('cpu_family_model', '?')}"


def merge(sources: list[str | Path]) -> tuple[list[dict], list[str]]:
    """Runs of ``sources`` in order (see :func:`parse_source`), later ``(log, filter,
    seed)`` replacing earlier ones; also the list of replaced runs (for the record).
    Each run keeps its ``source`` file and, where that file names its machine, its
    ``cpu`` (:func:`run_cpu`)."""
    by_key: dict[tuple, dict] = {}
    replaced: list[str] = []
    for spec in sources:
        path, only = parse_source(str(spec))
        try:
            payload = json.loads(path.read_text())
            runs = payload["runs"]
        except (OSError, ValueError, KeyError) as error:
            raise SystemExit(f"{path}: not a grid_robustness result ({error})") from error
        cpu = run_cpu(payload.get("machine"))
        for run in runs:
            if cpu is not None and "cpu" not in run:  # a run keeps the CPU of the file it was made in
                run = {**run, "cpu": cpu}
            if only is not None:
                if run["filter"] not in only:
                    continue
                if only[run["filter"]] != run["filter"]:
                    run = {**run, "filter": only[run["filter"]], "renamed_from": run["filter"]}
            key = (run["log"], run["filter"], run["seed"], run.get("code_split"))
            if key in by_key:
                split = "" if key[3] is None else f" code split {key[3]}"
                replaced.append(f"{key[0]} {key[1]} seed {key[2]}{split}: {by_key[key]['source']} -> {path.name}")
            by_key[key] = {**run, "source": path.name}
    order = {f: i for i, f in enumerate(FILTERS)}
    rows = sorted(by_key.values(), key=lambda r: (r["log"], order.get(r["filter"].split("[")[0], 99),
                                                  r.get("code_split") or 0, r["seed"]))
    return rows, replaced


def common(rows: list[dict]) -> list[dict]:
    """The runs of ``rows`` that compare filters: of each log and code split that two or
    more filters ran, the seeds every one of them ran (``--common``)."""
    ran: dict[tuple, dict[str, set]] = {}
    for row in rows:
        ran.setdefault((row["log"], row.get("code_split")), {}).setdefault(row["filter"], set()).add(row["seed"])
    keep = {key: set.intersection(*by_filter.values()) for key, by_filter in ran.items() if len(by_filter) > 1}
    return [row for row in rows if row["seed"] in keep.get((row["log"], row.get("code_split")), ())]


def series(rows: list[dict]) -> list[tuple[str, int | None]]:
    """The plot's series: each ``(filter, code_split)`` the runs hold (a variant,
    ``srupf-gm[NAME]``, is a filter of its own), in the order of :data:`FILTERS`."""
    order = {f: i for i, f in enumerate(FILTERS)}
    return sorted({(r["filter"], r.get("code_split")) for r in rows},
                  key=lambda k: (order.get(k[0].split("[")[0], 99), k[0], k[1] or 0))


def plot(rows: list[dict], path: Path) -> None:
    """Relations error (mean over relations) of each seed, per log, filter and code split."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    scored = [r for r in rows if r.get("mean_m") is not None and "error" not in r]
    logs = sorted({r["log"] for r in scored})
    filters = series(scored)
    fig, ax = plt.subplots(figsize=(max(6.0, 1.1 * len(logs) + 2) + 2.5, 4.2))
    markers = {"srupf-gm": "o", "gmapping": "s", "gmapping-cpp": "^"}
    width = 0.8 / max(1, len(filters))
    for j, (name, split) in enumerate(filters):
        label = name if split is None else f"{name}, code split {split}"
        for i, log in enumerate(logs):
            values = [r["mean_m"] for r in scored
                      if r["log"] == log and r["filter"] == name and r.get("code_split") == split]
            x = [i - 0.4 + width * (j + 0.5)] * len(values)
            ax.scatter(x, values, marker=markers.get(name.split("[")[0], "x"), color=f"C{j}", s=22,
                       label=label if i == 0 else None, alpha=0.8)
    ax.set_yscale("log")
    ax.set_xticks(range(len(logs)))
    ax.set_xticklabels(logs, rotation=30, ha="right")
    ax.set_ylabel("relations error, mean [m] (one marker per seed)")
    ax.grid(True, axis="y", which="both", alpha=0.3)
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8)  # outside: markers sit at any height
    variants = any("[" in name for name, _ in filters)
    ax.set_title("grid SLAM, 30 particles, the same seeds under each setting" if variants
                 else "grid SLAM with the defaults, 30 particles")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def markdown(summary: list[dict]) -> str:
    """One Markdown row per log, one column per filter (and code split, where the runs
    have one): on logs with relations the mean of the seeds' means (worst seed), the
    worst relation and the count over 0.5 m over every seed; elsewhere the largest
    keyframe correction over the seeds."""
    splits = sorted({s.get("code_split") for s in summary}, key=lambda v: -1 if v is None else v)
    filters = [(f, v) for f in FILTERS for v in splits
               if any(s["filter"] == f and s.get("code_split") == v for s in summary)]
    logs = sorted({s["log"] for s in summary}, key=lambda log: ("worst_mean_m" not in next(
        s for s in summary if s["log"] == log), log))
    names = [f if v is None else f"{f}, code split {v}" for f, v in filters]
    lines = ["| log | " + " | ".join(names) + " |", "|---|" + "---|" * len(filters)]
    for log in logs:
        cells = []
        for name, split in filters:
            item = next((s for s in summary if s["log"] == log and s["filter"] == name
                         and s.get("code_split") == split), None)
            if item is None or not item["seeds"]:
                cells.append("")
            elif "worst_mean_m" in item:
                cells.append(f"{item['mean_of_means_m']:.3f} ({item['worst_mean_m']:.3f}), "
                             f"{item['worst_max_m']:.2f} m, {item['over_0.5m_total']} [{item['seeds']}]")
            else:
                cells.append(f"largest correction {item['worst_jump_m']:.2f} m [{item['seeds']}]")
        lines.append(f"| {log} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("files", nargs="+",
                        help="grid_robustness JSON files, earliest first; PATH:FILTER[,FILTER] takes only "
                             "those filters' runs of a file (e.g. GMapping C++ runs of an earlier part); "
                             "FILTER=NAME takes them under NAME (a variant that became the default)")
    parser.add_argument("--name", default="", help="suffix of the merged JSON and plot")
    parser.add_argument("--out", default="", help="name of the merged JSON and plot under benchmarks/results/ "
                        "(default grid_robustness_merged[_NAME])")
    parser.add_argument("--markdown", action="store_true",
                        help="also print a Markdown table: per log and filter the mean of the seeds' means "
                             "(worst seed), the worst relation, relations over 0.5 m and [seeds]")
    parser.add_argument("--common", action="store_true",
                        help="keep only the logs and code splits that two or more filters ran, on the seeds "
                             "all of them ran")
    args = parser.parse_args(argv)
    rows, replaced = merge(args.files)
    if args.common:
        rows = common(rows)
    print_table(rows, ["log", "seed", "filter", "mean_m", "median_m", "max_m", "over_0.5m", "n_relations",
                       "wall_s", "source"])
    print()
    summary = summarize(rows)
    columns = ["log", "filter", "seeds", "worst_mean_m", "mean_of_means_m", "median_seed_mean_m", "tail_share",
               "worst_max_m", "over_0.5m_total", "wall_s_mean"]
    if any("code_split" in s for s in summary):
        columns.insert(2, "code_split")
    print_table(summary, columns)
    if args.markdown:
        print()
        print(markdown(summary))
    stem = args.out or "grid_robustness_merged" + (f"_{args.name}" if args.name else "")
    json_path = RESULTS / f"{stem}.json"
    png_path = RESULTS / f"{stem}.png"
    payload = {"machine": machine_info(), "sources": [str(p) for p in args.files], "replaced": replaced,
               "runs": rows, "summary": summary}
    json_path.write_text(json.dumps(payload, indent=1, default=float) + "\n")
    plot(rows, png_path)
    print(f"wrote {json_path} and {png_path} ({len(replaced)} runs replaced by later files)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
