"""The documentation's result tables, generated from the JSON kept in ``benchmarks/results/``.

``conf.py`` runs :func:`write_all` before every build, so that a table cannot drift from
the data it shows: each table is a Markdown file under ``docs/_generated/`` that a page
includes. ``python docs/generate_tables.py`` writes them by hand (and prints the README's
headline table, which ``tests/test_docs.py`` checks against the README).

Every function reads one or two result files and fails loudly (``KeyError``,
``FileNotFoundError``) when a file or a field it needs is missing.
"""

from __future__ import annotations

import collections
import json
import re
import statistics
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
GENERATED = Path(__file__).resolve().parent / "_generated"

RAW_LOGS = ["intel", "fr079", "mit-killian"]
PERTURBED_LOGS = ["intel-high", "csail-high", "seattle-high", "belgioioso-high", "edmonton-high", "fhw-high",
                  "orebro-high", "acapulco-high", "fr101-high", "infinite-corridor-high", "fr-campus-high"]
LOG_NAMES = {"intel": "Intel (raw)", "fr079": "FR079 (raw)", "mit-killian": "MIT Killian (raw)"}
# The perturbed logs: a GMapping-corrected log (its dataset name) given generated wheel
# odometry with the suite's high noise, drift and scale errors.
CORRECTED_NAMES = {"fr101": "freiburg-101", "fr-campus": "freiburg-campus"}
for _log in PERTURBED_LOGS:
    _base = _log.removesuffix("-high")
    LOG_NAMES[_log] = f"`{CORRECTED_NAMES.get(_base, _base)}-corrected`, perturbed"
FILTER_NAMES = {"srupf-gm": "`srupf-gm`", "gmapping": "`gmapping`", "gmapping-cpp": "GMapping C++"}
SPEED_CASES = {"intel-srupf-30": "Intel, `srupf-gm`, 30", "intel-gmapping-30": "Intel, `gmapping`, 30",
               "killian-srupf-30": "MIT Killian, `srupf-gm`, 30", "clinic-srupf-30": "fr-clinic, `srupf-gm`, 30",
               "vp-erb-100": "Victoria Park, `erb-upf`, 100"}


def load(name: str) -> dict:
    """The JSON of ``benchmarks/results/NAME``."""
    return json.loads((RESULTS / name).read_text())


