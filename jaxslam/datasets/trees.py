"""Tree-trunk detection in 2-D laser scans, and matching of two detection sets.

Host-side NumPy, vectorised over all beams of all scans at once (no Python loop over
scans). Written for Victoria Park (SICK LMS, 361 beams over 0..pi, 0.5 deg apart,
no return above 80 m), in the spirit of ACFR's ``detectTreesI16`` (Guivant & Nebot
2001) but not a port of it.

The extractor
-------------
A trunk seen by a scanner is a short run of neighbouring beams that all hit at about
the same range and stand in front of what lies beside them. For each scan:

1. Beams with ``min_range < r < max_range`` are returns. A single missing or outlying
   beam between two returns at nearly the same range is filled with their mean (the
   SICK drops single beams on bark).
2. The returns are cut into segments wherever two neighbouring beams differ in range
   by more than ``jump_m + jump_fraction * r``, or a beam is not a return.
3. A segment is a trunk candidate when

   * its chord ``d = n dtheta r_mid`` (``n`` beams, ``r_mid`` the range at the middle
     of the segment) is between ``min_diameter`` and ``max_diameter``;
   * its two end ranges differ by less than ``end_asymmetry * d`` (a cylinder seen
     side-on; a wall seen obliquely fails this; a trunk only 1-2 beams wide can fail
     it too when one beam grazes its edge);
   * nothing beside it is closer (the beam just outside each end is no return or is
     farther away): an object cut by something in front has an unknown width;
   * it is at least ``edge_margin`` beams away from both ends of the scan;
   * it stands alone: no return outside the segment lies within ``clearance_m`` of the
     trunk's surface (this rejects bushes, hedges, cars and wall corners, whose
     segments are surrounded by other returns, while park trees stand in the open).

4. A candidate gives ``range = r_mid + d / 2`` (the centre of the trunk, behind its
   visible surface), ``bearing`` = mean of the end beam angles ``- pi/2`` (0 ahead,
   left positive, the frame of :mod:`jaxslam.datasets.victoria_park`) and
   ``diameter = d``.

Matching
--------
:func:`match_detections` pairs two detection sets scan by scan, greedily by
normalised distance ``max(|dr| / max_range_diff, |db| / max_bearing_diff)``, accepting a
pair when that distance is at most 1, each detection used once.
"""

from __future__ import annotations

import dataclasses

import numpy as np

BEAM_STEP = np.pi / 360.0


@dataclasses.dataclass(frozen=True)
class ScanDetections:
    """Detections per scan, padded: (S, D) ``ranges`` [m], ``bearings`` [rad, 0 ahead,
    left positive], ``diameters`` [m] and the ``mask`` of real entries."""

    ranges: np.ndarray
    bearings: np.ndarray
    diameters: np.ndarray
    mask: np.ndarray

    @property
    def counts(self) -> np.ndarray:
        return self.mask.sum(axis=1)


