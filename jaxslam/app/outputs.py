"""The files of a ``jaxslam run`` output folder, written and redrawn in one place.

* ``summary.json`` (:func:`write_summary`: strict JSON, atomically) and ``run.json``
  (the run's arguments and its ``status``, :func:`marked_run`);
* ``trajectory.tum`` — the estimate in the TUM format;
* landmark runs: ``landmarks.csv`` (id, x, y, covariance);
* grid runs: ``map.pgm`` + ``map.yaml`` (ROS map_server convention) and ``map.png``
  (:func:`jaxslam.grid.export.save_map`), and ``map.npz``, the same map losslessly
  (:func:`jaxslam.grid.mapfile.save_map_npz`, read back by :func:`jaxslam.grid.mapfile.load_map`);
* ``arrays.npz`` — the data the figures are drawn from, so that :func:`replot` (``jaxslam
  plot``) redraws every figure of the folder: ``trajectory.png`` (landmark runs) or
  ``map_trajectory.png`` and ``map.png`` (grid runs), and ``health.png``;
* the live view (:func:`open_live_view`, ``--rerun`` / ``--rerun-spawn``).

Host-side NumPy; matplotlib only inside :func:`replot` (via :mod:`jaxslam.app.plotting`).
"""

from __future__ import annotations

import contextlib
import csv
import json
import os
import shutil
import threading
import zipfile
from pathlib import Path

import numpy as np

from jaxslam.app.errors import RunError
from jaxslam.datasets.paths import DataFormatError, DatasetNotFoundError


def json_default(value):
    """JSON for NumPy scalars and arrays (anything else as its ``str``)."""
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, (np.floating,)):
        return float(value)
    if isinstance(value, np.ndarray):
        return value.tolist()
    return str(value)


def strict_json(value, where: str = "", nonfinite: list | None = None):
    """``value`` as plain JSON data (NumPy scalars and arrays as numbers and lists,
    tuples as lists, anything else but ``None``/``bool``/``str`` as its ``str``), with
    every NaN or infinity replaced by ``None`` and its place (``"a.b[2]"``) appended
    to ``nonfinite``: JSON has no such numbers, and Python's ``NaN``/``Infinity`` are
    not JSON."""
    nonfinite = [] if nonfinite is None else nonfinite
    if isinstance(value, dict):
        return {str(k): strict_json(v, f"{where}.{k}" if where else str(k), nonfinite) for k, v in value.items()}
    if isinstance(value, (list, tuple, np.ndarray)):
        return [strict_json(v, f"{where}[{i}]", nonfinite) for i, v in enumerate(value)]
    if value is None or isinstance(value, (bool, str, np.bool_)):
        return bool(value) if isinstance(value, np.bool_) else value
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        if np.isfinite(value):
            return float(value)
        nonfinite.append(where)
        return None
    return json_default(value)


def write_json(path: Path, payload: dict) -> None:
    """Write strict JSON (:func:`strict_json`: no NaN or infinity) atomically: a
    temporary file, then a rename."""
    tmp = path.with_name(f"{path.name}.{os.getpid()}.tmp")
    tmp.write_text(json.dumps(strict_json(payload), indent=2, allow_nan=False) + "\n")
    os.replace(tmp, path)


def write_summary(path: Path, summary: dict) -> dict:
    """Write ``summary.json`` (:func:`write_json`) and return what it holds: where a
    value was NaN or infinite it holds ``null``, and ``nonfinite_values`` lists those
    places (absent when there were none)."""
    places: list[str] = []
    clean = strict_json(summary, nonfinite=places)
    if places:
        clean["nonfinite_values"] = places
    write_json(path, clean)
    return clean


STAGE_PREFIX = ".jaxslam-partial-"


def prepare_folder(out: Path) -> Path:
    """``out`` if a run can write its folder there, else a ``RunError`` naming it
    (an existing file, a folder or parent that cannot be written). Creates nothing."""
    from jaxslam.app.errors import RunError

    if out.exists() and not out.is_dir():
        raise RunError(f"--out {str(out)!r}: is a file, not a folder")
    existing = out
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    if not existing.is_dir():
        raise RunError(f"--out {str(out)!r}: {str(existing)!r} is a file, not a folder")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise RunError(f"--out {str(out)!r}: the folder {str(existing)!r} is not writable")
    return out


