"""What a scalar parameter may be: its unit, its meaning and its allowed range.

A :class:`ParamSpec` sits beside the defaults of a filter's ``Params``
(:data:`jaxslam.grid.types.PARAMETER_SPECS`, :data:`jaxslam.feature.params.PARAMETER_SPECS`),
so that a value given on the command line is refused, with its name, before anything
is compiled, instead of turning into a NaN, a silently ignored setting or a map that
looks plausible and is not. A swappable part (a resampler, a matcher) is given as a
function or by its name in a table (:func:`choose`), refused likewise when unknown.
"""

from __future__ import annotations

import math
from typing import Any, Callable, Mapping, NamedTuple

__all__ = ["ParamSpec", "at_least", "choose", "fraction", "positive", "real"]


def choose(table: Mapping[str, Callable[..., Any]], choice: str | Callable[..., Any], what: str) -> Callable[..., Any]:
    """``choice`` itself when it is a function, else the function named ``choice`` in
    ``table``; an unknown name is a ``ValueError`` naming ``what`` and the names known."""
    if callable(choice):
        return choice
    try:
        return table[choice]
    except KeyError:
        raise ValueError(f"unknown {what} {choice!r}; choose one of {sorted(table)}") from None


class ParamSpec(NamedTuple):
    """A scalar parameter's unit, meaning and allowed values.

    Attributes:
        unit: its unit (``"m"``, ``"rad"``, ``"1"`` for a plain number ...).
        meaning: what it does, in a few words.
        low: smallest allowed value (``-inf``: none); every value must be finite.
        high: largest allowed value (``inf``: none).
        low_open: ``low`` itself is not allowed (``> low``, as for a standard deviation).
        algorithms: the algorithms that use it; ``None``: every filter of its family.
    """

    unit: str
    meaning: str
    low: float = -math.inf
    high: float = math.inf
    low_open: bool = False
    algorithms: tuple[str, ...] | None = None

    def allowed(self) -> str:
        """The allowed values in words: ``"finite and > 0"``, ``"in [0, 1]"`` ..."""
        if math.isfinite(self.low) and math.isfinite(self.high):
            return f"in {'(' if self.low_open else '['}{_text(self.low)}, {_text(self.high)}]"
        if math.isfinite(self.low):
            return f"finite and {'>' if self.low_open else '>='} {_text(self.low)}"
        if math.isfinite(self.high):
            return f"finite and <= {_text(self.high)}"
        return "finite"

    def problem(self, value: float) -> str | None:
        """Why ``value`` is not allowed, or None if it is."""
        if not math.isfinite(value):
            return f"must be {self.allowed()}"
        below = value <= self.low if self.low_open else value < self.low
        return f"must be {self.allowed()}" if below or value > self.high else None


def _text(value: float) -> str:
    return f"{value:g}"


def positive(unit: str, meaning: str, **kwargs) -> ParamSpec:
    """A finite value > 0 (a standard deviation, a length, a gain)."""
    return ParamSpec(unit, meaning, low=0.0, low_open=True, **kwargs)


def at_least(low: float, unit: str, meaning: str, **kwargs) -> ParamSpec:
    """A finite value >= ``low``."""
    return ParamSpec(unit, meaning, low=low, **kwargs)


def fraction(meaning: str, unit: str = "1", **kwargs) -> ParamSpec:
    """A value in [0, 1]."""
    return ParamSpec(unit, meaning, low=0.0, high=1.0, **kwargs)


def real(unit: str, meaning: str, **kwargs) -> ParamSpec:
    """Any finite value."""
    return ParamSpec(unit, meaning, **kwargs)
