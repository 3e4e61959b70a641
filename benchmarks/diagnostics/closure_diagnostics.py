"""Every loop closure of saved runs, judged right or wrong by the log's relations.

For the runs that ``benchmarks/grid_robustness.py`` keeps (``--work``, default
``/tmp/grid_robustness/TAG/*.npz``, each with the per-scan ``info_track_closed``,
``info_track_score`` and ``info_track_conflict``) this lists each scan ``c`` where the
loop-closure search replaced the tracking's match (:mod:`jaxslam.grid.closure`):

* ``jump``: the position change of the path at ``c`` (m), and ``turn`` (deg);
* ``travelled``: the path length since the previous closure (m), and ``jump`` over it;
* ``score``: the tracking score (fraction of the matched beams) at ``c``, and the mean
  over scans ``c-10 .. c-4`` (``score_before``);
* ``conflict_before``: the share of the local match's beams ending in known free space
  just before ``c``; ``conflict_after``: its largest value over the three scans after
  ``c``, whose local matches start in the closure's frame (what a test at the
  candidate would measure; see :mod:`jaxslam.grid.closure`);
* ``conflict_level``: the log's own level of that share, its mean over the scans from
  :data:`LEVEL_FROM_M` to :data:`LEVEL_TO_M` of path before ``c`` (outdoors far higher
  than indoors: the Freiburg campus 0.15-0.18 in the median scan of a run, MIT Killian
  0.017), to judge ``watch_conflict`` against;
* ``verdict``: with relations (a raw log with benchmark relations), the relations
  from a scan more than 300 scans before ``c`` to one of scans ``c .. c+60`` judge it
  by their translational errors (:func:`jaxslam.metrics.relations.relation_errors`,
  the metric's own): ``R`` (right) if their median ``relation_error_m`` is under 0.5
  m, ``W`` (wrong) otherwise, ``?`` without such relations;
* ``heading_fix_deg`` and ``taken_back`` (with ``--reference``, the corrected log a
  perturbed log was made from): the heading error against the reference that the
  closure's step removed, ``e_c`` with ``e_k = wrap(dtheta_k - dtheta_ref_k)`` the error
  of the increment that ends at scan ``k``, and the share of it that the next
  :data:`TAKEN_BACK_SCANS` scans took back, ``-(e_{c+1} + ... + e_{c+10}) / e_c`` (1: the
  path is back in the frame it had before the closure);
* ``undone_at``: the scan whose watch undid the closure, if one did, and
  ``watch_conflict``: the share of beams in known free space averaged over the scans
  that watched it (up to the undo, else over 5 m of path), which ``closure_undo``
  judges.

Runs that hold ``info_track_undo``: their undos are not listed as
closures, and every measure here is taken on the path as it was tracked (the reported
path takes undone closures back, :func:`jaxslam.grid.undone_closures.take_back`, and
would hide them; :func:`jaxslam.grid.undone_closures.put_back` undoes that).

    python benchmarks/diagnostics/closure_diagnostics.py --log mit-killian --runs '/tmp/grid_robustness/killian/*.npz' \\
        --name closure_diagnostics_killian

Prints the table, writes ``benchmarks/results/NAME.json`` and ``NAME.png`` (the share
after the closure against jump / travelled, by verdict). With ``--log``, a second table
gives each run's relations error with and without the end's judgment of a closure still
watched when the log ended (``end_judgment``;
:func:`jaxslam.grid.undone_closures.judge_at_end`).
A third table says where each run's relations over 1 m lie and which closures were taken
there (``bad_places``, :func:`bad_places`), with the decision behind the first place where
the run went wrong (``cause``, :func:`cause`; where no right closure came, runs that
hold ``info_track_search`` say whether the search ran there and which test refused its
best candidate); ``tail_causes`` counts the causes over the runs in the tail
(:func:`tail_causes`).
"""

from __future__ import annotations

import argparse
import glob
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _common import RESULTS, print_table, write_json  # noqa: E402

BEFORE = 300
"""A relation judges a closure when its earlier scan lies this many scans before it."""
AFTER = 60
"""... and its later scan within this many scans after it."""
def _default_watch() -> float:
    from jaxslam.grid.types import ClosureParams

    return float(ClosureParams().watch)