@contextlib.contextmanager
def marked_run(out: Path, run_args: dict):
    """A run's output folder, whole or marked as not.

    Creates ``out`` and writes ``out/run.json`` (``run_args`` with ``status``
    ``"running"``); yields a staging folder inside ``out`` for the run's files. When
    the block ends normally the files are moved into ``out`` (``summary.json`` last)
    and the status becomes ``"complete"``; on Ctrl-C it becomes ``"interrupted"``, on
    an error ``"failed"``, each with a ``reason``, and the staged files are removed
    (the files of an earlier run in ``out`` are left as they were). A checkpoint
    (``--checkpoint-every``) is written to ``out`` directly, so that such a run can be
    continued with ``--resume``.
    """
    from jaxslam.app.interrupts import on_interrupt
    from jaxslam.app.errors import RunError

    try:
        out.mkdir(parents=True, exist_ok=True)
        for stale in out.glob(f"{STAGE_PREFIX}*"):
            shutil.rmtree(stale, ignore_errors=True)
        stage = out / f"{STAGE_PREFIX}{os.getpid()}"
        stage.mkdir()
        _mark(out, run_args, "running")
    except OSError as err:
        raise RunError(f"--out {str(out)!r}: cannot write there: {err.strerror or err}") from None

    def interrupted():
        _mark(out, run_args, "interrupted", "interrupted by the user (SIGINT)")
        shutil.rmtree(stage, ignore_errors=True)

    try:
        with on_interrupt(interrupted):
            yield stage
            names = sorted(p.name for p in stage.iterdir())
            for name in sorted(names, key=lambda n: n == "summary.json"):
                os.replace(stage / name, out / name)
    except KeyboardInterrupt:
        _mark(out, run_args, "interrupted", "interrupted by the user (KeyboardInterrupt)")
        raise
    except BaseException as err:
        text = str(err).strip().splitlines()
        _mark(out, run_args, "failed", f"{type(err).__name__}: {text[0] if text else ''}".rstrip(": "))
        raise
    else:
        _mark(out, run_args, "complete")
    finally:
        shutil.rmtree(stage, ignore_errors=True)


RUN_STATES = ("running", "complete", "interrupted", "failed")
"""The ``status`` of a ``run.json`` (:func:`marked_run`)."""


def _mark(out: Path, run_args: dict, status: str, reason: str | None = None) -> None:
    try:
        write_json(out / "run.json", {**run_args, "status": status, **({"reason": reason} if reason else {})})
    except OSError:
        pass


def write_npz(path: Path, **arrays) -> None:
    """``np.savez_compressed`` at zlib level 1 (NumPy's is level 6), written atomically.

    The file is an ordinary ``.npz`` (``np.load`` reads it). Level 1 writes a large
    float32 map about twice as fast as level 6, for a file less than twice as large.
    """
    path = Path(path)
    partial = path.with_name(f"{path.name}.{os.getpid()}.tmp")
    try:
        with zipfile.ZipFile(partial, "w", zipfile.ZIP_DEFLATED, compresslevel=1) as archive:
            for name, value in arrays.items():
                with archive.open(f"{name}.npy", "w", force_zip64=True) as member:
                    np.lib.format.write_array(member, np.asanyarray(value), allow_pickle=False)
        os.replace(partial, path)
    finally:
        partial.unlink(missing_ok=True)


def landmark_arrays(result, title: str, reference_xy, reference_label: str, true_landmarks) -> dict:
    """What ``arrays.npz`` of a landmark run holds (the figures are drawn from it).

    Args:
        result: a :class:`jaxslam.feature.experiment.LandmarkSlamResult`.
        title: the figures' title.
        reference_xy: ``(R, 2)`` reference positions drawn with the trajectory, or None.
        reference_label: their legend label.
        true_landmarks: ``(M, 2)`` true landmark positions, or None.
    """
    return dict(
        kind="landmark", times=result.times, trajectory=result.trajectory,
        landmark_means=result.landmark_means, landmark_covs=result.landmark_covs,
        reference_xy=reference_xy if reference_xy is not None else np.zeros((0, 2)),
        reference_label=reference_label,
        true_landmarks=true_landmarks if true_landmarks is not None else np.zeros((0, 2)),
        ess=result.info["ess"], resampled=result.info["resampled"], particles=result.particles,
        weight_variance=result.info.get("weight_variance", np.zeros(0)),
        title=title,
    )


