"""Shared plumbing for benchmark scripts: machine facts, timing, JSON output."""

from __future__ import annotations

import json
import os
import platform
import sys
import time
from pathlib import Path
from typing import Any, Callable

RESULTS = Path(__file__).resolve().parent / "results"


def machine_info() -> dict[str, Any]:
    """Machine, library versions and the command that produced a result."""
    import jax
    import numpy as np

    from jaxslam.runtime.compiler import cpus_allowed

    cpu = platform.processor() or platform.machine()
    fields: dict[str, str] = {}
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if not line.strip():
                    break  # the first processor's block
                key, _, value = line.partition(":")
                fields[key.strip()] = value.strip()
    except OSError:
        pass
    cpu = fields.get("model name", cpu)
    # Two "AMD EPYC" machines may be different CPUs whose vector instructions give XLA's
    # code other rounding, and so chaotic runs other results (see the documentation's Reproducibility page).
    flags = set(fields.get("flags", "").split())
    return {
        "cpu": cpu,
        "cores": os.cpu_count(),
        "cpu_family_model": f"{fields.get('cpu family', '?')}/{fields.get('model', '?')}" if fields else None,
        "vector_extensions": sorted(flags & {"sse4_2", "avx", "avx2", "fma", "avx512f", "avx512bw", "avx512vl"}),
        # the CPUs this process (and the workers it starts) may use: XLA compiles
        # another program for another count (jaxslam.runtime.compiler.cpus_allowed)
        "cpus_allowed": cpus_allowed(),
        "platform": platform.platform(),
        "python": platform.python_version(),
        "jax": jax.__version__,
        "jaxlib": getattr(jax.lib, "__version__", None) or __import__("jaxlib").__version__,
        "numpy": np.__version__,
        "backend": jax.default_backend(),
        "devices": [str(d) for d in jax.devices()],
        "command": " ".join([Path(sys.executable).name] + sys.argv),
        "date": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }


def time_call(fn: Callable[[], Any], repeats: int = 5, min_time: float = 0.2) -> float:
    """Median seconds per call of an already compiled ``fn`` (blocks on the result)."""
    import jax

    jax.block_until_ready(fn())
    samples = []
    for _ in range(repeats):
        n, t0 = 0, time.perf_counter()
        while True:
            jax.block_until_ready(fn())
            n += 1
            elapsed = time.perf_counter() - t0
            if elapsed >= min_time / repeats:
                break
        samples.append(elapsed / n)
    samples.sort()
    return samples[len(samples) // 2]


def write_json(name: str, payload: dict[str, Any]) -> Path:
    """Write ``benchmarks/results/<name>.json`` with machine info attached."""
    RESULTS.mkdir(parents=True, exist_ok=True)
    path = RESULTS / f"{name}.json"
    payload = {"machine": machine_info(), **payload}
    path.write_text(json.dumps(payload, indent=2, default=float) + "\n")
    return path


def print_table(rows: list[dict[str, Any]], columns: list[str]) -> None:
    """A plain-text table of ``rows`` restricted to ``columns``."""
    def fmt(value):
        if isinstance(value, float):
            return f"{value:.4g}"
        return str(value)

    widths = {c: max([len(c), *(len(fmt(r.get(c, ""))) for r in rows)]) for c in columns}
    print("  ".join(c.rjust(widths[c]) for c in columns))
    print("  ".join("-" * widths[c] for c in columns))
    for r in rows:
        print("  ".join(fmt(r.get(c, "")).rjust(widths[c]) for c in columns))