def pad_by_scan(
    scan_index: np.ndarray, n_scans: int, capacity: int | None = None, **columns: np.ndarray
) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Scatter flat rows into (n_scans, D) arrays; rows of one scan keep their order.

    Args:
        scan_index: (N,) scan of each row, non-decreasing.
        n_scans: number of scans S.
        capacity: D (default: the largest count in one scan, at least 1).
        columns: (N,) arrays to scatter.

    Returns:
        ``({name: (S, D) array}, mask (S, D))``.
    """
    scan_index = np.asarray(scan_index, dtype=np.int64)
    counts = np.bincount(scan_index, minlength=n_scans)
    width = max(int(counts.max()) if counts.size else 0, 1)
    if capacity is not None:
        if capacity < width:
            raise ValueError(f"capacity {capacity} < {width} rows in one scan")
        width = capacity
    slot = np.arange(scan_index.size) - np.concatenate([[0], np.cumsum(counts)])[scan_index]
    mask = np.zeros((n_scans, width), dtype=bool)
    mask[scan_index, slot] = True
    padded = {}
    for name, values in columns.items():
        out = np.zeros((n_scans, width), dtype=np.asarray(values).dtype)
        out[scan_index, slot] = values
        padded[name] = out
    return padded, mask


def extract_trees(
    ranges: np.ndarray,
    *,
    min_range: float = 1.0,
    max_range: float = 75.0,
    jump_m: float = 0.3,
    jump_fraction: float = 0.02,
    min_diameter: float = 0.0,
    max_diameter: float = 1.2,
    end_asymmetry: float = 0.35,
    edge_margin: int = 5,
    clearance_m: float = 3.0,
    capacity: int | None = None,
) -> ScanDetections:
    """Find tree trunks in laser scans (see the module docstring for the method).

    Args:
        ranges: (S, 361) or (361,) ranges [m], beam k at angle k pi / 360.
        min_range, max_range: returns outside (min_range, max_range) are ignored [m].
        jump_m, jump_fraction: two neighbouring beams belong to one segment when their
            ranges differ by at most ``jump_m + jump_fraction * r``.
        min_diameter, max_diameter: accepted trunk diameters [m].
        end_asymmetry: largest ``|r_first - r_last| / d`` of a trunk.
        edge_margin: beams ignored at each end of the scan.
        clearance_m: no return outside the segment may lie closer than this to the
            trunk's surface (0 turns the test off) [m].
        capacity: D of the padded output (default: the largest count in one scan).

    Returns:
        :class:`ScanDetections` with (S, D) arrays, in beam order (right to left).
    """
    ranges = np.asarray(ranges, dtype=np.float64)
    if ranges.ndim == 1:
        ranges = ranges[None]
    n_scans, n_beams = ranges.shape

    hit = (ranges > min_range) & (ranges < max_range)
    # Fill a single dropout (or outlier) between two returns at nearly the same range.
    left, right = ranges[:, :-2], ranges[:, 2:]
    bridge = (
        hit[:, :-2] & hit[:, 2:]
        & (np.abs(left - right) <= jump_m + jump_fraction * np.minimum(left, right))
        & (~hit[:, 1:-1] | (np.abs(ranges[:, 1:-1] - 0.5 * (left + right)) > jump_m + jump_fraction * left))
    )
    ranges = ranges.copy()
    ranges[:, 1:-1] = np.where(bridge, 0.5 * (left + right), ranges[:, 1:-1])
    hit[:, 1:-1] |= bridge

    near = np.abs(np.diff(ranges, axis=1)) <= jump_m + jump_fraction * np.minimum(ranges[:, 1:], ranges[:, :-1])
    joined = hit[:, 1:] & hit[:, :-1] & near  # beam k+1 continues the segment of beam k
    first = hit & ~np.concatenate([np.zeros((n_scans, 1), bool), joined], axis=1)
    last = hit & ~np.concatenate([joined, np.zeros((n_scans, 1), bool)], axis=1)
    scan, start = np.nonzero(first)
    _, stop = np.nonzero(last)  # row-major order pairs each start with its stop

    count = stop - start + 1
    mid_lo = (start + stop) // 2
    mid_hi = (start + stop + 1) // 2
    r_mid = 0.5 * (ranges[scan, mid_lo] + ranges[scan, mid_hi])
    diameter = count * BEAM_STEP * r_mid
    r_first = ranges[scan, start]
    r_last = ranges[scan, stop]

    # The beams just outside the segment must be no return or farther away.
    outside_left = np.where(start > 0, ranges[scan, np.maximum(start - 1, 0)], np.inf)
    outside_right = np.where(stop < n_beams - 1, ranges[scan, np.minimum(stop + 1, n_beams - 1)], np.inf)
    left_open = ~hit[scan, np.maximum(start - 1, 0)] | (outside_left > r_first) | (start == 0)
    right_open = ~hit[scan, np.minimum(stop + 1, n_beams - 1)] | (outside_right > r_last) | (stop == n_beams - 1)

    keep = (
        (diameter >= min_diameter)
        & (diameter <= max_diameter)
        & (np.abs(r_first - r_last) < end_asymmetry * diameter)
        & left_open
        & right_open
        & (start >= edge_margin)
        & (stop <= n_beams - 1 - edge_margin)
    )
    scan, start, stop = scan[keep], start[keep], stop[keep]
    diameter, r_mid = diameter[keep], r_mid[keep]
    bearing = 0.5 * (start + stop) * BEAM_STEP - np.pi / 2
    if clearance_m > 0:
        clear = _clearance(ranges, hit, scan, start, stop, r_mid + 0.5 * diameter, bearing, diameter)
        keep = clear >= clearance_m
        scan, start, stop = scan[keep], start[keep], stop[keep]
        diameter, r_mid, bearing = diameter[keep], r_mid[keep], bearing[keep]
    padded, mask = pad_by_scan(
        scan, n_scans, capacity,
        ranges=r_mid + 0.5 * diameter, bearings=bearing, diameters=diameter,
    )
    return ScanDetections(padded["ranges"], padded["bearings"], padded["diameters"], mask)


def _clearance(ranges, hit, scan, start, stop, centre_range, bearing, diameter, chunk=4096):
    """Distance [m] from each trunk's surface to the nearest return not in its segment."""
    n_beams = ranges.shape[1]
    angles = np.arange(n_beams) * BEAM_STEP
    beam = np.arange(n_beams)
    out = np.empty(scan.size)
    for lo in range(0, scan.size, chunk):
        sl = slice(lo, lo + chunk)
        r, a = ranges[scan[sl]], angles[None, :]
        centre_x = centre_range[sl] * np.cos(bearing[sl] + np.pi / 2)
        centre_y = centre_range[sl] * np.sin(bearing[sl] + np.pi / 2)
        gap = np.hypot(r * np.cos(a) - centre_x[:, None], r * np.sin(a) - centre_y[:, None])
        gap -= 0.5 * diameter[sl, None]
        own = (beam[None] >= start[sl, None]) & (beam[None] <= stop[sl, None])
        gap = np.where(hit[scan[sl]] & ~own, gap, np.inf)
        out[sl] = gap.min(axis=1)
    return out