def write_landmark_outputs(out: Path, result, arrays: dict, comment: str) -> None:
    """``trajectory.tum`` (``comment``: its header comment), ``landmarks.csv`` and
    ``arrays.npz`` (:func:`landmark_arrays`) of a landmark run."""
    write_trajectory(out, result.times, result.trajectory, comment)
    with open(out / "landmarks.csv", "w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(["id", "x_m", "y_m", "cov_xx", "cov_xy", "cov_yy"])
        for i, (m, c) in enumerate(zip(result.landmark_means, result.landmark_covs)):
            writer.writerow([i, f"{m[0]:.4f}", f"{m[1]:.4f}", f"{c[0, 0]:.6g}", f"{c[0, 1]:.6g}", f"{c[1, 1]:.6g}"])
    write_npz(out / "arrays.npz", **arrays)


def write_trajectory(out: Path, times, trajectory, comment: str) -> None:
    """``trajectory.tum``."""
    from jaxslam.metrics.trajectory_io import write_tum

    write_tum(out / "trajectory.tum", times, trajectory, comment=comment)


def grid_arrays(result, title: str) -> dict:
    """What ``arrays.npz`` of a grid run (a :class:`jaxslam.grid.experiment.GridSlamResult`)
    holds (the figures are drawn from it)."""
    return dict(
        kind="laser", times=result.scan_times, trajectory=result.trajectory,
        log_odds=result.map_log_odds, resolution=result.resolution, origin=np.asarray(result.origin),
        ess=result.info["ess"], resampled=result.info["resampled"], particles=result.particles,
        title=title,
    )


def write_grid_outputs(out: Path, result, arrays: dict, comment: str) -> None:
    """``trajectory.tum`` (``comment``: its header comment), ``map.pgm``, ``map.yaml``,
    ``map.png``, ``map.npz`` and ``arrays.npz`` (:func:`grid_arrays`) of a grid run."""
    from jaxslam.grid.export import save_map
    from jaxslam.grid.mapfile import save_map_npz

    write_trajectory(out, result.scan_times, result.trajectory, comment)
    save_map(out, result.map_log_odds, result.resolution, result.origin, name="map", trajectory=result.trajectory)
    layout = getattr(getattr(result, "config", None), "layout", None)
    save_map_npz(out / "map.npz", result.map_log_odds, result.resolution, result.origin,
                 log_odds_unit=(result.params or {}).get("map.log_odds_unit"), tile=getattr(layout, "tile", None),
                 pose=result.trajectory[-1])
    write_npz(out / "arrays.npz", **arrays)


def write_with_figures(out: Path, write_files, arrays: dict | None) -> None:
    """``write_files()`` on a thread while the figures are drawn from ``arrays``
    (:func:`replot`; None: no figures); any error of either is raised once both ended.

    The files' zlib compression and NumPy work release the GIL, the figures mostly hold
    it, so the two overlap: for a large map the two together take little more than
    the longer of them."""
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="jaxslam-write") as pool:
        files = pool.submit(write_files)
        if arrays is not None:
            replot(out, arrays)
        files.result()


def open_live_view(rerun_path, rerun_spawn: bool, name: str):
    """The live view of a run (a :class:`jaxslam.viz.rerun_log.RerunLog` recording to
    ``rerun_path`` or to a spawned viewer), None without either, or a RunError naming
    the install command when rerun is missing."""
    if rerun_path is None and not rerun_spawn:
        return None
    try:
        from jaxslam.viz.rerun_log import RerunLog

        return RerunLog(rerun_path, spawn=rerun_spawn, name=f"jaxslam {name}")
    except ImportError as err:
        raise RunError(f"--rerun/--rerun-spawn: {err}") from None


def prefetch_plotting() -> threading.Thread:
    """Import matplotlib and :mod:`jaxslam.app.plotting` on a background thread.

    Importing matplotlib takes about a second, as long as the filter loop of a short
    run; a run starts this before its filter, so that the import overlaps the loop
    (XLA releases the GIL while it computes) and the figures at the end need not wait
    for it. :func:`replot` imports the module as usual (Python's import lock makes it
    wait for an import under way)."""

    def load():
        import jaxslam.app.plotting  # noqa: F401

    thread = threading.Thread(target=load, name="jaxslam-prefetch-plotting", daemon=True)
    thread.start()
    return thread


def replot(folder: str | Path, arrays: dict | None = None) -> list[Path]:
    """Draw the figures of an output folder from its ``arrays.npz``, or from ``arrays``
    (what :func:`grid_arrays` or :func:`landmark_arrays` gave; a run draws its figures
    from memory while the file is written).

    From the file, a grid run's ``map.png`` is redrawn too (the same pixels); a run
    writes that one with the map files (:func:`write_grid_outputs`)."""
    from jaxslam.app import plotting

    folder = Path(folder)
    if arrays is not None:
        data = {name: np.asarray(value) for name, value in arrays.items()}
    else:
        arrays_path = folder / "arrays.npz"
        if not arrays_path.exists():
            raise DatasetNotFoundError(
                f"{str(arrays_path)!r} not found: is {str(folder)!r} a `jaxslam run` output folder?")
        try:
            data = np.load(arrays_path, allow_pickle=False)
        except (OSError, ValueError) as err:
            raise DataFormatError(arrays_path, None, f"cannot read: {err}") from None
    title = str(data["title"])
    written = []
    if str(data["kind"]) == "landmark":
        fig = plotting.plot_landmark_slam(
            data["trajectory"], data["landmark_means"], data["landmark_covs"],
            reference_xy=data["reference_xy"], reference_label=str(data["reference_label"]),
            true_landmarks=data["true_landmarks"], title=title,
        )
        written.append(plotting.save(fig, folder / "trajectory.png"))
    else:
        fig = plotting.plot_grid_map(data["log_odds"], float(data["resolution"]), data["origin"],
                                     trajectory=data["trajectory"], title=title)
        written.append(plotting.save(fig, folder / "map_trajectory.png"))
        if arrays is None:
            from jaxslam.grid.export import save_map_png

            written.append(save_map_png(folder / "map.png", data["log_odds"], float(data["resolution"]),
                                        data["origin"], trajectory=data["trajectory"]))
    wv = data["weight_variance"] if "weight_variance" in data and data["weight_variance"].size else None
    fig = plotting.plot_filter_health(data["ess"], data["resampled"], int(data["particles"]), wv, title=title)
    written.append(plotting.save(fig, folder / "health.png"))
    return written
