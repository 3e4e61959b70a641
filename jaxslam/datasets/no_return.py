"""Finding a "no return" sentinel pile in laser ranges (see :func:`~jaxslam.datasets.no_return.detect_no_return`)."""

from __future__ import annotations

from typing import Any

import numpy as np

NO_RETURN_BAND = 0.25
"""Width of the band at the top of the observed ranges searched for a sentinel pile (m)."""


def detect_no_return(
    ranges: np.ndarray,
    limit: np.ndarray | float,
    *,
    band: float = NO_RETURN_BAND,
    gap: float = 2.0,
    min_share: float = 1e-3,
    min_count: int = 50,
    min_contrast: float = 20.0,
    min_beam_share: float = 0.1,
) -> dict[str, Any]:
    """Find a "no return" sentinel: readings piled up at the top of the observed range.

    Some lasers (and logs converted from other formats) report "no echo" not as their
    range limit or a code above it but as a value just above their real range, with
    no PARAM saying so: MIT Killian's SICK has a 50 m range and logs about 40,000
    readings at 51.05-51.22 m; Orebro's logs about 970 at 32.76-32.77 m. Taken as
    hits they draw walls that do not exist. Such a pile has a shape that real echoes
    do not have, and all of these must hold:

    1. Narrow and on top: the ``band``-wide window (1 cm histogram bins) holding the
       most readings among windows that start in the top 10 % of the observed range
       (readings ``0 < r < limit``), with at most 1 % of its count above it.
    2. A cliff, not a slope: its density (readings per m) is at least
       ``min_contrast`` times the density in the ``gap`` metres just below it. Walls
       seen from a moving robot spread over many ranges (a flat wall at distance
       ``d`` gives ``d / cos(angle)``, densest at ``d``, thinning out upwards), so
       real data falls off gently towards its top.
    3. Frequent: at least ``min_count`` readings and ``min_share`` of all readings.
    4. On many beams: at least ``min_beam_share`` of the beam indices have a reading
       in it. One wall at a fixed distance (a robot driving along a corridor, its
       side beam at a constant range) fills one or a few beams, a sentinel every
       beam that looks into open space somewhere along the path.

    On the shipped logs the sentinels score contrast 110-5000, share 0.7-8 % and beam
    share 0.59-1.0, and every other log's top window contrast < 35 with fewer than
    200 readings; the thresholds sit in between. The pile starts at the lowest 1 cm
    bin reached from its fullest bin going down over bins with at least 0.1 % of the
    fullest bin's count (and two readings), across holes of at most 5 cm, so the
    pile's stray codes are not left as hits and real echoes further below are.

    Args:
        ranges: (S, B) ranges (NaN for missing beams).
        limit: the range limit in use, scalar or (S,) per scan; readings at or above
            it are already "no return" and not looked at.
        band, gap, min_share, min_count, min_contrast, min_beam_share: the criteria
            above.

    Returns:
        ``{"detected": bool, "range_m": start of the pile or None, "readings": n,
        "share", "contrast", "beam_share", "window_m": [lo, hi]}`` (the statistics of
        the best window, also when it is not a sentinel).
    """
    ranges = np.asarray(ranges, dtype=np.float64)
    limit = np.broadcast_to(np.asarray(limit, dtype=np.float64).reshape(-1, 1), (ranges.shape[0], 1))
    with np.errstate(invalid="ignore"):
        usable = np.isfinite(ranges) & (ranges > 0.0) & (ranges < limit)
    values = ranges[usable]
    result: dict[str, Any] = {"detected": False, "range_m": None, "readings": 0, "share": 0.0,
                              "contrast": 0.0, "beam_share": 0.0, "window_m": None}
    if values.size < min_count:
        return result
    step = 0.01
    width = max(int(round(band / step)), 1)
    top = float(values.max())
    counts = np.bincount(np.floor(values / step).astype(np.int64))
    windows = np.convolve(counts, np.ones(width, dtype=np.int64), mode="valid")
    first = min(int(0.9 * top / step), windows.size - 1)
    start = first + int(np.argmax(windows[first:]))
    pile_count = int(windows[start])
    low, high = start * step, (start + width) * step
    above = int(counts[start + width :].sum())
    below = int(counts[max(start - int(round(gap / step)), 0) : start].sum())
    contrast = (pile_count / band) / max(below / gap, 1.0 / gap)
    bins = np.floor(ranges / step)
    with np.errstate(invalid="ignore"):
        in_window = usable & (bins >= start) & (bins < start + width)
    beam_share = float(np.mean(in_window.any(axis=0)))
    result.update(readings=pile_count, share=pile_count / values.size, contrast=float(contrast),
                  beam_share=beam_share, window_m=[round(low, 2), round(high, 2)])
    if (
        pile_count >= max(min_count, min_share * values.size)
        and above <= 0.01 * pile_count
        and contrast >= min_contrast
        and beam_share >= min_beam_share
    ):
        window = counts[start : start + width]
        floor = max(2, 0.001 * window.max())
        edge, hole = int(np.argmax(window)), 0
        for index in range(edge - 1, -1, -1):  # down from the fullest bin over holes <= 5 cm
            if window[index] >= floor:
                edge, hole = index, 0
            else:
                hole += 1
                if hole > 5:
                    break
        result.update(detected=True, range_m=round((start + edge) * step, 2))
    return result