@dataclasses.dataclass(frozen=True)
class MatchResult:
    """Per-scan result of :func:`match_detections`.

    Attributes:
        partner: (S, Da) index into ``b``'s row of the matched detection, or -1.
        n_a, n_b: (S,) detections in each set.
        n_matched: (S,) matched pairs.
    """

    partner: np.ndarray
    n_a: np.ndarray
    n_b: np.ndarray
    n_matched: np.ndarray

    def scan_agrees(self, fraction: float = 0.5) -> np.ndarray:
        """(S,) True where more than ``fraction`` of the detections of *each* set are
        matched (scans where both sets are empty agree)."""
        n_matched = self.n_matched.astype(np.float64)
        ok_a = (n_matched > fraction * self.n_a) | (self.n_a == 0)
        ok_b = (n_matched > fraction * self.n_b) | (self.n_b == 0)
        return ok_a & ok_b

    def summary(self, fraction: float = 0.5) -> dict[str, float]:
        """Totals: recall (of ``b``), precision (of ``a``), fraction of agreeing scans."""
        total_a, total_b, matched = int(self.n_a.sum()), int(self.n_b.sum()), int(self.n_matched.sum())
        return dict(
            n_a=total_a,
            n_b=total_b,
            n_matched=matched,
            recall_b=matched / max(total_b, 1),
            precision_a=matched / max(total_a, 1),
            scans_agree=float(self.scan_agrees(fraction).mean()),
        )


def match_detections(
    a_ranges: np.ndarray,
    a_bearings: np.ndarray,
    a_mask: np.ndarray,
    b_ranges: np.ndarray,
    b_bearings: np.ndarray,
    b_mask: np.ndarray,
    *,
    max_range_diff: float = 0.5,
    max_bearing_diff: float = np.deg2rad(2.0),
) -> MatchResult:
    """Pair the detections of two sets scan by scan (greedy, nearest first).

    Args:
        a_ranges, a_bearings, a_mask: (S, Da) padded set ``a``.
        b_ranges, b_bearings, b_mask: (S, Db) padded set ``b``.
        max_range_diff: range gate [m].
        max_bearing_diff: bearing gate [rad].

    Returns:
        A :class:`MatchResult`.
    """
    a_ranges, a_bearings, a_mask = (np.asarray(x) for x in (a_ranges, a_bearings, a_mask))
    b_ranges, b_bearings, b_mask = (np.asarray(x) for x in (b_ranges, b_bearings, b_mask))
    n_scans, width_a = a_mask.shape
    width_b = b_mask.shape[1]
    if b_mask.shape[0] != n_scans:
        raise ValueError(f"the sets cover {n_scans} and {b_mask.shape[0]} scans")
    range_diff = np.abs(a_ranges[:, :, None] - b_ranges[:, None, :]) / max_range_diff
    bearing_diff = np.abs(np.angle(np.exp(1j * (a_bearings[:, :, None] - b_bearings[:, None, :])))) / max_bearing_diff
    cost = np.maximum(range_diff, bearing_diff)
    cost = np.where(a_mask[:, :, None] & b_mask[:, None, :] & (cost <= 1.0), cost, np.inf)

    partner = np.full((n_scans, width_a), -1, dtype=np.int64)
    rows = np.arange(n_scans)
    for _ in range(min(width_a, width_b)):
        flat = cost.reshape(n_scans, -1).argmin(axis=1)
        i, j = np.divmod(flat, width_b)
        found = np.isfinite(cost[rows, i, j])
        if not found.any():
            break
        partner[rows[found], i[found]] = j[found]
        cost[rows[found], i[found], :] = np.inf
        cost[rows[found], :, j[found]] = np.inf
    return MatchResult(
        partner=partner,
        n_a=a_mask.sum(axis=1),
        n_b=b_mask.sum(axis=1),
        n_matched=(partner >= 0).sum(axis=1),
    )
