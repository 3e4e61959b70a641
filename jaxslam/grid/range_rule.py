r"""How far to use the laser: the usable range chosen from the log's own readings.

Indoors almost every reading ends within 20 m (a percent or less beyond), and there
the default range of 20 m (:class:`jaxslam.grid.types.SensorParams`) for both the map
and the matcher is the filter's design point. Outdoors, or in large halls, a fifth or
more of the readings lie beyond it: cropped at 20 m, a scan keeps a sparse near field that no longer pins
the pose, and the map bends where GMapping, with its 80 m, keeps it straight.

The rule, with :math:`f` the fraction of valid readings beyond ``NEAR_RANGE``:

* :math:`f \le` ``FAR_FRACTION``: ``usable_range = score_range = NEAR_RANGE`` (the
  defaults);
* :math:`f >` ``FAR_FRACTION``: ``usable_range = score_range = min(FAR_RANGE,
  max_range)``: the map and the matcher see the far field, every beam weighing 1, as
  GMapping does with its 80 m ``maxUrange``.

Why not 80 m everywhere: a log with few far readings gains nothing from them and
loses to chance; on indoor logs the far field, at full weight or at a discount
(``sensor.score_range`` 20 m, :func:`jaxslam.grid.filter.beam_weights`), makes the filter less robust
and the loop slower. Why no discount where the far field is used: where a fifth of
the readings are far, they are what pins the pose, at full weight as in GMapping.
``benchmarks/grid_robustness.py`` (``--variant``) compares both. Why 10 %: logs fall
in two groups, indoor ones at or below a few percent and outdoor or hall ones at or
above a tenth; the threshold sits in the gap between them, not on any one log.

The decision is the log's, made once before the run from all its readings, like the
"no return" detection of :func:`jaxslam.datasets.no_return.detect_no_return`; it is
reported in ``summary.json`` (``range_rule``). An explicit ``sensor.usable_range`` or
``sensor.score_range`` (``--set``) turns it off. The streaming filter
(:mod:`jaxslam.grid.stream`), which sees one scan at a time, cannot measure the
fraction before it starts: it keeps the 20 m defaults unless it is given the ranges.
"""

from __future__ import annotations

from typing import Any

import numpy as np

NEAR_RANGE = 20.0
"""The usable range of indoor logs (m)."""

FAR_RANGE = 80.0
"""The usable range (m) of logs with a far field (GMapping's default ``maxUrange``)."""

FAR_FRACTION = 0.10
"""Fraction of valid readings beyond :data:`NEAR_RANGE` above which the far field is used."""


def choose_range(ranges: np.ndarray, valid: np.ndarray, max_range: float | None = None) -> dict[str, Any]:
    """The usable and score ranges for a log's readings (see the module docstring).

    Args:
        ranges: ``(S, B)`` readings in m.
        valid: ``(S, B)`` usable hits (finite, below the log's "no return" limit).
        max_range: the laser's range limit (m), or ``None``.

    Returns:
        ``{"usable_range", "score_range", "far_fraction", "far_field", "near_range",
        "threshold"}`` (JSON-ready).
    """
    ranges = np.asarray(ranges, np.float64)
    valid = np.asarray(valid, bool) & np.isfinite(ranges) & (ranges > 0)
    count = int(np.count_nonzero(valid))
    far = float(np.count_nonzero(valid & (ranges > NEAR_RANGE)) / count) if count else 0.0
    far_field = far > FAR_FRACTION
    limit = FAR_RANGE
    if max_range is not None and np.isfinite(max_range) and max_range > 0:
        limit = min(FAR_RANGE, float(max_range))
    usable = max(limit, NEAR_RANGE) if far_field else NEAR_RANGE
    return {
        "usable_range": float(usable),
        "score_range": float(usable),
        "far_fraction": far,
        "far_field": bool(far_field),
        "near_range": NEAR_RANGE,
        "threshold": FAR_FRACTION,
    }


def apply_range_rule(overrides: dict[str, Any], log) -> tuple[dict[str, Any], dict[str, Any]]:
    """``(overrides, record)``: parameter overrides with the rule's ranges added for
    ``log`` (a :class:`jaxslam.datasets.carmen.CarmenLog`, all its scans), unless they
    set ``sensor.usable_range`` or ``sensor.score_range`` (or the whole ``sensor``) themselves. ``record`` is what
    ``summary.json`` reports as ``range_rule``: ``{"source": "params"}``, or
    ``{"source": "log", **choose_range(...)}``. Every grid entry point that builds
    parameters for a log (the run, the calibration) takes its ranges from here."""
    overrides = dict(overrides)
    if {"sensor", "sensor.usable_range", "sensor.score_range"} & set(overrides):
        return overrides, {"source": "params"}
    record = {"source": "log", **choose_range(log.ranges, log.valid, getattr(log, "max_range", None))}
    overrides["sensor.usable_range"], overrides["sensor.score_range"] = record["usable_range"], record["score_range"]
    return overrides, record


__all__ = ["FAR_FRACTION", "FAR_RANGE", "NEAR_RANGE", "apply_range_rule", "choose_range"]