WATCH_M = _default_watch()
"""Path length over which ``watch_conflict`` averages: the filter's own ``closure.watch``
default, read from :class:`jaxslam.grid.types.ClosureParams` so the two cannot drift apart."""
RIGHT_M = 0.5
"""A right closure's judging relations have a median translational error under this (m)."""
TAKEN_BACK_SCANS = 10
"""Scans after a closure over which ``taken_back`` sums the heading error."""
LEVEL_FROM_M, LEVEL_TO_M = 200.0, 20.0
"""Path before a closure (m) over which ``conflict_level`` averages the share."""
PLACE_WINDOW = 1000
"""Scans per stretch of the log in :func:`bad_places`."""


def heading_taken_back(error: np.ndarray, c: int) -> tuple[float, float]:
    """``(heading_fix_deg, taken_back)`` of a closure at scan ``c`` (module docstring);
    ``error``: :func:`grid_common.heading_errors` of the run against the reference."""
    if c > error.shape[0]:
        return float("nan"), float("nan")
    fix = error[c - 1]  # error[i] is the increment that ends at scan i + 1
    after = error[c:c + TAKEN_BACK_SCANS].sum()
    return float(np.degrees(fix)), float(-after / fix) if fix != 0 else float("nan")


def closures(path: str, relations=None, reference: np.ndarray | None = None) -> list[dict]:
    """The closures of one saved run (see the module docstring); ``reference``: the
    corrected log's poses, for ``heading_fix_deg`` and ``taken_back``."""
    from jaxslam.datasets.geometry import se2_between
    from jaxslam.metrics.relations import relation_errors

    run = np.load(path)
    path_poses, stamps = run["trajectory"], run["scan_times"]
    score, conflict = run["info_track_score"], run["info_track_conflict"]
    closed = np.flatnonzero(run["info_track_closed"]) + 1  # info[i] is scan i + 1
    undo_of: dict[int, int] = {}
    if "info_track_undo" in run.files:  # undos apart, and the path as tracked
        from grid_common import saved_undo
        from jaxslam.grid.undone_closures import put_back

        undo = saved_undo(run)  # the last row: the end's judgment
        undone_at = np.flatnonzero(undo[:, 0] > 0) + 1
        undo_of = {int(b - round(undo[b - 1, 0])): int(b) for b in undone_at}
        closed = np.setdiff1d(closed, undone_at)
        path_poses = put_back(path_poses, np.arange(path_poses.shape[0]), undo)
    length = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(path_poses[:, :2], axis=0).T))])
    if reference is not None:
        from grid_common import heading_errors

        heading_error = heading_errors(path_poses, reference)
    if relations is not None:
        errors = relation_errors(relations, stamps, path_poses)
        first = np.minimum(errors.index1, errors.index2)
        later = np.maximum(errors.index1, errors.index2)
    rows, last = [], 0
    for c in closed:
        step = se2_between(path_poses[c - 1][None], path_poses[c][None])[0]
        travelled = float(length[c - 1] - length[last])
        verdict, error_m = "?", None
        if relations is not None:
            judging = errors.matched & (first < c - BEFORE) & (later >= c) & (later <= c + AFTER)
            if judging.any():
                error_m = float(np.median(errors.trans[judging]))
                verdict = "R" if error_m < RIGHT_M else "W"
        rows.append({
            "run": Path(path).stem, "scan": int(c), "jump_m": float(np.hypot(*step[:2])),
            "turn_deg": float(np.degrees(step[2])), "travelled_m": travelled,
            "jump_per_m": float(np.hypot(*step[:2]) / max(travelled, 1e-9)),
            "score": float(score[c - 1]), "score_before": float(score[max(c - 11, 0):max(c - 4, 1)].mean()),
            "conflict_before": float(conflict[c - 2]), "conflict_after": float(conflict[c:c + 3].max(initial=0.0)),
            "relation_error_m": error_m, "verdict": verdict, "undone_at": undo_of.get(int(c)),
            "watch_conflict": watched_conflict(conflict, length, int(c), undo_of.get(int(c))),
            "conflict_level": conflict_level(conflict, length, int(c)),
        })
        if reference is not None:
            rows[-1]["heading_fix_deg"], rows[-1]["taken_back"] = heading_taken_back(heading_error, int(c))
        last = c
    return rows


