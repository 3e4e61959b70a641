"""What a run reports: the few lines ``jaxslam run`` prints at its end and ``jaxslam
evaluate``'s score of a TUM trajectory.

:func:`report` writes the lines from the run's summary and its folder; :func:`evaluate`
scores a trajectory by a relations file or by GPS.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from jaxslam.app.errors import RunError
from jaxslam.datasets.paths import DatasetNotFoundError
from jaxslam.datasets.registry import DATASETS, lookup

# The files of an output folder, in the order the report names them.
OUTPUT_FILES = ("summary.json", "trajectory.tum", "landmarks.csv", "map.pgm", "map.yaml", "map.png",
                "trajectory.png", "map_trajectory.png", "health.png", "arrays.npz", "run.json", "checkpoint.npz")


def _number(value, digits: int) -> str:
    """``value`` with ``digits`` decimals; ``n/a`` for None or NaN."""
    if value is None or not np.isfinite(value):
        return "n/a"
    return f"{value:.{digits}f}"


def _score_rows(summary: dict[str, Any]) -> list[tuple[str, str]]:
    from jaxslam.metrics.scoring import matched_counts

    counted = matched_counts(summary)
    rows = []
    if "trans_err_mean_m" in summary:
        scored, total, _ = counted
        rows.append(("relations error", f"{_number(summary['trans_err_mean_m'], 3)} m mean, "
                     f"{_number(summary['trans_err_median_m'], 3)} m median, "
                     f"{_number(summary['trans_err_max_m'], 3)} m max ({summary['n_trans_err_over_0_5m']} over "
                     f"0.5 m), {_number(summary['rot_err_mean_deg'], 2)} deg mean; {scored} of {total} scored"))
    if "gps_mean_m" in summary:
        scored, total, _ = counted
        rows.append(("GPS error", f"{_number(summary['gps_mean_m'], 2)} m mean, {_number(summary['gps_rms_m'], 2)} "
                     f"m RMS, {_number(summary['gps_max_m'], 2)} m max; {scored} of {total} fixes used"))
    if "pos_err_mean_m" in summary:
        text = (f"{_number(summary['pos_err_mean_m'], 3)} m mean, {_number(summary['pos_err_rms_m'], 3)} m RMS, "
                f"{_number(summary['pos_err_max_m'], 3)} m max against the ground truth")
        if "nees_mean" in summary:
            text += f"; pose NEES {_number(summary['nees_mean'], 2)} (consistent: {summary['nees_expected']:g})"
        rows.append(("position error", text))
    return rows or [("score", "none: no reference for this data (relations, GPS or ground truth)")]


def report(summary: dict[str, Any], out: str | Path) -> str:
    """A few lines for the terminal at the end of a run: what ran, its score, its times
    and where its files are (the whole summary is ``out/summary.json``).

    Args:
        summary: what :func:`jaxslam.app.runs.run` returned.
        out: the output folder.
    """
    out = Path(out)
    if "keyframes" in summary:  # laser data
        steps = (f"{summary['scans']} scans, {summary['keyframes']} keyframes, {summary['resamplings']} "
                 f"resamplings, {summary.get('closures', 0)} loop closures")
        if summary.get("closures_undone"):
            steps += f" ({summary['closures_undone']} undone)"
        rate, unit = summary.get("keyframes_per_s"), "keyframes/s"
    else:
        steps = f"{summary['steps']} steps, {summary['resamplings']} resamplings, {summary['landmarks']} landmarks"
        rate, unit = summary.get("steps_per_s"), "steps/s"
    rows = [("filter", steps), *_score_rows(summary)]
    if not summary.get("finite", True):
        rows.append(("warning", "the trajectory has non-finite poses"))
    repairs = {k: v for k, v in summary.get("repairs", {}).items() if v}
    if repairs:
        rows.append(("repaired", ", ".join(f"{v} {k.removeprefix('num_').replace('_', ' ')}"
                                           for k, v in repairs.items())))
    counts = summary.get("compilations", {})
    compiled = (f" ({counts['compiled']} programs compiled, {counts['cache_hits']} loaded from the cache)"
                if "compiled" in counts else "")
    rows.append(("time", f"{_number(summary.get('total_s'), 1)} s in all: compilation "
                 f"{_number(summary['compile_s'], 1)} s{compiled}, filter loop {_number(summary['wall_s'], 2)} s "
                 f"({_number(rate, 0)} {unit})"))
    present = {p.name for p in out.iterdir() if p.is_file()} if out.is_dir() else set()
    files = [name for name in OUTPUT_FILES if name in present]
    files += sorted(name for name in present - set(OUTPUT_FILES) if not name.endswith(".tmp"))
    rows.append(("files", f"{out}: {', '.join(files)}"))
    if summary.get("rerun"):
        rows.append(("recording", str(summary["rerun"])))
    width = max(len(label) for label, _ in rows)
    head = f"{summary['algorithm']} on {summary['dataset']}, {summary['particles']} particles, seed {summary['seed']}"
    return "\n".join([head, *(f"  {label:<{width}}  {text}" for label, text in rows)])


def evaluate(trajectory: Path, relations: str | None = None, gps: str | None = None) -> dict[str, Any]:
    """Score a TUM trajectory by a relations file (or dataset name) or by GPS."""
    from jaxslam.metrics.trajectory_io import read_tum

    if not Path(trajectory).exists():
        raise DatasetNotFoundError(f"trajectory file {str(trajectory)!r} does not exist")
    times, poses = read_tum(trajectory)
    if relations is not None:
        from jaxslam.metrics.relations import load_relations, relations_metric

        path = Path(relations)
        if not path.exists():
            try:
                info = lookup(relations)
            except KeyError as err:
                raise RunError(f"{relations!r} is neither a relations file nor a dataset name: {err.args[0]}") from None
            path = info.relations_path()
            if path is None:
                raise RunError(f"dataset {info.name!r} has no relations file")
        scores = relations_metric(load_relations(path), times, poses)
        scores["relations_file"] = str(path)
        return scores
    try:
        info = lookup(gps)
    except KeyError as err:
        raise RunError(f"--gps: {err.args[0]}") from None
    if not info.gps:
        with_gps = ", ".join(name for name, entry in DATASETS.items() if entry.gps)
        raise RunError(f"GPS scoring is available for {with_gps}, not {info.name!r}")
    from jaxslam.datasets.victoria_park import load_gps
    from jaxslam.metrics.gps import gps_error

    fixes = load_gps()
    scores = gps_error(times, poses[:, :2], fixes.times, fixes.xy)
    return {k: v for k, v in scores.items() if k not in ("used", "errors_m")}
