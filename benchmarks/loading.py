"""Load time of the datasets: the bulk NumPy CARMEN reader vs the line-by-line one.

Usage:
    python benchmarks/loading.py [--datasets intel mit-killian victoria-park] [--repeats 3]

For each CARMEN log, ``line reader`` is :func:`jaxslam.datasets.carmen.load_carmen`
with its bulk path switched off (every line parsed in Python, the reference reader
that also handles every malformed input) and ``bulk reader`` the default (NumPy's
text parser on all FLASER and all ODOM lines at once); both results are checked to be
identical. Victoria Park is read from its NumPy/whitespace-table files by
:func:`jaxslam.datasets.victoria_park.load_sequence` (one column). Median of
``--repeats`` loads each, both readers in the same run, alternating.

Writes benchmarks/results/loading.json.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import statistics
import sys
import time
from unittest import mock

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _common import print_table, write_json  # noqa: E402


def _timed(fn):
    started = time.perf_counter()
    value = fn()
    return time.perf_counter() - started, value


def _same(a, b) -> bool:
    for field in dataclasses.fields(a):
        x, y = getattr(a, field.name), getattr(b, field.name)
        if isinstance(x, np.ndarray):
            if not (x.shape == y.shape and np.array_equal(x, y, equal_nan=True)):
                return False
        elif x != y:
            return False
    return True


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--datasets", nargs="+", default=["intel", "mit-killian", "victoria-park"])
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()

    from jaxslam.datasets import carmen, registry, victoria_park

    rows = []
    for name in args.datasets:
        if name in ("victoria-park", "vp"):
            times = [_timed(victoria_park.load_sequence)[0] for _ in range(args.repeats)]
            rows.append({"dataset": name, "line_reader_s": None, "bulk_reader_s": statistics.median(times),
                         "speedup": None, "identical": None})
            continue
        slow_times, fast_times = [], []
        slow = fast = None
        for _ in range(args.repeats):
            with mock.patch.object(carmen, "_read_lines_fast", lambda *a: None):
                seconds, slow = _timed(lambda: registry.load_dataset_log(name))
            slow_times.append(seconds)
            seconds, fast = _timed(lambda: registry.load_dataset_log(name))
            fast_times.append(seconds)
        line_s, bulk_s = statistics.median(slow_times), statistics.median(fast_times)
        rows.append({"dataset": name, "scans": fast.num_scans, "line_reader_s": line_s, "bulk_reader_s": bulk_s,
                     "speedup": line_s / bulk_s, "identical": _same(fast, slow)})
    print_table(rows, ["dataset", "scans", "line_reader_s", "bulk_reader_s", "speedup", "identical"])
    print("load average:", os.getloadavg())
    path = write_json("loading", {"rows": rows, "repeats": args.repeats, "load_average": os.getloadavg()})
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