def _table(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return "\n".join(lines) + "\n"


def _cells(summary: list[dict]) -> dict[tuple[str, str], dict]:
    return {(s["log"], s["filter"]): s for s in summary}


def _mean_worst(cell: dict | None, seeds: bool = True) -> str:
    if cell is None:
        return ""
    text = f"{cell['mean_of_means_m']:.3f} ({cell['worst_mean_m']:.3f})"
    return text + (f" [{cell['seeds']}]" if seeds else "")


def machine_line(data: dict) -> str:
    """One sentence on the machine a result file was measured on; a merged file whose
    runs name more than one CPU (``cpu``, ``grid_robustness_merge.run_cpu``) names each,
    with its count of runs."""
    m = data["machine"]
    cpus = collections.Counter(r["cpu"] for r in data.get("runs", []) if "cpu" in r)
    if len(cpus) > 1:
        parts = [f"{cpu.rsplit(' ', 1)[0]} (family/model {cpu.rsplit(' ', 1)[1]}, {n} run{'s' * (n != 1)})"
                 for cpu, n in sorted(cpus.items(), key=lambda item: -item[1])]
        return f"Measured on {m['cores']}-core machines: " + " and ".join(parts) + f"; jax {m['jax']}."
    return f"Measured on a {m['cores']}-core {m['cpu']} (family/model {m.get('cpu_family_model', '?')}), jax {m['jax']}."


def robustness_table() -> str:
    """The robustness suite: every filter with its defaults, relations error mean of the
    seeds' means (worst seed) [seeds], m."""
    data = load("robustness_suite.json")
    cells = _cells(data["summary"])
    filters = ["srupf-gm", "gmapping", "gmapping-cpp"]
    rows = []
    for log in RAW_LOGS + PERTURBED_LOGS:
        rows.append([LOG_NAMES.get(log, log)] + [_mean_worst(cells.get((log, f))) for f in filters])
    return _table(["log: relations error, m, mean over seeds (worst seed) [seeds]"]
                  + [FILTER_NAMES[f] for f in filters], rows)


def robustness_counts() -> dict[str, int]:
    """How many of the suite's scored logs ``srupf-gm``'s mean and worst seed are at or
    under GMapping C++'s on."""
    cells = _cells(load("robustness_suite.json")["summary"])
    logs = RAW_LOGS + PERTURBED_LOGS
    ours = [cells[(log, "srupf-gm")] for log in logs]
    cpp = [cells[(log, "gmapping-cpp")] for log in logs]
    return {"logs": len(logs),
            "mean_at_or_under": sum(a["mean_of_means_m"] <= b["mean_of_means_m"] for a, b in zip(ours, cpp)),
            "worst_at_or_under": sum(a["worst_mean_m"] <= b["worst_mean_m"] for a, b in zip(ours, cpp))}


SPEED_FILES = ("end_to_end.json", "end_to_end_intel.json", "end_to_end_killian_vp.json")
"""The whole-log end-to-end result files of one machine, newest first (the first-run
table, :func:`first_run_table`, has its own file)."""


def _current_rows(name: str) -> list[dict]:
    """The rows of an end-to-end file measured with this checkout (``--tree new=.``, or no ``--tree``)."""
    return [row for row in load(name)["rows"] if row.get("tree") in (None, "new")]


def _speed_rows() -> dict[str, dict]:
    """Each whole-log case's row from the newest file that ran it (:data:`SPEED_FILES`)."""
    rows: dict[str, dict] = {}
    for name in SPEED_FILES:
        for row in _current_rows(name):
            if row["case"] in SPEED_CASES:
                rows.setdefault(row["case"], row)
    return rows


def speed_table() -> str:
    """Whole ``jaxslam run`` processes, cold and warm compilation cache, GMapping C++ in the
    same run."""
    rows = []
    for case, row in _speed_rows().items():
        cpp = row.get("gmapping_process_s")
        modes = [mode for mode in ("cold", "warm") if row.get(f"{mode}_process_s") is not None]
        for mode in modes:
            ratio = row.get(f"{mode}_speedup_process")
            rows.append([SPEED_CASES[case] if mode == modes[0] else "", mode,
                         f"{row[f'{mode}_process_s']:.1f} s", f"{row[f'{mode}_compile_s']:.2f} s",
                         f"{row[f'{mode}_wall_s']:.1f} s",
                         f"{cpp:.1f} s" if cpp and mode == "cold" else "",
                         f"{ratio:.2f}x" if ratio else ""])
    return _table(["case", "cache", "whole process", "compile", "filter loop", "GMapping C++ process",
                   "GMapping C++ / jaxslam"], rows)


FIRST_RUN_CASES = {"intel200-bag": "Intel's first 200 keyframes as a ROS 2 bag, `srupf-gm`, 30",
                   "intel200-sweep": "a sweep of 10, 20, 30, 50 and 100 particles on those 200 keyframes, one process",
                   "intel-srupf-30": "Intel, `srupf-gm`, 30", "intel-gmapping-30": "Intel, `gmapping`, 30",
                   "vp-erb-100": "Victoria Park, `erb-upf`, 100"}


def first_run_table() -> str:
    """What a first run pays before the filter works: compilation with an empty cache
    (programs compiled, tracing and lowering among them) beside the filter loop and the
    whole process, and the same with the filled cache."""
    by_case = {row["case"]: row for row in _current_rows("end_to_end_first_run.json")}
    rows = []
    for case, label in FIRST_RUN_CASES.items():
        row = by_case[case]
        for mode in ("cold", "warm"):
            if row.get(f"{mode}_process_s") is None:
                continue
            trace, lower = row.get(f"{mode}_trace_s"), row.get(f"{mode}_lower_s")
            parts = f" (tracing {trace:.1f} s, lowering {lower:.1f} s)" if mode == "cold" and trace else ""
            rows.append([label if mode == "cold" else "", mode, str(row[f"{mode}_compiled"]),
                         f"{row[f'{mode}_compile_s']:.1f} s{parts}", f"{row[f'{mode}_wall_s']:.1f} s",
                         f"{row[f'{mode}_process_s']:.1f} s"])
    return _table(["case", "cache", "programs compiled", "compilation", "filter loop", "whole process"], rows)


def continue_map_table() -> str:
    """The second part of a log continued from the first part's saved map, against the
    whole log in one run, on the second part's relations."""
    data = load("continue_map.json")
    rows = [[str(r["seed"]), str(r["relations"]), f"{r['continued_trans_m']:.4f} m, {r['continued_rot_deg']:.3f} deg",
             f"{r['whole_trans_m']:.4f} m, {r['whole_rot_deg']:.3f} deg", f"{r['ratio']:.2f}",
             f"{100 * r['first_scan_match']['moved_m']:.1f} cm, {r['first_scan_match']['turned_deg']:.2f} deg"]
            for r in data["runs"]]
    return _table(["seed", "relations scored", "continued: mean error", "whole log: mean error",
                   "continued / whole", "first scan's match moved it"], rows)


def continue_localize_table() -> str:
    """The second part started by localization in the saved map (``--localize-first``),
    against the run started at the known pose."""
    rows = []
    for r in load("continue_map.json")["runs"]:
        first = r.get("localize_first")
        if first:
            rows.append([str(r["seed"]), str(first["converged_scan"]), str(first["start_scan"]),
                         f"{100 * first['start_offset_m']:.1f} cm, {first['start_offset_deg']:.2f} deg",
                         f"{first['keyframes']} keyframes ({first['scans_compared']} scans)",
                         f"{100 * first['max_gap_m']:.1f} cm"])
    return _table(["seed", "localizer converged at scan", "mapping starts at scan",
                   "start: apart from the known-pose run's", "mapped", "paths apart, at most"], rows)


def landmark_table() -> str:
    """Victoria Park, all scans: GPS error after rigid alignment over seeds."""
    data = load("erb_particles.json")
    rows = []
    for run in sorted(data["runs"], key=lambda r: (r["particles"], r["algorithm"])):
        lo, hi = run["gps_mean_m_ci"]
        rows.append([str(run["particles"]), f"`{run['algorithm']}`", str(len(run["seeds"])),
                     f"{run['gps_mean_m']:.2f} ± {run['gps_mean_m_std']:.2f} m", f"[{lo:.2f}, {hi:.2f}]",
                     f"{run['gps_mean_m_median']:.2f} m", f"{max(run['gps_mean_m_per_seed']):.2f} m"])
    return _table(["particles", "filter", "seeds", "GPS error, mean ± sd over seeds", "95 % interval",
                   "median", "worst seed"], rows)


def scale_table() -> str:
    """Paged maps at scale: whole-process peak memory and time per keyframe."""
    rows = []
    for run in load("grid_scale.json")["runs"]:
        rows.append([run["dataset"], str(run["particles"]), str(run["scans"]), str(run["keyframes"]),
                     f"{run['peak_rss_mb'] / 1000:.2f} GB", f"{1000 * run['s_per_keyframe']:.1f} ms",
                     str(run["maps"]["tiles_used"]), f"{run['trans_err_mean_m']:.3f} m"])
    big = load("grid_scale_killian_1000.json")
    s = big["summary"]
    rows.append([s["dataset"], str(s["particles"]), str(s["scans"]), str(s["keyframes"]),
                 f"{big['peak_rss_gb']:.2f} GB", f"{1000 * s['wall_s'] / s['keyframes']:.0f} ms",
                 str(s["maps"]["tiles_used"]), f"{s['trans_err_mean_m']:.3f} m"])
    return _table(["log", "particles", "scans", "keyframes", "peak memory (process)", "per keyframe",
                   "tiles used", "relations error"], rows)


FEATURE_VARIANTS = {"base": "the defaults", "no_closure": "no loop-closure search (`closure` False)",
                    "no_recover": "no recovery (`recover_radius` 0)",
                    "coarse0": "no coarse stage (`coarse_iterations` 0)",
                    "kf1m": "GMapping's 1 m keyframes (`linear_update` 1)",
                    "no_tracking": "no per-scan tracking (`tracking` False)",
                    "all_off": "all five off"}


def feature_cost_table() -> str:
    """Raw Intel, seed 0, one core: each part of ``srupf-gm`` switched off in turn."""
    runs = {r["variant"]: r for r in load("feature_cost_intel.json")["runs"]}
    rows = []
    for key, label in FEATURE_VARIANTS.items():
        r = runs[key]
        rows.append([label, f"{r['filter_s']:.1f} s", f"{r['compile_s']:.1f} s", str(r["keyframes"]),
                     f"{r['mean_m']:.4f} m", str(r["over_0.5m"])])
    return _table(["variant", "filter loop", "cold compile", "keyframes", "relations error (mean)",
                   "relations over 0.5 m"], rows)


def _srupf_runs(data: dict) -> dict[tuple[str, int], float]:
    return {(r["log"], r["seed"]): r["mean_m"] for r in data["runs"] if r["filter"] == "srupf-gm"}


def other_cpu_table() -> str:
    """The same program and seeds on the suite's CPU and on another one: ``srupf-gm``'s
    relations error per log, mean of the seeds' means (worst seed), the seeds over
    twice the log's median seed, and the seeds that drew the same run on both."""
    suite, other = load("robustness_suite.json"), load("robustness_other_cpu.json")
    cpus = [f"CPU {d['machine']['cpu_family_model']}" for d in (suite, other)]
    first, second = _srupf_runs(suite), _srupf_runs(other)
    rows = []
    for log in [log for log in RAW_LOGS + PERTURBED_LOGS if any(name == log for name, _ in second)]:
        seeds = sorted(seed for (name, seed) in second if name == log and (name, seed) in first)
        cells = []
        for runs in (first, second):
            errors = [runs[(log, seed)] for seed in seeds]
            median = statistics.median(errors)
            cells.append(f"{statistics.mean(errors):.3f} ({max(errors):.3f}), "
                         f"{sum(e > 2 * median for e in errors)} over 2x median")
        same = sum(first[(log, seed)] == second[(log, seed)] for seed in seeds)
        rows.append([LOG_NAMES.get(log, log), f"{seeds[0]}-{seeds[-1]}", *cells, str(same)])
    return _table(["log", "seeds", *cpus, "same run on both"], rows)


def tail_places_table() -> str:
    """Per seed of a log, where its relations over 1 m lie (``5k-11k``: from a scan in
    5000-5999 to one in 11000-11999) and the closures taken in the later stretch
    (``scan:verdict/undone at``; ``R`` right, ``W`` wrong, ``?`` no relation to judge),
    the first of those places where most of the pair's relations are wrong, and the
    decision there (``closure_diagnostics.cause``)."""
    data = load("closure_diagnostics_killian.json")
    labels = data["tail_causes"]["labels"]
    rows = []
    for row in sorted(data["bad_places"], key=lambda r: _seed(r["run"])):
        places = [f"{row[f'place_{k}']} ({row[f'closures_{k}']})" for k in (1, 2, 3) if f"place_{k}" in row]
        first = f"{row['first_place']} ({labels[row['cause']]})" if row.get("first_place") else ""
        rows.append([str(_seed(row["run"])), f"{row['mean_m']:.3f}", str(row["over_1m"]), "; ".join(places), first])
    return _table(["seed", "mean error, m", "relations over 1 m",
                   "largest groups: stretches, relations (closures in the later stretch)",
                   "went wrong first (cause)"], rows)


REFUSAL_LOGS = [("MIT Killian", "closure_diagnostics_refusals_killian.json"),
                ("infinite corridor (high)", "closure_diagnostics_refusals_corridor.json"),
                ("Freiburg campus (high)", "closure_diagnostics_refusals_campus.json"),
                ("Orebro (high)", "closure_diagnostics_refusals_orebro.json")]
"""The runs of the tail table with the search's record (``Info.track_search``), per log."""


def tail_refusals_table(logs: list[tuple[str, str]] = REFUSAL_LOGS) -> str:
    """Per run of the tail (``logs``: rows as :data:`REFUSAL_LOGS`), where it went wrong
    first, the decision there (``closure_diagnostics.cause``, split by what the search
    did where no right closure came) and the search's record of that stretch
    (``closure_diagnostics.search_summary``)."""
    rows = []
    for log, name in logs:
        data = load(name)
        labels = data["tail_causes"]["labels"]
        for row in sorted(data["bad_places"], key=lambda r: _seed(r["run"])):
            rows.append([log, str(_seed(row["run"])), f"{row['mean_m']:.3f}", row.get("first_place") or "",
                         labels.get(row["cause"], "") if row.get("cause") else "", row.get("search", "")])
    return _table(["log", "seed", "mean error, m", "went wrong first", "cause",
                   "the search there: scans searched, held; the best candidate that moves the pose"], rows)


def _seed(run: str) -> int:
    """The seed of a saved run's name (``mit-killian_srupf-gm_s7``, ``..._s7_split32``)."""
    return int(re.search(r"_s(\d+)(_|$)", run).group(1))


TAIL_CAUSE_LOGS = [("MIT Killian", "closure_diagnostics_killian.json"),
                   ("MIT Killian, XLA code split 32", "closure_diagnostics_killian_split32.json"),
                   ("MIT Killian", "closure_diagnostics_killian_amd.json"),
                   ("infinite corridor (high)", "closure_diagnostics_corridor.json"),
                   ("Freiburg campus (high)", "closure_diagnostics_campus.json"),
                   ("Orebro (high)", "closure_diagnostics_orebro.json"),
                   ("CSAIL (high)", "closure_diagnostics_csail.json"),
                   ("Intel (high)", "closure_diagnostics_intel.json"),
                   ("Seattle (high)", "closure_diagnostics_seattle.json"),
                   ("FR101 (high)", "closure_diagnostics_fr101.json"),
                   ("Edmonton (high)", "closure_diagnostics_edmonton.json")]
"""The rows of the causes table: (log, diagnostics JSON), each made on the CPU that ran its runs."""
BOUNDED_CAUSE_LOGS = [("MIT Killian", "closure_diagnostics_killian_first.json")]
"""The causes table's rows with the first closure bounded (``closure.first_drift`` 0.02)."""

TRIGGER_CAUSE_LOGS = [("MIT Killian", "closure_diagnostics_killian_trigger.json")]
"""The causes table's rows with the search triggered under 0.35 (``closure.trigger``)."""

TRIGGER_RATIO_CAUSE_LOGS = [("MIT Killian", "closure_diagnostics_killian_trigger_ratio.json")]
"""The causes table's rows with the trigger raised to 0.8 times the recent matches'
mean score (``closure.trigger_ratio``, the default)."""


def _cpu(data: dict) -> str:
    """The CPU a diagnostics file names, ``AMD EPYC 25/1``."""
    cpu = data["machine"]["cpu"].replace("(R)", "").replace(" Processor", "")
    return f"{cpu} {data['machine'].get('cpu_family_model', '?')}"


def tail_causes_table(logs: list[tuple[str, str]] = TAIL_CAUSE_LOGS) -> str:
    """Per log and CPU (``logs``: rows as :data:`TAIL_CAUSE_LOGS`), the seeds over
    twice the median seed and the decision at the first place each went wrong
    (``closure_diagnostics.tail_causes``)."""
    labels = load(logs[0][1])["tail_causes"]["labels"]
    rows = []
    for log, name in logs:
        data = load(name)
        tail = data["tail_causes"]
        seeds = sorted(_seed(Path(run).stem) for run in data["runs"])
        worst = max(data["bad_places"], key=lambda row: row["mean_m"])
        rows.append([log, _cpu(data), f"{seeds[0]}-{seeds[-1]}", f"{tail['median_m']:.3f}",
                     f"{worst['mean_m']:.3f} ({_seed(worst['run'])})", str(len(tail["runs"])),
                     *(str(tail["counts"][key]) for key in labels)])
    return _table(["log", "CPU", "seeds", "median seed, m", "worst seed, m (seed)", "seeds over 2x median",
                   *labels.values()], rows)


def tail_causes_machines(logs: list[tuple[str, str]] = TAIL_CAUSE_LOGS) -> dict:
    """The machine line's input for the causes table: every run with the CPU of its row."""
    files = [load(name) for _, name in logs]
    return {"machine": files[0]["machine"], "runs": [{"cpu": _cpu(data)} for data in files for _ in data["runs"]]}


def first_closures(closures: list[dict], rate: float, floor: float) -> list[dict]:
    """Each run's first closure (a closure diagnostics file's ``closures``) with its
    jump over the tracking's own drift since the start, ``jump_m / max(floor, rate *
    travelled_m)`` (``drift_ratio``): ``closure.reach_rate`` and ``closure.jump``, the
    bound ``closure.first_drift`` puts on a first closure at its default."""
    first: dict[str, dict] = {}
    for closure in sorted(closures, key=lambda c: c["scan"]):
        first.setdefault(closure["run"], closure)
    return [{**c, "drift_ratio": c["jump_m"] / max(floor, rate * c["travelled_m"])} for c in first.values()]


def first_closure_table() -> str:
    """Per row of the causes table, the runs' first closures by verdict: how many, the
    largest jump over the tracking's drift since the start (``drift_ratio``), and the
    runs and scans where it exceeds 1."""
    from jaxslam.grid.types import ClosureParams

    rate, floor = float(ClosureParams().reach_rate), float(ClosureParams().jump)
    verdicts = {"R": "right", "W": "wrong", "?": "no relation judges"}
    rows = []
    for log, name in TAIL_CAUSE_LOGS:
        data = load(name)
        first = first_closures(data["closures"], rate, floor)
        cells = []
        for key in verdicts:
            group = [c for c in first if c["verdict"] == key]
            over = [f"seed {_seed(c['run'])}, scan {c['scan']}" for c in group if c["drift_ratio"] > 1]
            if not group:
                cells.append("0")
                continue
            cells.append(f"{len(group)}, {max(c['drift_ratio'] for c in group):.2f}"
                         + (f" ({'; '.join(over)})" if over else ""))
        rows.append([log, _cpu(data), str(len(data["runs"])), *cells])
    return _table(["log", "CPU", "runs", *verdicts.values()], rows)


def paired_arms(runs: list[dict], without: str, with_: str) -> list[dict]:
    """Per log and code split, two variants of one filter run on the same seeds
    (``filter`` ``srupf-gm[without]`` and ``srupf-gm[with_]``): each arm's median
    seed, worst seed (and its seed), count of seeds over twice the median seed and
    worst relation, and the seeds whose mean differs between the arms, as
    ``(seed, without's mean, with_'s mean)``. Seeds run in one arm only are left out,
    and a log and split that only one arm ran."""
    arms: dict[tuple, dict[str, dict[int, dict]]] = collections.defaultdict(lambda: {without: {}, with_: {}})
    for run in runs:
        variant = run["filter"].partition("[")[2].rstrip("]")
        if variant in (without, with_) and "mean_m" in run:
            arms[(run["log"], run.get("code_split"))][variant][run["seed"]] = run
    rows = []
    for (log, split), arm in sorted(arms.items(), key=lambda item: (item[0][0], item[0][1] or 0)):
        seeds = sorted(set(arm[without]) & set(arm[with_]))
        if not seeds:
            continue
        row = {"log": log, "code_split": split, "seeds": len(seeds)}
        for variant in (without, with_):
            means = {seed: arm[variant][seed]["mean_m"] for seed in seeds}
            median = statistics.median(means.values())
            worst = max(seeds, key=lambda seed: means[seed])
            row[variant] = {"median_m": median, "worst_m": means[worst], "worst_seed": worst,
                            "over_2x": sum(m > 2 * median for m in means.values()),
                            "worst_max_m": max(arm[variant][seed]["max_m"] for seed in seeds)}
        row["changed"] = [(seed, arm[without][seed]["mean_m"], arm[with_][seed]["mean_m"]) for seed in seeds
                          if arm[without][seed]["mean_m"] != arm[with_][seed]["mean_m"]]
        rows.append(row)
    return rows


def paired_table(name: str, *arms: tuple[str, str]) -> str:
    """``srupf-gm`` under two or more settings, the same seeds and program (``name``; each
    arm ``(variant, label)``, the runs ``srupf-gm[variant]``), per log and XLA code split
    (:func:`paired_arms`, each arm against the first); the last column lists the seeds
    whose mean differs between any two arms, with each arm's mean."""
    from jaxslam.runtime.compiler import OPTIONS

    fixed = str(OPTIONS["xla_cpu_parallel_codegen_split_count"])
    (base, base_label), others = arms[0], arms[1:]
    runs = load(name)["runs"]
    pairs = [{(row["log"], row["code_split"]): row for row in paired_arms(runs, base, variant)}
             for variant, _ in others]
    rows = []
    for key, first in pairs[0].items():
        if not all(key in pair for pair in pairs):
            continue
        cells = []
        for variant, pair in zip([base, *(variant for variant, _ in others)], [pairs[0], *pairs]):
            arm = pair[key][variant]
            cells.append(f"{arm['median_m']:.3f}, {arm['worst_m']:.3f} (seed {arm['worst_seed']}), "
                         f"{arm['over_2x']}, {arm['worst_max_m']:.2f} m")
        means = {}
        for index, pair in enumerate(pairs):
            for seed, a, b in pair[key]["changed"]:
                means.setdefault(seed, {0: a})[index + 1] = b
        changed = []
        for seed in sorted(means):
            values = [means[seed].get(index, means[seed][0]) for index in range(len(arms))]
            changed.append(f"{seed}: " + " to ".join(f"{value:.3f}" for value in values))
        log, split = key
        rows.append([LOG_NAMES.get(log, log), str(split or fixed), str(first["seeds"]), *cells,
                     "; ".join(changed) or "none"])
    heads = [f"{base_label}: median, worst seed, over 2x median, worst relation",
             *(f"{label}: the same" for _, label in others)]
    return _table(["log", "code split", "seeds", *heads, "seeds that changed (mean, m)"], rows)


def _tail(cell: dict) -> str:
    return f"{cell['tail_share']:.0%}, {cell['worst_max_m']:.2f} m"


def comparison_table(with_name: str, without_name: str, with_label: str, without_label: str,
                     tail: bool = False) -> str:
    """``srupf-gm`` with and without one part, next to GMapping C++, on the logs both ran;
    ``tail``: each arm's tail as well (the share of seeds over twice the median seed, and
    the worst relation, :func:`grid_robustness.summarize`)."""
    with_cells = _cells(load(with_name)["summary"])
    without_cells = _cells(load(without_name)["summary"])
    cpp = _cells(load("robustness_suite.json")["summary"])
    rows = []
    for log in RAW_LOGS + PERTURBED_LOGS:
        a, b = with_cells.get((log, "srupf-gm")), without_cells.get((log, "srupf-gm"))
        if a is None or b is None:
            continue
        arms = [_mean_worst(a), _tail(a), _mean_worst(b), _tail(b)] if tail else [_mean_worst(a), _mean_worst(b)]
        rows.append([LOG_NAMES.get(log, log), *arms, _mean_worst(cpp.get((log, "gmapping-cpp")))])
    labels = ([with_label, "tail, worst relation", without_label, "tail, worst relation"] if tail
              else [with_label, without_label])
    return _table(["log", *labels, "GMapping C++"], rows)


def closure_search_cost_table() -> str:
    """The search's candidate scores, block sums against per-beam gathers, one core."""
    rows = [[str(r["beams"]), f"{r['candidates']:,}", f"{r['gathers_ms']:.1f} ms", f"{r['blocks_ms']:.1f} ms",
             f"{r['speed_up']:.1f}x", r["identical"]] for r in load("closure_search_cost.json")["rows"]]
    return _table(["beams scored", "candidates", "gathers", "block sums", "speed-up", "identical scores"], rows)


def compile_cost_table() -> str:
    """SRUPF-GM's chunk runner compiled in fresh processes, one core, cache off: CPU
    seconds of each stage (CPU time, since the machine was shared), the old tree
    (every hill climb written out) against today's (the climbs as phases of one loop)."""
    data = load("compile_cost.json")
    label = {"old": "each climb written out", "new": "the climbs as phases of one climb (today)"}
    rows = [[label[r["tree"]], f"{r['xla_cpu_median_s']:.1f} s", f"{r['trace_cpu_median_s']:.1f} s",
             f"{r['lower_cpu_median_s']:.1f} s", str(r["rounds"])] for r in data["summary"]]
    return _table(["program", "XLA compilation (CPU, median)", "tracing", "lowering to MLIR", "rounds"], rows)


def path_agreement_table() -> str:
    """MIT CSAIL: each run's path against GMapping C++'s seed 2, median (largest) distance, m."""
    data = load("path_agreement_csail.json")
    groups: dict[str, dict[int, str]] = {}
    for r in data["rows"]:
        cell = "reference" if r["median_m"] == 0.0 else f"{r['median_m']:.2f} ({r['max_m']:.1f})"
        groups.setdefault(r["group"], {})[r["seed"]] = cell
    seeds = sorted({r["seed"] for r in data["rows"]})
    rows = [[group] + [cells.get(s, "") for s in seeds] for group, cells in groups.items()]
    return _table(["runs on MIT CSAIL"] + [f"seed {s}" for s in seeds], rows)


def headline_table() -> str:
    """The README's table: accuracy over the suite, speed in one run, memory on MIT Killian."""
    cells = _cells(load("robustness_suite.json")["summary"])
    counts = robustness_counts()
    speed = _speed_rows()
    scale = {r["dataset"]: r for r in load("grid_scale.json")["runs"]}
    big = load("grid_scale_killian_1000.json")
    suite = "[robustness suite](benchmarks/grid_robustness.py)"
    e2e = "[end to end](benchmarks/end_to_end.py)"
    rows = []
    for log in RAW_LOGS:
        a, b = cells[(log, "srupf-gm")], cells[(log, "gmapping-cpp")]
        rows.append([f"{LOG_NAMES[log]}: relations error, mean (worst seed)", _mean_worst(a, False) + " m",
                     _mean_worst(b, False) + " m", suite])
    pert_ours = [cells[(log, "srupf-gm")] for log in PERTURBED_LOGS]
    pert_cpp = [cells[(log, "gmapping-cpp")] for log in PERTURBED_LOGS]
    rows.append([f"{len(PERTURBED_LOGS)} perturbed logs: median of the logs' means (worst seed of any log)",
                 f"{statistics.median(c['mean_of_means_m'] for c in pert_ours):.3f} "
                 f"({max(c['worst_mean_m'] for c in pert_ours):.3f}) m",
                 f"{statistics.median(c['mean_of_means_m'] for c in pert_cpp):.3f} "
                 f"({max(c['worst_mean_m'] for c in pert_cpp):.3f}) m", suite])
    rows.append([f"logs where the mean / worst seed is at or under GMapping C++'s",
                 f"{counts['mean_at_or_under']} / {counts['worst_at_or_under']} of {counts['logs']}", "", suite])
    for case in ("intel-srupf-30", "killian-srupf-30"):
        r = speed[case]
        rows.append([f"{SPEED_CASES[case]}: whole process, cold / warm cache",
                     f"{r['cold_process_s']:.1f} / {r['warm_process_s']:.1f} s", f"{r['gmapping_process_s']:.1f} s",
                     e2e])
    k = scale["mit-killian"]
    rows.append([f"MIT Killian ({k['scans']} scans), peak memory of the process, 30 / 1000 particles",
                 f"{k['peak_rss_mb'] / 1000:.2f} / {big['peak_rss_gb']:.2f} GB", "",
                 "[scale](benchmarks/grid_scale.py)"])
    return _table(["", "jaxslam `srupf-gm`", "GMapping C++", "reproduce"], rows)


LOCALIZATION_LOGS = {"intel": "Intel", "fr079": "FR079"}


def _localization_files() -> list[dict]:
    return [load("localization.json"), load("localization_fr079.json")]


def localization_tracking_table() -> str:
    """Tracking from the known start pose in a map built from the corrected poses."""
    rows = []
    for data in _localization_files():
        for r in data["tracking"]:
            rows.append([LOCALIZATION_LOGS.get(r["log"], r["log"]), str(r["seed"]), f"{r['mean_m']:.3f} m",
                         f"{r['max_m']:.2f} m", f"{r['mean_deg']:.2f} deg", str(r["over_0_5m"]),
                         f"{r['particles_mean']:.0f} of {data['tracking_particles']}", f"{r['scans_per_s']:.0f}"])
    return _table(["log", "seed", "mean error", "largest error", "mean heading error", "scans over 0.5 m",
                   "particles in use", "scans/s"], rows)


def _rate(value: float) -> str:
    return f"{value:.1f}" if value < 10 else f"{value:.0f}"


def localization_global_table() -> str:
    """Global localization from a uniform start over the map's free space, per particle count."""
    rows = []
    for data in _localization_files():
        process = {(r["log"], r["particles"]): r for r in data.get("process_timing", [])}
        counts = sorted({(r["log"], r["particles"]) for r in data["global"]}, key=lambda k: (k[0], k[1]))
        for log, particles in counts:
            runs = [r for r in data["global"] if (r["log"], r["particles"]) == (log, particles)]
            good = [r for r in runs if r["success"]]
            whole = process.get((log, particles))
            rows.append([
                LOCALIZATION_LOGS.get(log, log), f"{particles:,}", f"{len(good)} of {len(runs)}",
                f"{statistics.median(r['converged_scan'] for r in good):.0f}" if good else "",
                f"{statistics.median(r['converged_after_s'] for r in good):.0f} s" if good else "",
                _rate(statistics.mean(r['scans_per_s'] for r in runs)),
                _rate(statistics.mean(r['scans_per_s_with_compile'] for r in runs)),
                _rate(whole['scans_per_s_process']) if whole else ""])
    return _table(["log", "capacity", "converged and stayed", "median from scan", "median log time",
                   "scans/s, filter loop", "scans/s, with compilation", "scans/s, whole process (seed 0)"], rows)


def localization_global_runs_table() -> str:
    """Every global localization run."""
    rows = []
    for data in _localization_files():
        for r in data["global"]:
            rows.append([LOCALIZATION_LOGS.get(r["log"], r["log"]), f"{r['particles']:,}", str(r["seed"]),
                         "yes" if r["success"] else "no",
                         "" if r["converged_scan"] is None else str(r["converged_scan"]),
                         "" if r["converged_after_s"] is None else f"{r['converged_after_s']:.0f} s",
                         f"{r['final_err_m']:.2f} m", f"{r['wall_s']:.1f} s"])
    return _table(["log", "capacity", "seed", "converged and stayed", "from scan", "log time", "final error",
                   "filter loop"], rows)


def localization_kidnap_table() -> str:
    """Recovery from a kidnapping: the log cut and continued elsewhere."""
    rows = []
    for data in _localization_files():
        for r in data.get("kidnap", []):
            rows.append([LOCALIZATION_LOGS.get(r["log"], r["log"]), str(r["seed"]),
                         f"{r['cut_scan']} -> {r['resume_scan']}", f"{r['jump_m']:.1f} m",
                         f"{r['before_mean_m']:.3f} m", "yes" if r["recovered"] else "no",
                         "" if r["recovery_scans"] is None else str(r["recovery_scans"]),
                         "" if r["recovery_s"] is None else f"{r['recovery_s']:.0f} s",
                         str(r["injections_after"])])
    return _table(["log", "seed", "scans (cut -> resumed)", "jump", "error before", "recovered", "scans after",
                   "log time after", "injections after"], rows)


def localization_amcl_table() -> str:
    """jaxslam and ROS AMCL, each a whole process, on the same maps and logs."""
    data = load("localization_amcl.json")
    rows = []
    keys = []
    for r in data["amcl"]:
        key = (r["log"], r["mode"], r["particles"], r["localizer"])
        if key not in keys:
            keys.append(key)
    for log, mode, particles, localizer in keys:
        runs = [r for r in data["amcl"] if (r["log"], r["mode"], r["particles"], r["localizer"]) ==
                (log, mode, particles, localizer)]
        good = [r for r in runs if r["success"]]
        rows.append([LOCALIZATION_LOGS.get(log, log), mode, f"{particles:,}", localizer,
                     f"{len(good)} of {len(runs)}", f"{statistics.median(r['median_m'] for r in runs):.3f} m",
                     f"{statistics.mean(r['particles_mean'] for r in runs):.0f}",
                     f"{statistics.mean(r['per_update_ms'] for r in runs):.2f} ms",
                     f"{statistics.mean(r['process_s'] for r in runs):.1f} s"])
    return _table(["log", "start", "capacity", "localizer", "converged and stayed", "median error",
                   "particles in use", "per update", "whole process"], rows)


TABLES = {
    "robustness": robustness_table, "speed": speed_table, "landmark": landmark_table, "scale": scale_table,
    "feature_cost": feature_cost_table, "closure_search_cost": closure_search_cost_table,
    "compile_cost": compile_cost_table, "first_run": first_run_table, "continue_map": continue_map_table,
    "continue_localize": continue_localize_table, "other_cpu": other_cpu_table,
    "tail_places": tail_places_table, "tail_causes": tail_causes_table,
    "first_closures": first_closure_table,
    "path_agreement": path_agreement_table,
    "localization_tracking": localization_tracking_table, "localization_global": localization_global_table,
    "localization_global_runs": localization_global_runs_table, "localization_kidnap": localization_kidnap_table,
    "localization_amcl": localization_amcl_table,
    "coarse_stage": lambda: comparison_table("robustness_coarse_stage.json", "robustness_no_coarse_stage.json",
                                             "with the coarse stage", "without"),
    "recovery": lambda: comparison_table("robustness_recovery.json", "robustness_no_recovery.json",
                                         "with the recovery and wider proposals", "without"),
    "map_bound": lambda: comparison_table("robustness_map_bound.json", "robustness_no_map_bound.json",
                                          "with the map bound", "without", tail=True),
    "first_drift": lambda: paired_table("robustness_first_drift.json", ("off", "off"), ("first", "0.02")),
    "tail_causes_bounded": lambda: tail_causes_table(BOUNDED_CAUSE_LOGS),
    "trigger": lambda: paired_table("robustness_trigger.json", ("t25", "0.25"), ("t35", "0.35")),
    "tail_causes_trigger": lambda: tail_causes_table(TRIGGER_CAUSE_LOGS),
    "trigger_ratio": lambda: paired_table("robustness_trigger_ratio.json", ("r0", "fixed at 0.25"), ("r70", "ratio 0.7"),
                                             ("r80", "ratio 0.8")),
    "tail_causes_trigger_ratio": lambda: tail_causes_table(TRIGGER_RATIO_CAUSE_LOGS),
    "tail_refusals": tail_refusals_table,
    "confirm_gain": lambda: paired_table("robustness_confirm_gain.json", ("r80", "the defaults"),
                                         ("cg12", "confirm_gain 1.2")),
}
MACHINES = {"robustness": "robustness_suite.json", "speed": "end_to_end.json", "landmark": "erb_particles.json",
            "scale": "grid_scale.json", "feature_cost": "feature_cost_intel.json",
            "closure_search_cost": "closure_search_cost.json", "compile_cost": "compile_cost.json",
            "first_run": "end_to_end_first_run.json", "continue_map": "continue_map.json",
            "continue_localize": "continue_map.json", "other_cpu": "robustness_other_cpu.json",
            "tail_places": "closure_diagnostics_killian.json", "tail_causes": tail_causes_machines,
            "first_closures": tail_causes_machines,
            "path_agreement": "path_agreement_csail.json", "localization_tracking": "localization.json",
            "localization_global": "localization.json", "localization_global_runs": "localization.json",
            "localization_kidnap": "localization.json", "localization_amcl": "localization_amcl.json",
            "coarse_stage": "robustness_coarse_stage.json",
            "recovery": "robustness_recovery.json", "map_bound": "robustness_map_bound.json",
            "first_drift": "robustness_first_drift.json",
            "tail_causes_bounded": lambda: tail_causes_machines(BOUNDED_CAUSE_LOGS),
            "trigger": "robustness_trigger.json",
            "tail_causes_trigger": lambda: tail_causes_machines(TRIGGER_CAUSE_LOGS),
            "trigger_ratio": "robustness_trigger_ratio.json",
            "tail_causes_trigger_ratio": lambda: tail_causes_machines(TRIGGER_RATIO_CAUSE_LOGS),
            "tail_refusals": "closure_diagnostics_refusals_killian.json",
            "confirm_gain": "robustness_confirm_gain.json"}


def write_all(folder: Path = GENERATED) -> list[Path]:
    """Write every table as ``folder/NAME.md`` (the table, then the machine it was measured on)."""
    folder.mkdir(parents=True, exist_ok=True)
    written = []
    for name, make in TABLES.items():
        path = folder / f"{name}.md"
        source = MACHINES[name]
        data = source() if callable(source) else load(source)
        text = make() + "\n" + machine_line(data) + "\n"
        if not path.exists() or path.read_text() != text:
            path.write_text(text)
        written.append(path)
    return written


if __name__ == "__main__":
    for p in write_all():
        print("wrote", p.relative_to(ROOT))
    print()
    print(headline_table())
