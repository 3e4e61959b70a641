"""The parameters ``jaxslam run --set NAME=VALUE`` accepts: names, units, meanings,
defaults, and the check of a value against its allowed range.

The specifications live beside the filters' ``Params``
(:data:`jaxslam.grid.types.PARAMETER_SPECS`, :data:`jaxslam.feature.params.PARAMETER_SPECS`);
this module joins them with each algorithm's defaults for the command line
(``--set``, ``--params``, ``--list-params``) and for the documentation
(:func:`parameter_reference`).
"""

from __future__ import annotations

import difflib
import math
from typing import NamedTuple

import numpy as np

from jaxslam.core.spec import ParamSpec
from jaxslam.datasets.registry import ALGORITHMS

__all__ = ["ParamRow", "check_value", "defaults", "parameter_reference", "parameter_table", "specs"]


class ParamRow(NamedTuple):
    """One parameter of :func:`parameter_reference`.

    Attributes:
        name: the name ``--set`` takes.
        unit: its unit.
        meaning: what it does.
        defaults: each algorithm that uses it, with its default written as one types
            it on the command line (``"0.05"``).
    """

    name: str
    unit: str
    meaning: str
    defaults: dict[str, str]


def specs(algorithm: str) -> dict[str, ParamSpec]:
    """The parameters ``--set`` accepts for ``algorithm``, by name."""
    if ALGORITHMS[algorithm] == "landmark":
        from jaxslam.feature.params import PARAMETER_SPECS
    else:
        from jaxslam.grid.types import PARAMETER_SPECS
    return {name: spec for name, spec in PARAMETER_SPECS.items()
            if spec.algorithms is None or algorithm in spec.algorithms}


def defaults(algorithm: str) -> dict[str, str]:
    """Each parameter of :func:`specs` with ``algorithm``'s default, as typed."""
    if ALGORITHMS[algorithm] == "landmark":
        from jaxslam.feature.params import Params

        values = Params()
    else:
        from jaxslam.grid.algorithms import grid_algorithm
        from jaxslam.grid.types import get_path

        grid = grid_algorithm(algorithm).make_params(np.zeros(1), dtype=np.float64)
        return {name: typed(float(get_path(grid, name))) for name in specs(algorithm)}
    return {name: typed(float(getattr(values, name))) for name in specs(algorithm)}


def typed(value: float) -> str:
    """``value`` as one would type it: the shortest text that reads back as the same
    float32 (the dtype the filters run in by default): ``0.05``, ``20``, ``-1e+09``,
    ``0.05235988`` for 3 degrees in radians. Between 1e-4 and 1e6 the digits are written
    out (``20``, not ``2e+01``)."""
    target = np.float32(value)
    for digits in range(1, 18):
        text = f"{value:.{digits}g}"
        if np.float32(float(text)) == target:
            if "e" in text and 1e-4 <= abs(float(text)) < 1e6:
                return np.format_float_positional(float(text), trim="-")
            return text
    return repr(float(value))


def parameter_reference() -> list[ParamRow]:
    """Every parameter ``jaxslam run --set`` accepts for some algorithm, in the order
    of the filters' parameter specifications (grid filters first), each with the
    defaults of the algorithms that use it."""
    rows: dict[str, ParamRow] = {}
    for algorithm in ("srupf-gm", "srupf-gm-npc", "gmapping", "erb-upf", "rb-upf"):
        values = defaults(algorithm)
        for name, spec in specs(algorithm).items():
            row = rows.setdefault(name, ParamRow(name, spec.unit, spec.meaning, {}))
            row.defaults[algorithm] = values[name]
    return list(rows.values())


def parameter_table(algorithm: str) -> str:
    """``--list-params``: a table of name, default as typed, unit and meaning of every
    parameter ``--set`` accepts for ``algorithm``."""
    values, table = defaults(algorithm), specs(algorithm)
    rows = [("name", "default", "unit", "meaning")]
    rows += [(name, values[name], spec.unit, f"{spec.meaning} ({spec.allowed()})") for name, spec in table.items()]
    widths = [max(len(row[i]) for row in rows) for i in range(3)]
    return "\n".join(f"{a:<{widths[0]}}  {b:>{widths[1]}}  {c:<{widths[2]}}  {d}" for a, b, c, d in rows)


def check_value(algorithm: str, name: str, value, origin: str = "--set") -> str:
    """``name`` (a ``Params`` field of a landmark filter, the path of a grid filter's
    leaf) after checking ``value``; a ``ValueError`` naming ``origin``, the parameter and
    the value otherwise. ``value``: a number, or a list of numbers (from a calibration
    file) for a vector parameter."""
    table = specs(algorithm)
    spec = table.get(name)
    if isinstance(value, list):
        return _check_vector(algorithm, name, value, origin)
    if spec is None:
        close = difflib.get_close_matches(name, list(table), n=1)
        raise ValueError(f"{origin} {name}={value:g}: {algorithm} has no parameter {name!r}"
                         f"{_unused_hint(algorithm, name)}{f'; did you mean {close[0]!r}?' if close else ''} "
                         f"Its parameters: {', '.join(table)} (`jaxslam run --list-params --algorithm {algorithm}`)")
    problem = spec.problem(float(value))
    if problem is not None:
        raise ValueError(f"{origin} {name}={value:g}: {name} ({spec.unit}, {spec.meaning}) {problem}")
    return name


def _unused_hint(algorithm: str, name: str) -> str:
    from jaxslam.feature.params import PARAMETER_SPECS as LANDMARK
    from jaxslam.grid.types import PARAMETER_SPECS as GRID

    spec = GRID.get(name) or LANDMARK.get(name)
    if spec is not None and spec.algorithms:
        return f" (it is a parameter of {', '.join(spec.algorithms)})"
    if spec is not None:
        return " (it is a parameter of the " + ("grid" if name in GRID else "landmark") + " filters)"
    return ""


def _check_vector(algorithm: str, name: str, value: list, origin: str) -> str:
    from jaxslam.grid.types import VECTORS

    size = VECTORS.get(name) if ALGORITHMS[algorithm] == "laser" else None
    if size is None:
        raise ValueError(f"{origin} {name}: {algorithm} has no vector parameter {name!r}")
    if len(value) != size:
        raise ValueError(f"{origin} {name}: expected {size} number(s), got a list of {len(value)}")
    for i, item in enumerate(value):
        if not (math.isfinite(float(item)) and float(item) >= 0.0):
            raise ValueError(f"{origin} {name}[{i}]={float(item):g}: must be finite and >= 0")
    return name
