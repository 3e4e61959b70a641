r"""Per-particle landmark tables of fixed capacity.

Each particle owns ``C`` slots; a slot holds a landmark mean ``(2,)``, covariance
``(2, 2)``, an evidence score and an ``active`` flag. Shapes never change: a new
landmark takes the first free slot, a pruned one frees its slot, and a table that is
full drops new landmarks (counted in the filter's ``Info``). The functions here are
for one particle; the filter ``vmap`` s them.

Evidence (for pruning spurious landmarks such as moving objects): each match adds 1,
each scan in which the landmark should have been seen (well inside the sensor's range
and field of view from the sampled pose) but was not matched subtracts 1; a landmark
whose evidence falls below the prune threshold is deleted.

Association works on a *local* set of slots: one pass over the table per particle and
scan keeps the active landmarks inside the sensor's footprint (range and field of
view, widened by a margin), compacted into ``local_size`` slots with a prefix sum.
Everything downstream (Euclidean pre-selection, the sigma-point Mahalanobis test,
visibility for evidence) then costs ``O(local_size)``, not ``O(C)``, per observation.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
from jax import Array


class LandmarkTable(NamedTuple):
    """Landmark slots of one particle (or a batch of particles: leading axes).

    Attributes:
        means: ``(C, 2)``.
        covs: ``(C, 2, 2)``.
        evidence: ``(C,)``.
        active: ``(C,)`` bool.
        count: ``()`` int32, number of active slots.
    """

    means: Array
    covs: Array
    evidence: Array
    active: Array
    count: Array


def empty_table(capacity: int, dtype=jnp.float32, batch: tuple[int, ...] = ()) -> LandmarkTable:
    """A table with every slot free."""
    return LandmarkTable(
        means=jnp.zeros(batch + (capacity, 2), dtype),
        covs=jnp.broadcast_to(jnp.eye(2, dtype=dtype), batch + (capacity, 2, 2)),
        evidence=jnp.zeros(batch + (capacity,), dtype),
        active=jnp.zeros(batch + (capacity,), bool),
        count=jnp.zeros(batch, jnp.int32),
    )


def prefix_count(mask: Array, block: int = 32) -> Array:
    """Inclusive prefix count of a bool vector ``(C,)`` as int32.

    Written as two small triangular matrix products (blocks of ``block``) rather than
    ``jnp.cumsum``: on CPU the products run several times faster and counts below
    2^24 are exact in float32.
    """
    size = mask.shape[0]
    if size % block:
        return jnp.cumsum(mask, dtype=jnp.int32)
    x = mask.astype(jnp.float32).reshape(size // block, block)
    within = x @ jnp.triu(jnp.ones((block, block), jnp.float32))
    before = within[:, -1] @ jnp.triu(jnp.ones((size // block, size // block), jnp.float32), 1)
    return (within + before[:, None]).reshape(size).astype(jnp.int32)


def nth_true(counts: Array, num: int) -> Array:
    """Indices of the first ``num`` true entries from the prefix count of a mask;
    ``C`` where there are fewer. A binary search per output (``O(num log C)``), not a
    scatter of all ``C`` entries (scatters run serially on CPU)."""
    targets = jnp.arange(1, num + 1, dtype=counts.dtype)
    return jnp.searchsorted(counts, targets, side="left", method="scan").astype(jnp.int32)


def local_slots(
    table: LandmarkTable,
    sensor_xy: Array,
    heading: Array,
    max_range: Array,
    half_fov: Array,
    margin: Array,
    size: int,
) -> tuple[Array, Array, Array]:
    """Slots of the active landmarks inside the sensor footprint, widened by ``margin``.

    A landmark at range ``r`` and forward coordinate ``l_x`` (sensor frame) is kept
    when ``r < max_range + margin`` and ``l_x >= r cos(half_fov) - margin``.

    Returns:
        ``(slots (size,), valid (size,), overflow ())``: the first ``size`` kept slots
        in slot order (``C`` marks an empty entry) and how many were left out.
    """
    capacity = table.active.shape[0]
    d = table.means - sensor_xy
    r2 = d[:, 0] ** 2 + d[:, 1] ** 2
    forward = jnp.cos(heading) * d[:, 0] + jnp.sin(heading) * d[:, 1]
    reach = max_range + margin
    keep = table.active & (r2 < reach * reach) & (forward >= jnp.sqrt(r2) * jnp.cos(half_fov) - margin)
    counts = prefix_count(keep)
    slots = nth_true(counts, size)
    overflow = jnp.maximum(counts[-1] - size, 0)
    return slots, slots < capacity, overflow


def free_slots(active: Array, num: int) -> Array:
    """The first ``num`` free slots ``(num,)``; ``C`` where the table has no more."""
    return nth_true(prefix_count(~active), num)


def gather(table: LandmarkTable, slots: Array) -> tuple[Array, Array]:
    """Means ``(k, 2)`` and covariances ``(k, 2, 2)`` at ``slots`` (clipped)."""
    idx = jnp.minimum(slots, table.active.shape[0] - 1)
    return table.means[idx], table.covs[idx]
