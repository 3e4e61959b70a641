r"""How far saved runs have drifted where a perturbed log comes back to a place.

For the runs that ``benchmarks/grid_robustness.py`` keeps (``--work``, default
``/tmp/grid_robustness/TAG/*.npz``: jaxslam's runs and GMapping
C++'s) on a perturbed GMapping-corrected log, this compares the pose of scan ``b``
relative to scan ``a`` with the corrected log's (the reference the suite scores
against):

.. math:: e = \big((x^{ref}_a)^{-1} \oplus x^{ref}_b\big)^{-1} \oplus \big(x_a^{-1} \oplus x_b\big)

(:func:`jaxslam.datasets.geometry.se2_between` three times, as the relations metric
composes its errors),

reported as its position (m) and heading (deg). With ``a`` and ``b`` at the same place
(the Freiburg campus: scans 5 and 735, the end of its 700 m loop, before any closure
there) it is the drift the filter has gathered over the loop, which a loop-closure
step must undo; scans in between show where it grew.

    python benchmarks/diagnostics/loop_drift.py --log fr-campus --pairs 5:300 5:500 5:700 5:735 \\
        --runs '/tmp/grid_robustness/campus/*.npz' --name loop_drift_campus

Prints the table and writes ``benchmarks/results/NAME.json`` and ``NAME.png`` (position
and heading error against the pair's second scan, one line per run, a colour per
filter).
"""

from __future__ import annotations

import argparse
import glob
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from _common import print_table, write_json  # noqa: E402

from jaxslam.datasets.geometry import se2_between  # noqa: E402
from jaxslam.datasets.perturb import load_reference_log  # noqa: E402


def drift(trajectory: np.ndarray, reference: np.ndarray, a: int, b: int) -> tuple[float, float]:
    """Position (m) and heading (deg) error of the pose of scan ``b`` relative to ``a``."""
    if max(a, b) >= min(trajectory.shape[0], reference.shape[0]):
        raise ValueError(f"scan pair {a}:{b} beyond the run ({trajectory.shape[0]} scans) "
                         f"or the reference ({reference.shape[0]})")
    estimated = se2_between(trajectory[a][None], trajectory[b][None])
    wanted = se2_between(reference[a][None], reference[b][None])
    error = se2_between(wanted, estimated)[0]
    return float(np.hypot(error[0], error[1])), float(np.degrees(error[2]))


def plot(rows: list[dict], pairs: list[tuple[int, int]], out: Path, title: str) -> None:
    """Position and heading error of each pair against its second scan, per run."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    filters = sorted({row["run"].rsplit("_s", 1)[0] for row in rows})
    colours = {f: plt.get_cmap("tab10")(i % 10) for i, f in enumerate(filters)}
    fig, axes = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    x = [b for _, b in pairs]
    for row in rows:
        kind = row["run"].rsplit("_s", 1)[0]
        label = kind if kind not in {line.get_label() for line in axes[0].get_lines()} else None
        for ax, unit in zip(axes, ("m", "deg")):
            ax.plot(x, [row[f"{a}:{b}_{unit}"] for a, b in pairs], "o-", color=colours[kind], ms=3, lw=1,
                    alpha=0.8, label=label if unit == "m" else None)
    axes[0].set_ylabel("position error (m)")
    axes[1].set_ylabel("heading error (deg)")
    axes[1].set_xlabel("second scan of the pair")
    axes[0].set_title(title)
    axes[0].legend(fontsize=7)
    for ax in axes:
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--log", default="fr-campus", help="corrected log (name or path) the runs perturbed")
    parser.add_argument("--pairs", nargs="+", default=["5:300", "5:500", "5:700", "5:735"], help="scan pairs A:B")
    parser.add_argument("--runs", action="append", required=True, help="glob of saved runs (.npz)")
    parser.add_argument("--name", default="loop_drift")
    args = parser.parse_args(argv)
    reference = load_reference_log(args.log).poses
    pairs = [tuple(int(s) for s in p.split(":")) for p in args.pairs]
    paths = sorted({p for pattern in args.runs for p in glob.glob(pattern)})
    if not paths:
        raise SystemExit(f"no runs match {args.runs}")
    rows = []
    for path in paths:
        trajectory = np.load(path)["trajectory"]
        row = {"run": Path(path).stem}
        for a, b in pairs:
            row[f"{a}:{b}_m"], row[f"{a}:{b}_deg"] = drift(trajectory, reference, a, b)
        rows.append(row)
    print_table(rows, list(rows[0]))
    path = write_json(args.name, {"log": args.log, "pairs": args.pairs, "runs": paths, "rows": rows})
    pairs_text = ", ".join(args.pairs) if len(pairs) <= 4 else f"{len(pairs)} scan pairs"
    plot(rows, pairs, path.with_suffix(".png"), f"{args.log}: drift against the reference ({pairs_text})")
    print(f"wrote {path} and {path.with_suffix('.png')}")


if __name__ == "__main__":
    main()
