"""Output writing on a big map: PGM/YAML/PNG (jaxslam.grid.export) and the map figure.

Usage:
    python benchmarks/export_big_map.py [--size 4000] [--repeats 3] [--baseline REV]

A synthetic ``size x size`` log-odds map (5 cm cells: rooms and corridors, free, occupied
and unknown cells, a trajectory over it) is written with ``save_map`` and drawn with
``plotting.plot_grid_map`` + ``plotting.save`` as ``jaxslam run`` does. With
``--baseline REV`` (default ``main``) the same is timed with export.py and plotting.py
as they are in git revision REV (loaded from ``git show``), in the same run, and the
files are compared: PGM and PNG pixels must be identical.

Writes benchmarks/results/export_big_map.json.
"""

from __future__ import annotations

import argparse
import importlib.util
import io
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _common import print_table, write_json  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def synthetic_map(size: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Log-odds map with unknown borders, free rooms, walls; and a path through it."""
    rng = np.random.default_rng(seed)
    log_odds = np.zeros((size, size), np.float32)
    inner = slice(size // 10, size - size // 10)
    log_odds[inner, inner] = -2.0
    for k in range(size // 10, size - size // 10, max(size // 25, 2)):
        log_odds[k : k + 3, inner] = 3.0
        log_odds[inner, k : k + 3] = 3.0
        doors = rng.integers(size // 10, size - size // 10, 6)
        for d in doors:
            log_odds[k : k + 3, d : d + 20] = -2.0
    log_odds += rng.normal(0.0, 0.3, log_odds.shape).astype(np.float32)
    t = np.linspace(0, 6 * np.pi, 5000)
    trajectory = np.stack([size * 0.025 + size * 0.018 * np.cos(t) * (1 + t / 20),
                           size * 0.025 + size * 0.018 * np.sin(t) * (1 + t / 20), t], 1)
    return log_odds, trajectory


def _load_module(name: str, source: str):
    spec = importlib.util.spec_from_loader(name, loader=None)
    module = importlib.util.module_from_spec(spec)
    exec(compile(source, f"<{name}>", "exec"), module.__dict__)
    return module


def _png_pixels(data: bytes) -> np.ndarray:
    from matplotlib.image import imread

    pixels = np.round(imread(io.BytesIO(data), format="png") * 255).astype(np.uint8)
    if pixels.ndim == 3 and pixels.shape[2] == 4:
        pixels = pixels[..., :3]
    if pixels.ndim == 3 and np.all(pixels[..., :1] == pixels):
        pixels = pixels[..., 0]
    return pixels


def _time(fn, repeats: int) -> float:
    samples = []
    for _ in range(repeats):
        started = time.perf_counter()
        fn()
        samples.append(time.perf_counter() - started)
    return statistics.median(samples)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--size", type=int, default=4000)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--baseline", default="main", help="git revision to compare with ('' for none)")
    args = parser.parse_args()

    from jaxslam.app import plotting
    from jaxslam.grid import export

    versions = {"current": (export, plotting)}
    if args.baseline:
        sources = {name: subprocess.run(["git", "-C", str(ROOT), "show", f"{args.baseline}:jaxslam/{name}"],
                                        check=True, capture_output=True, text=True).stdout
                   for name in ("grid/export.py", "plotting.py")}
        versions = {f"baseline ({args.baseline})": (_load_module("export_baseline", sources["grid/export.py"]),
                                                    _load_module("plotting_baseline", sources["plotting.py"])),
                    **versions}
    log_odds, trajectory = synthetic_map(args.size)
    resolution, origin = 0.05, (-3.0, -2.0)
    rows, files = [], {}
    with tempfile.TemporaryDirectory() as folder:
        for label, (exp, plot) in versions.items():
            out = Path(folder) / label.split()[0]
            save_s = _time(lambda: exp.save_map(out, log_odds, resolution, origin, trajectory=trajectory),
                           args.repeats)
            figure_s = _time(lambda: plot.save(plot.plot_grid_map(log_odds, resolution, origin,
                                                                  trajectory=trajectory, title="big map"),
                                               out / "map_trajectory.png"), args.repeats)
            files[label] = {name: (out / name).read_bytes() for name in ("map.pgm", "map.png", "map.yaml")}
            rows.append({"version": label, "save_map_s": save_s, "figure_s": figure_s,
                         "total_s": save_s + figure_s,
                         "png_bytes": len(files[label]["map.png"]), "pgm_bytes": len(files[label]["map.pgm"])})
    if len(rows) == 2:
        base, cur = (files[r["version"]] for r in rows)
        same_pgm = base["map.pgm"] == cur["map.pgm"] and base["map.yaml"] == cur["map.yaml"]
        same_png = bool(np.array_equal(_png_pixels(base["map.png"]), _png_pixels(cur["map.png"])))
        rows[1]["speedup"] = rows[0]["total_s"] / rows[1]["total_s"]
        rows[1]["pgm_identical"], rows[1]["png_pixels_identical"] = same_pgm, same_png
    print(f"map {args.size} x {args.size}, median of {args.repeats}")
    print_table(rows, ["version", "save_map_s", "figure_s", "total_s", "speedup", "png_bytes", "pgm_identical",
                       "png_pixels_identical"])
    print("load average:", os.getloadavg())
    path = write_json("export_big_map", {"size": args.size, "rows": rows, "load_average": os.getloadavg()})
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