def watched_conflict(conflict: np.ndarray, length: np.ndarray, c: int, undone_at: int | None) -> float:
    """The mean share of beams in known free space over the scans that watched the
    closure at scan ``c``: up to its undo, else over the next :data:`WATCH_M` of path
    (the path's length stands in for the odometry distance the filter counts)."""
    end = undone_at if undone_at is not None else int(np.searchsorted(length, length[c] + WATCH_M))
    end = min(end, conflict.shape[0])
    return float(conflict[c:end].mean()) if end > c else float("nan")  # conflict[i] is scan i + 1


def conflict_level(conflict: np.ndarray, length: np.ndarray, c: int) -> float:
    """The mean share of beams in known free space over the scans that lie
    :data:`LEVEL_FROM_M` to :data:`LEVEL_TO_M` of path before scan ``c`` (at least one
    scan; ``conflict[i]`` is scan ``i + 1``)."""
    lo = int(np.searchsorted(length, length[c] - LEVEL_FROM_M))
    hi = max(int(np.searchsorted(length, length[c] - LEVEL_TO_M)), lo + 1)
    return float(conflict[max(lo - 1, 0):max(hi - 1, 1)].mean())


def plot(rows: list[dict], out: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.5))
    for verdict, colour, label in (("R", "tab:green", "right"), ("W", "tab:red", "wrong"), ("?", "0.6", "no relation")):
        pick = [r for r in rows if r["verdict"] == verdict]
        if pick:
            ax.scatter([r["jump_per_m"] for r in pick], [r["conflict_after"] for r in pick], c=colour,
                       label=f"{label} ({len(pick)})", s=28, alpha=0.85, edgecolors="none")
    ax.set_xscale("log")
    ax.set_xlabel("jump / path length since the previous closure")
    ax.set_ylabel("beams ending in known free space, 3 scans after (largest)")
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(out, dpi=120)
    plt.close(fig)


def end_judgment(path: str, relations) -> dict:
    """One run: the relations error of the reported path, and of the same path without
    the end's judgment of a closure still watched when the log ended
    (:func:`jaxslam.grid.undone_closures.judge_at_end`; ``info_track_undo_end``), so that
    what the judgment changed is measured on the run itself."""
    from grid_common import saved_undo
    from jaxslam.grid.undone_closures import put_back
    from jaxslam.metrics.relations import relation_errors

    run = np.load(path)
    poses = run["trajectory"]
    # only the end's row: put back, it leaves the path as the filter reported it without the end's judgment
    rows = saved_undo(run, end_only=True)
    row = {"run": Path(path).stem, "closures": int(np.sum(run["info_track_closed"])),
           "undone_at_end_scans": int(round(rows[-1, 0]))}
    for key, trajectory in (("", poses), ("without_end_", put_back(poses, np.arange(poses.shape[0]), rows))):
        errors = relation_errors(relations, run["scan_times"], trajectory)
        row[f"{key}mean_m"] = float(np.nanmean(errors.trans))
        row[f"{key}max_m"] = float(np.nanmax(errors.trans))
        row[f"{key}over_0.5"] = int(np.sum(errors.matched & (errors.trans > 0.5)))
    return row


def _scan_label(scan: int) -> str:
    return f"{scan // 1000}k" if scan and scan % 1000 == 0 else str(scan)


def bad_places(path: str, relations, closure_rows: list[dict], threshold: float = 1.0,
               window: int = PLACE_WINDOW, top: int = 3) -> dict:
    """Where one run's relations go wrong: the relations over ``threshold`` (m) grouped
    by the ``window``-scan stretches of their two scans (``5k-11k``: from a scan in
    5000-5999 to one in 11000-11999), the ``top`` largest groups, and the closures
    (``scan:verdict``, ``/undone_at``) taken in each group's later stretch. A return that
    went wrong shows as one group from the place first seen to the place of the return;
    a return without a closure there was never searched for, or the search found
    nothing within its reach. ``first_place`` is the earliest of those groups where
    most of the pair's relations are wrong (:data:`FIRST_SHARE`), ``cause`` the
    decision there (:func:`cause`), and ``search``, for runs that hold
    ``info_track_search``, what the search did in its later stretch
    (:func:`search_summary`)."""
    from jaxslam.metrics.relations import match_timestamps, relation_errors

    run = np.load(path)
    stamps = run["scan_times"]
    errors = relation_errors(relations, stamps, run["trajectory"])
    first, _ = match_timestamps(relations.t1, stamps, 1e-6)
    second, _ = match_timestamps(relations.t2, stamps, 1e-6)
    bad = errors.matched & (errors.trans > threshold)
    groups: dict[tuple[int, int], int] = {}
    totals: dict[tuple[int, int], int] = {}
    for a, b, wrong in zip(first[errors.matched] // window, second[errors.matched] // window, bad[errors.matched]):
        key = (int(min(a, b)), int(max(a, b)))
        totals[key] = totals.get(key, 0) + 1
        if wrong:
            groups[key] = groups.get(key, 0) + 1
    name = Path(path).stem

    def there(b: int) -> list[dict]:
        return [r for r in closure_rows if r["run"] == name and b * window <= r["scan"] < (b + 1) * window]

    def label(a: int, b: int, count: int) -> str:
        return f"{_scan_label(a * window)}-{_scan_label(b * window)}: {count}"

    row = {"run": name, "mean_m": float(np.nanmean(errors.trans)), f"over_{threshold:g}m": int(bad.sum()),
           "first_place": None, "cause": None}
    largest = sorted(groups.items(), key=lambda item: -item[1])[:top]
    for rank, ((a, b), count) in enumerate(largest):
        taken = [f"{r['scan']}:{r['verdict']}" + (f"/{r['undone_at']}" if r["undone_at"] is not None else "")
                 for r in there(b)]
        row[f"place_{rank + 1}"] = label(a, b, count)
        row[f"closures_{rank + 1}"] = " ".join(taken) or "none"
    failed = [(b, -count, a) for (a, b), count in largest if count >= FIRST_SHARE * totals[a, b]]
    search = run["info_track_search"] if "info_track_search" in run.files else None
    if failed:
        b, count, a = min(failed)
        row["first_place"] = label(a, b, -count)
        rows = None if search is None else search[max(b * window - 1, 0):(b + 1) * window - 1]
        row["cause"] = cause(a == b, there(b), rows)
        if rows is not None:
            row["search"] = search_summary(rows)
    return row


def _default_jump() -> float:
    from jaxslam.grid.types import ClosureParams

    return float(ClosureParams().jump)


MOVE_M = _default_jump()
"""A candidate moves the pose when it lies at least this far from the local match (m):
the filter's own ``closure.jump``. Nearer ones are the local match found again."""


def best_candidate(search: np.ndarray) -> np.ndarray | None:
    """The ``Info.track_search`` row of the best-scoring candidate the search found
    (rows with kind 1) among those at least :data:`MOVE_M` from the local match, or of
    the best of all where none is; None without a search."""
    searched = np.flatnonzero(search[:, 0] == 1)
    if not searched.size:
        return None
    moving = searched[search[searched, 2] >= MOVE_M]
    pick = moving if moving.size else searched
    return search[pick[np.argmax(search[pick, 1])]]


def refusal_tests() -> tuple[tuple[int, str, str], ...]:
    """The refusal bits of ``Info.track_search`` in the order the tests are judged:
    ``(bit, test, cause)``, the cause a key of :data:`CAUSES`."""
    from jaxslam.grid.closure import REFUSED_ALIAS, REFUSED_GAIN, REFUSED_JUMP, REFUSED_SCORE

    return ((REFUSED_SCORE, "score", "low"), (REFUSED_GAIN, "gain", "flat"), (REFUSED_JUMP, "jump", "far"),
            (REFUSED_ALIAS, "alias", "alias"))


def search_summary(search: np.ndarray) -> str:
    """``Info.track_search`` of a stretch's scans in words: how many scans searched and
    climbed a held candidate, and the best candidate the search found
    (:func:`best_candidate`) with its score (fraction of the matched beams), distance
    from the local match and the tests that refused it (:func:`refusal_tests`)."""
    search = np.asarray(search, np.float64).reshape(-1, 4)
    searched, held = search[:, 0] == 1, search[:, 0] == 2
    text = f"{int(searched.sum())} searched, {int(held.sum())} held"
    best = best_candidate(search)
    if best is not None:
        names = [name for bit, name, _ in refusal_tests() if int(best[3]) & bit]
        text += f"; best {best[1]:.2f} at {best[2]:.1f} m" + (f" ({'+'.join(names)})" if names else " (won)")
    return text


def refusal(search: np.ndarray) -> str:
    """Why a stretch without a right closure had none, from ``Info.track_search`` of its
    scans (:func:`jaxslam.grid.closure.closure_outcome`): ``unsearched`` where no scan
    ran the search, ``unconfirmed`` where a candidate that moves the pose
    (:data:`MOVE_M`) won a scan (and was held) but never ``closure.confirm`` in a row,
    and otherwise the first test, in the order
    score, gain, jump bound, alias, that refused the best candidate the search found
    there (:func:`best_candidate`)."""
    search = np.asarray(search, np.float64).reshape(-1, 4)
    searched = search[:, 0] == 1
    if not searched.any():
        return "unsearched"
    moving = search[:, 2] >= MOVE_M
    if np.any(moving & ((search[:, 0] == 2) | (searched & (search[:, 3] == 0)))):
        return "unconfirmed"
    bits = int(best_candidate(search)[3])
    return next((key for bit, _, key in refusal_tests() if bits & bit), "unconfirmed")


FIRST_SHARE = 0.5
"""One of a run's ``top`` largest groups of wrong relations is a place where the run went
wrong when at least this share of all the relations between its two stretches is wrong;
the first of them (the earliest later stretch) names the run's cause, because the places
after it inherit its error: a return closed onto a stretch that was itself put in the
wrong place is wrong however right its own closure was."""


CAUSES = {
    "wrong": "wrong closure kept",
    "undone": "right closure undone",
    "late": "right closure, late",
    "unjudged": "closure no relation judges",
    "none": "no right closure",
    "unsearched": "no right closure: no search there",
    "unconfirmed": "no right closure: a candidate not confirmed",
    "low": "no right closure: candidates under the minimum score",
    "flat": "no right closure: candidates without the gain",
    "far": "no right closure: candidates past the jump bound",
    "alias": "no right closure: candidates of an undone closure",
    "local": "within one stretch",
}
"""The decisions :func:`cause` names the first place a run went wrong by, with their
labels (``tail_causes`` carries them into the JSON, where the docs' tables read them)."""


def cause(one_stretch: bool, there: list[dict], search: np.ndarray | None = None) -> str:
    """The decision behind a group of wrong relations (a key of :data:`CAUSES`), from the
    closures ``there`` (rows of :func:`closures`) taken in the group's later stretch:
    a group inside one stretch is ``local``; else, in this order, a wrong closure that
    was kept, a right closure that was undone, a right one kept (it came after some of
    the stretch's scans had gone wrong, or fixed only part of it), a closure without a
    relation to judge it, and otherwise no right closure at all: ``none``, or with
    ``search`` (``Info.track_search`` of the stretch's scans) why the search found none
    (:func:`refusal`). A lineage lost at resampling shows here as one of the others:
    the saved run holds the chosen path only."""
    if one_stretch:
        return "local"
    kept = [r["verdict"] for r in there if r["undone_at"] is None]
    undone = [r["verdict"] for r in there if r["undone_at"] is not None]
    if "W" in kept:
        return "wrong"
    if "R" in undone:
        return "undone"
    if "R" in kept:
        return "late"
    if "?" in kept + undone:
        return "unjudged"
    return "none" if search is None else refusal(search)


def tail_causes(places: list[dict], factor: float) -> dict:
    """The count of each cause over the tail: the runs whose mean relations error exceeds
    ``factor`` times the median run's (``grid_robustness.TAIL_FACTOR``), with the median
    and the tail's runs."""
    median = float(np.median([p["mean_m"] for p in places]))
    tail = [p for p in places if p["mean_m"] > factor * median]
    counts = {key: sum(p["cause"] == key for p in tail) for key in CAUSES}
    return {"median_m": median, "factor": factor, "runs": [p["run"] for p in tail], "counts": counts,
            "labels": CAUSES}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", action="append", required=True, help="glob of saved runs (.npz); repeatable")
    ap.add_argument("--log", default=None, help="raw log whose benchmark relations judge the closures, or a "
                    "relations file (a perturbed log's, written by grid_robustness.py into WORK/TAG/logs/)")
    ap.add_argument("--reference", default=None, help="corrected log a perturbed log was made from (name or "
                    "path): adds heading_fix_deg and taken_back")
    ap.add_argument("--window", type=int, default=PLACE_WINDOW, help="scans per stretch of the log in the table "
                    "of where the relations go wrong (a perturbed log of keyframes: a few hundred)")
    ap.add_argument("--name", default="closure_diagnostics")
    args = ap.parse_args(argv)
    reference = None
    if args.reference:
        from jaxslam.datasets.perturb import load_reference_log

        reference = load_reference_log(args.reference).poses

    relations = None
    if args.log:
        from jaxslam.metrics.relations import load_dataset_relations, load_relations

        relations = load_relations(args.log) if Path(args.log).is_file() else load_dataset_relations(args.log)
    paths = sorted({p for pattern in args.runs for p in glob.glob(pattern)})
    if not paths:
        raise SystemExit(f"no runs match {args.runs}")
    rows = [row for p in paths for row in closures(p, relations, reference)]
    print_table(rows, ["run", "scan", "jump_m", "turn_deg", "travelled_m", "jump_per_m", "score_before", "score",
                       "conflict_before", "conflict_after", "relation_error_m", "verdict", "undone_at",
                       "watch_conflict", "conflict_level"] + (["heading_fix_deg", "taken_back"] if reference is not None
                                                              else []))
    summary = {}
    for verdict in ("R", "W", "?"):
        after = np.array([r["conflict_after"] for r in rows if r["verdict"] == verdict])
        if after.size:
            summary[verdict] = {"count": int(after.size), "conflict_after_quartiles": np.percentile(after, [25, 50, 75]).tolist(),
                                "over_0.15": int(np.sum(after > 0.15)), "over_0.10": int(np.sum(after > 0.10))}
    print(summary)
    ends = [end_judgment(p, relations) for p in paths] if relations is not None else []
    if ends:
        print_table(ends, ["run", "closures", "undone_at_end_scans", "mean_m", "max_m", "over_0.5",
                           "without_end_mean_m", "without_end_max_m", "without_end_over_0.5"])
    places = [bad_places(p, relations, rows, window=args.window) for p in paths] if relations is not None else []
    causes = None
    if places:
        print_table(places, list(dict.fromkeys(key for row in places for key in row)))
        from grid_robustness import TAIL_FACTOR

        causes = tail_causes(places, TAIL_FACTOR)
        print(f"tail (over {TAIL_FACTOR:g}x the median run, {causes['median_m']:.3f} m): {len(causes['runs'])} of "
              f"{len(places)} runs; " + ", ".join(f"{key} {n}" for key, n in causes["counts"].items()))
    out = write_json(args.name, {"runs": paths, "log": args.log, "reference": args.reference, "window": args.window,
                                 "closures": rows,
                                 "summary": summary, "end_judgment": ends, "bad_places": places,
                                 "tail_causes": causes})
    name = Path(args.log).stem if args.log and Path(args.log).is_file() else (args.log or "runs")
    plot(rows, RESULTS / f"{args.name}.png", f"{name}: loop closures ({len(paths)} runs)")
    print(f"wrote {out} and {RESULTS / (args.name + '.png')}")


if __name__ == "__main__":
    main()
