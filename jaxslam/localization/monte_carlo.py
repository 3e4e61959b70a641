r"""Monte Carlo localization in a known map: KLD-adaptive, augmented MCL.

One :func:`mcl` filter, on the ``init``/``step`` protocol of the mapping filters:
``step(key, state, control, observation) -> (State, Info)`` with the odometry
increment ``(3,)`` as the control and a :class:`jaxslam.grid.types.Scan` as the
observation.

The particles in use are the first ``n_t`` slots of a fixed capacity of ``N``; the
others weigh nothing (``-inf``) and are never read. The motion and the measurement run
over the blocks of ``block_size`` slots that hold them (``ceil(n_t / block)`` turns of a
``lax.fori_loop``, each a ``dynamic_slice`` of the particles, ``vmap``-ed inside), so
there is one copy of the likelihood in the program and a step costs in proportion to
``n_t``, not ``N``.

Per step (Thrun, Burgard & Fox, *Probabilistic Robotics*, Tables 8.2-8.4):

1. **Motion.** Every particle in use draws ``x_t = x_{t-1} ⊕ (δ + n)`` from GMapping's
   odometry model (:func:`jaxslam.models.odometry.sample_gmapping`, the mapping
   filters' model, gains ``srr, srt, str, stt``), with a key folded from the step's
   key and its slot, so its draw does not depend on how many blocks run.
2. **Measurement**, once the odometry has moved ``update_min_d`` metres or
   ``update_min_a`` radians since the last one (AMCL's rule; the first scan always):
   the beam-endpoint likelihood field (:mod:`jaxslam.localization.field`) on up to
   ``max_beams`` evenly spaced beams, :math:`\log w \mathrel{+}= \lambda \sum_k
   \log p(z^k \mid x, m)` with a tempering power :math:`\lambda` (beams are not
   independent, so the product of all of them is overconfident).
3. **Augmented MCL.** With :math:`\bar w_t` the weighted mean likelihood per beam
   (the geometric mean over the beams of :math:`\sum_m w^{[m]}_{t-1} p(z_t|x^{[m]}_t)`),
   :math:`w_{slow} \mathrel{+}= \alpha_{slow}(\bar w_t - w_{slow})` and
   :math:`w_{fast} \mathrel{+}= \alpha_{fast}(\bar w_t - w_{fast})`. When
   :math:`p = 1 - w_{fast}/w_{slow}` exceeds ``inject_trigger`` the step resamples,
   and each new particle is, with probability :math:`p`, a pose drawn uniformly over
   the free cells (uniform heading) instead (Table 8.3; below the trigger nothing is
   injected, so that the noise of the averages in tracking does not widen the cloud).
4. **Resampling** (systematic: one uniform offset, positions ``(i + u) / m`` on the
   weights' CDF) when the effective sample size falls below ``ess_threshold`` times
   the particles in use, or to inject.
5. **Adaptive particle number** (KLD sampling, Fox 2003). At a resampling, a draw of
   ``m = n_t`` (of ``N`` when injecting: a uniform cloud needs them all), with the
   injected poses in it as AMCL counts its random particles, is binned (``bin_xy`` x
   ``bin_xy`` metres x ``bin_theta`` radians, the bins of AMCL's kd-tree); with ``k``
   bins occupied the particle number is Fox's bound

   .. math::
       n = \frac{k-1}{2\epsilon}\left(1 - \frac{2}{9(k-1)} +
           \sqrt{\frac{2}{9(k-1)}}\, z_{1-\delta}\right)^3,

   clipped to ``[min_particles, N]``. While ``n > m`` (and ``m < N``) the draw is
   made again with ``2m`` (``lax.while_loop``); the new cloud is the draw of ``n``
   (the last draw itself when ``n = m``). So a compact cloud (tracking) needs a few
   hundred and never costs a draw of ``N``; a cloud over a whole building (global
   localization, a kidnapping) the full capacity. A bin is one int32 key per pose
   (:func:`bin_keys`), counted by sorting only the shortest prefix of
   ``prefix_sizes`` (``block 4^j``, then ``N``) that holds the draw.
6. **Estimate.** The weighted circular mean of the particles within 1.5 bins of the
   heaviest bin (the mode, not the mean of a multi-modal cloud), with the mass it
   holds (``cluster_weight``) and the weighted spread of the whole cloud; the bins'
   masses come from the same prefix sort of the keys of the particles in use. The
   estimate keeps to the cluster it followed: where the mode lies elsewhere, the
   last estimate moved by the odometry stays the centre (the mean within 1.5 bins of
   it) until the mode's cluster holds ``estimate_switch`` (2) times its weight. After
   an injection in tracking, particles drawn over free space that fit one scan by
   chance can make a compact bin far away heavier than the true cluster's bins for a
   scan (Intel: 0.35 of the weight against 0.20), which moved the mode 20 m and back;
   a kidnapping or a global start still moves the estimate as soon as the old cluster
   has lost its weight.

What still runs over all ``N`` slots is linear and cheap beside the likelihood: the
tempering's bisection, the weights' normalisation and the CDF.

One module of about 580 lines: the filter's config, params, state and info beside its
step and factory, as for the other filters, with the KLD bound, the mode estimate and
the tempering that only this filter uses.
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import chex
import jax
import jax.numpy as jnp
import numpy as np
from jax import Array
from jax.scipy.special import logsumexp

from jaxslam.base import ParticleFilter
from jaxslam.core import se2
from jaxslam.core.numerics import safe_divide
from jaxslam.core.resampling import effective_sample_size, normalize_log_weights, systematic_rows
from jaxslam.grid.types import Scan
from jaxslam.localization.field import LikelihoodField, beam_log_likelihood, distance_at
from jaxslam.models.odometry import sample_gmapping


@dataclasses.dataclass(frozen=True)
class MclConfig:
    """Static settings (they size arrays or choose branches; changing one recompiles).

    Attributes:
        capacity: particles held (``N``); the number in use adapts inside it.
        num_beams: beams per scan of the log.
        max_beams: beams used per measurement, evenly spaced over the scan (AMCL's
            ``laser_max_beams``).
        min_particles: the fewest particles in use after a resampling.
        block: particles per block of the motion and measurement loops; 0 (default):
            the power of two at or above ``min_particles``, at most 2048 and at most
            the capacity (``block_size``). A cloud at its fewest then fills one block
            (tracking runs one or two turns of the loops), and a full cloud takes
            ``N / block`` turns, whose overhead is small beside the likelihood of a
            block (Intel, seed 0, global start, 1,000 / 10,000 particles: 3.5 / 5.1 ms
            per scan with blocks of 128 / 256, 3.8 / 6.0 ms with blocks of 1,024).
    """

    capacity: int = 5000
    num_beams: int = 180
    max_beams: int = 60
    min_particles: int = 250
    block: int = 0

    def __post_init__(self):
        if self.capacity < 1 or self.num_beams < 1 or self.max_beams < 1 or self.block < 0:
            raise ValueError(f"capacity, num_beams and max_beams must be positive, block >= 0: {self}")
        if not 1 <= self.min_particles <= self.capacity:
            raise ValueError(f"min_particles must lie in [1, capacity], got {self.min_particles}")

    @property
    def beam_indices(self) -> np.ndarray:
        """The beams used, evenly spaced over the scan."""
        count = min(self.max_beams, self.num_beams)
        return np.unique(np.round(np.linspace(0, self.num_beams - 1, count)).astype(np.int64))

    @property
    def block_size(self) -> int:
        """The particles of a block (``block``, or the power of two at or above
        ``min_particles`` and at most 2048), at most the capacity."""
        size = self.block or min(2048, 1 << max(0, self.min_particles - 1).bit_length())
        return min(self.capacity, size)

    @property
    def prefix_sizes(self) -> tuple[int, ...]:
        """Ascending prefix lengths (``block 4^j``, then the capacity) that the sorts and
        the weight arithmetic run on: the shortest holding the particles in use."""
        sizes, size = [], self.block_size
        while size < self.capacity:
            sizes.append(size)
            size *= 4
        return (*sizes, self.capacity)


class MclParams(NamedTuple):
    """Traced parameters: the map, the sensor geometry and every noise level and rate.

    Defaults (:func:`~jaxslam.localization.monte_carlo.default_params`) follow AMCL's recommended settings where it has
    them (``z_hit``, ``z_rand``, ``sigma_hit``, update thresholds, ``alpha_slow``,
    ``alpha_fast``, bin sizes) and GMapping's motion gains.
    """

    field: LikelihoodField
    free_cells: Array  # (F, 2) world centres of free cells
    beam_angles: Array  # (num_beams,) rad in the laser frame
    laser_offset: Array  # (3,) laser pose in the robot frame
    max_range: Array
    srr: Array
    srt: Array
    str_: Array
    stt: Array
    sigma_hit: Array
    z_hit: Array
    z_rand: Array
    likelihood_power: Array
    tempering_ess: Array
    ess_threshold: Array
    kld_epsilon: Array
    kld_z: Array
    alpha_slow: Array
    alpha_fast: Array
    inject_trigger: Array
    update_min_d: Array
    update_min_a: Array
    bin_xy: Array
    bin_theta: Array
    estimate_switch: Array


DEFAULTS = dict(
    srr=0.1, srt=0.2, str_=0.1, stt=0.2, sigma_hit=0.2, z_hit=0.95, z_rand=0.05, likelihood_power=1.0,
    tempering_ess=0.3,
    ess_threshold=0.5, kld_epsilon=0.02, kld_z=2.326, alpha_slow=0.001, alpha_fast=0.1, inject_trigger=0.7,
    update_min_d=0.2, update_min_a=math.pi / 6, bin_xy=0.5, bin_theta=math.radians(10.0), estimate_switch=2.0,
)
"""Default noise levels, rates and thresholds (``kld_z``: the 0.99 quantile of N(0, 1))."""


def default_params(field: LikelihoodField, free_cells, beam_angles, max_range: float,
                   laser_offset=(0.0, 0.0, 0.0), **overrides) -> MclParams:
    """:class:`~jaxslam.localization.monte_carlo.MclParams` with ``DEFAULTS``, any of them overridden by name."""
    unknown = set(overrides) - set(DEFAULTS)
    if unknown:
        raise ValueError(f"unknown MCL parameter(s) {sorted(unknown)}; known: {', '.join(sorted(DEFAULTS))}")
    dtype = field.distance.dtype
    values = {**DEFAULTS, **overrides}
    return MclParams(
        field=field, free_cells=jnp.asarray(free_cells, dtype), beam_angles=jnp.asarray(beam_angles, dtype),
        laser_offset=jnp.asarray(laser_offset, dtype), max_range=jnp.asarray(max_range, dtype),
        **{name: jnp.asarray(value, dtype) for name, value in values.items()},
    )


class MclState(NamedTuple):
    """Particles (the first ``num_active`` in use), log-weights and the MCL averages.

    Attributes:
        poses: ``(N, 3)``.
        log_weights: ``(N,)`` normalised; ``-inf`` for particles not in use.
        num_active: ``()`` int32, particles in use (slots ``0 .. n-1``).
        w_slow, w_fast: ``()`` long- and short-term mean likelihood per beam (0: unset).
        travel: ``(2,)`` odometry distance and rotation since the last measurement.
        estimate: ``(3,)`` the last step's estimate (the start pose after ``init``
            around one, NaN after a uniform start: none yet).
    """

    poses: Array
    log_weights: Array
    num_active: Array
    w_slow: Array
    w_fast: Array
    travel: Array
    estimate: Array


class MclInfo(NamedTuple):
    """What a step did. ``ess``, ``resampled``, ``ancestors`` and
    ``log_likelihood_increment`` as every filter's ``Info``: ``ess`` before
    resampling (unused slots weigh 0); ``ancestors`` ``(N,)`` the slot each particle
    was drawn from, -1 for a free-space draw (injected) and the identity without a
    resampling; ``log_likelihood_increment`` of the tempered likelihood (0 for a scan
    not used)."""

    ess: Array
    resampled: Array
    ancestors: Array
    log_likelihood_increment: Array
    particles: Array  # () particles in use after the step
    injected: Array  # () particles replaced by free-space draws
    updated: Array  # () whether the scan was used
    estimate: Array  # (3,)
    cluster_weight: Array  # () weight within the estimate's bins
    spread: Array  # () weighted xy standard deviation of the cloud (m)
    occupied_bins: Array  # () KLD bins of the resampling draw (0 without one)
    w_slow: Array
    w_fast: Array


def kld_bound(bins: Array, epsilon, z) -> Array:
    """Fox's KLD-sampling particle number for ``bins`` occupied bins (float)."""
    k = jnp.maximum(bins.astype(jnp.result_type(float)) - 1.0, 1.0)
    b = 2.0 / (9.0 * k)
    n = k / (2.0 * epsilon) * (1.0 - b + jnp.sqrt(b) * z) ** 3
    return jnp.where(bins > 1, n, 1.0)


def pose_bins(poses: Array, bin_xy, bin_theta) -> Array:
    """``(N, 3)`` int32 bin coordinates of poses."""
    ix = jnp.floor(poses[:, 0] / bin_xy)
    iy = jnp.floor(poses[:, 1] / bin_xy)
    it = jnp.floor((se2.wrap_angle(poses[:, 2]) + math.pi) / bin_theta)
    return jnp.stack([ix, iy, it], -1).astype(jnp.int32)


_NO_BIN = np.iinfo(np.int32).max  # the key of rows left out: after every bin's key


def bin_keys(bins: Array) -> Array:
    """``(N,)`` int32 key of each bin ``(ix, iy, itheta)``: 12 bits of ``ix``, 12 of ``iy``
    and 6 of ``itheta``, in ``[0, 2^30)``.

    Distinct bins have distinct keys while the bins span under 4,096 cells in x and in y
    (2,048 m at 0.5 m bins) and the heading has at most 64 bins (bins of at least 5.6
    deg; 36 at the default 10 deg); beyond that the coordinates wrap, and bins 4,096
    cells apart (or headings 64 bins apart) share a key. A shared key only merges bins,
    so the KLD count errs towards fewer bins and the mode towards a heavier one.
    """
    b = bins.astype(jnp.int32)
    return ((b[:, 0] & 0xFFF) << 18) | ((b[:, 1] & 0xFFF) << 6) | (b[:, 2] & 0x3F)


class Blocks(NamedTuple):
    """How a step walks the slots in use: ``capacity`` slots in blocks of ``block``
    (the last one starting at ``capacity - block`` at most), and the prefix lengths
    ``sizes`` (ascending, the last the capacity) a sort runs on."""

    capacity: int
    block: int
    sizes: tuple[int, ...]

    def rows(self, num: Array, fn, source, out):
        """``out`` with ``fn(start, source[block rows])`` written over the blocks holding
        slots ``0 .. num-1`` (``source``, ``out`` and what ``fn`` returns: arrays or trees
        of arrays with the slots first). The last block may overlap the one before it;
        ``fn`` reads only ``source``, so a slot written twice gets the same value."""

        def body(b, acc):
            start = jnp.minimum(b * self.block, self.capacity - self.block)
            rows = jax.tree.map(lambda x: jax.lax.dynamic_slice_in_dim(x, start, self.block), source)
            return jax.tree.map(lambda a, v: jax.lax.dynamic_update_slice_in_dim(a, v, start, 0), acc,
                                fn(start, rows))

        return jax.lax.fori_loop(0, (num + self.block - 1) // self.block, body, out)

    def sort(self, num: Array, keys: Array, *values: Array) -> tuple[Array, ...]:
        """``keys`` ``(capacity,)`` sorted, ``values`` in the same order, for keys that
        are ``_NO_BIN`` from slot ``num`` on: only the shortest prefix of ``sizes``
        holding ``num`` slots is sorted."""

        def branch(size):
            def run(*arrays):
                head = jax.lax.sort([x[:size] for x in arrays], num_keys=1)
                return tuple(jnp.concatenate([h, x[size:]]) for h, x in zip(head, arrays))
            return run

        level = jnp.minimum(jnp.searchsorted(jnp.asarray(self.sizes), num), len(self.sizes) - 1)
        return jax.lax.switch(level, [branch(size) for size in self.sizes], keys, *values)


def _distinct(sorted_keys: Array) -> Array:
    """Distinct keys other than ``_NO_BIN`` in sorted keys."""
    first = jnp.concatenate([jnp.ones((1,), bool), sorted_keys[1:] != sorted_keys[:-1]])
    return jnp.sum(first & (sorted_keys != _NO_BIN)).astype(jnp.int32)


def count_bins(bins: Array, mask: Array) -> Array:
    """Distinct bins (distinct :func:`bin_keys`) among the rows of ``bins`` where ``mask``."""
    return _distinct(jnp.sort(jnp.where(mask, bin_keys(bins), _NO_BIN)))


def _mode(blocks: Blocks, num: Array, poses: Array, log_weights: Array, bin_xy, bin_theta):
    """:func:`mode_estimate` of the slots below ``num`` (slot 0 in use); the others are never read."""
    dtype = poses.dtype
    held = (jnp.arange(blocks.capacity) < num) & (log_weights > -jnp.inf)
    weights = jnp.where(held, jnp.exp(normalize_log_weights(jnp.where(held, log_weights, -jnp.inf))), 0.0)
    poses = jnp.where(held[:, None], poses, poses[0])
    no_bin = jnp.full((blocks.capacity,), _NO_BIN, jnp.int32)
    keys = blocks.rows(num, lambda start, rows: bin_keys(pose_bins(rows, bin_xy, bin_theta)), poses, no_bin)
    keys = jnp.where(held, keys, _NO_BIN)
    ordered, ordered_weights = blocks.sort(num, keys, weights)
    # each bin's mass: the running sum at its last place less the one before its first
    total = jnp.cumsum(ordered_weights)
    first = jnp.concatenate([jnp.ones((1,), bool), ordered[1:] != ordered[:-1]])
    last = jnp.concatenate([ordered[1:] != ordered[:-1], jnp.ones((1,), bool)]) & (ordered != _NO_BIN)
    before = jax.lax.cummax(jnp.where(first, total - ordered_weights, 0.0))
    best = ordered[jnp.argmax(jnp.where(last, total - before, -1.0))]
    anchor = pose_bins(poses[jnp.argmax(keys == best)][None], bin_xy, bin_theta)[0]
    anchor = anchor.astype(dtype)
    centre_xy = (anchor[:2] + 0.5) * bin_xy
    centre_t = (anchor[2] + 0.5) * bin_theta - math.pi
    near = _near(poses, jnp.concatenate([centre_xy, centre_t[None]]), bin_xy, bin_theta)
    local = jnp.where(near & held, weights, 0.0)
    cluster_weight = jnp.sum(local)
    estimate = se2.pose_mean(poses, local / jnp.maximum(cluster_weight, jnp.finfo(dtype).tiny))
    mean_xy = jnp.sum(weights[:, None] * poses[:, :2], 0)
    spread = jnp.sqrt(jnp.sum(weights * jnp.sum(jnp.square(poses[:, :2] - mean_xy), -1)))
    return estimate, cluster_weight, spread


def _near(poses: Array, centre: Array, bin_xy, bin_theta) -> Array:
    """The poses within 1.5 bins of ``centre`` in position (each axis) and heading."""
    return (jnp.all(jnp.abs(poses[:, :2] - centre[:2]) <= 1.5 * bin_xy, -1)
            & (jnp.abs(se2.wrap_angle(poses[:, 2] - centre[2])) <= 1.5 * bin_theta))


def _kept_estimate(previous: Array, estimate: Array, cluster_weight: Array, active: Array, poses: Array,
                   log_weights: Array, params: MclParams) -> tuple[Array, Array]:
    """The estimate and its cluster's weight, given the mode's: the cluster around
    ``previous`` (the last estimate moved by the odometry; NaN: none) is kept while the
    mode's cluster lies elsewhere and holds less than ``estimate_switch`` times its
    weight."""
    dtype = poses.dtype
    weights = jnp.where(active, jnp.exp(jnp.where(active, log_weights, -jnp.inf)), 0.0)
    poses = jnp.where(active[:, None], poses, poses[0])  # slots not in use are never read
    local = jnp.where(_near(poses, previous, params.bin_xy, params.bin_theta), weights, 0.0)
    held = jnp.sum(local)
    elsewhere = ~_near(previous[None], estimate, params.bin_xy, params.bin_theta)[0]
    keep = jnp.all(jnp.isfinite(previous)) & elsewhere & (held > 0) & (cluster_weight < params.estimate_switch * held)
    mean = se2.pose_mean(poses, local / jnp.maximum(held, jnp.finfo(dtype).tiny))
    return jnp.where(keep, mean, estimate), jnp.where(keep, held, cluster_weight)


def mode_estimate(poses: Array, log_weights: Array, bin_xy, bin_theta) -> tuple[Array, Array, Array]:
    """``(estimate (3,), cluster_weight, spread)``: the weighted circular mean within 1.5
    bins of the heaviest bin, its weight, and the cloud's weighted xy spread (rows of
    weight zero are not read; row 0 must have weight)."""
    n = poses.shape[0]
    return _mode(Blocks(n, n, (n,)), jnp.asarray(n), poses, log_weights, bin_xy, bin_theta)


def tempering_power(log_weights: Array, loglik: Array, max_power, min_ess, iterations: int = 20) -> Array:
    """The largest power ``lam <= max_power`` with ``ESS(log_weights + lam loglik) >= min_ess``.

    Adaptive tempering (Jasra et al. 2011): the ESS falls as the power grows, so a
    bisection on ``log lam`` over ``[max_power 1e-6, max_power]`` finds it; where even
    the smallest power leaves fewer effective particles, that smallest power.
    """
    dtype = loglik.dtype
    finite = jnp.isfinite(log_weights)
    lik = jnp.where(finite, loglik, 0.0)

    def ess(lam):
        return effective_sample_size(jnp.where(finite, log_weights + lam * lik, -jnp.inf))

    top = jnp.asarray(max_power, dtype)
    lo0, hi0 = jnp.log(top) + jnp.log(jnp.asarray(1e-6, dtype)), jnp.log(top)

    def bisect(_, bounds):
        lo, hi = bounds
        mid = 0.5 * (lo + hi)
        enough = ess(jnp.exp(mid)) >= min_ess
        return jnp.where(enough, mid, lo), jnp.where(enough, hi, mid)

    lo, _ = jax.lax.fori_loop(0, iterations, bisect, (lo0, hi0))
    return jnp.where(ess(top) >= min_ess, top, jnp.exp(lo))


def sample_free_poses(key: Array, free_cells: Array, resolution, yaw, num: int) -> Array:
    """``(num, 3)`` poses uniform over the free cells (uniform in each cell, any heading)."""
    k_cell, k_offset, k_heading = jax.random.split(key, 3)
    dtype = free_cells.dtype
    cells = free_cells[jax.random.randint(k_cell, (num,), 0, free_cells.shape[0])]
    offset = (jax.random.uniform(k_offset, (num, 2), dtype) - 0.5) * resolution
    c, s = jnp.cos(yaw), jnp.sin(yaw)
    xy = cells + jnp.stack([c * offset[:, 0] - s * offset[:, 1], s * offset[:, 0] + c * offset[:, 1]], -1)
    heading = jax.random.uniform(k_heading, (num,), dtype, -math.pi, math.pi)
    return jnp.concatenate([xy, heading[:, None]], -1)


def scan_log_likelihood(params: MclParams, pose: Array, ranges: Array, use: Array, angles: Array) -> Array:
    """``sum_k log p(z^k | x, m)`` over the used beams of one particle (untempered)."""
    laser = se2.compose(pose, params.laser_offset)
    heading = laser[2] + angles
    r = jnp.where(use, ranges, 0.0)
    ends = laser[:2] + r[:, None] * jnp.stack([jnp.cos(heading), jnp.sin(heading)], -1)
    per_beam = beam_log_likelihood(distance_at(params.field, ends), params.sigma_hit, params.z_hit,
                                   params.z_rand, params.max_range)
    return jnp.sum(jnp.where(use, per_beam, 0.0))


def mcl(config: MclConfig, params: MclParams) -> ParticleFilter:
    """Augmented, KLD-adaptive Monte Carlo localization in ``params.field``'s map.

    Args:
        config: static sizes (:class:`~jaxslam.localization.monte_carlo.MclConfig`).
        params: the map's field, free cells, sensor geometry and noise levels
            (:func:`~jaxslam.localization.monte_carlo.default_params`).

    Returns:
        ``ParticleFilter(init, step)``: ``init(key, pose=None, pose_std=None)`` draws
        the full capacity uniformly over free space when ``pose`` is None (global
        localization), else around ``pose`` with standard deviations ``pose_std``
        ``(3,)``; ``step(key, state, increment (3,), scan)`` as in the module docstring.
    """
    capacity = config.capacity
    blocks = Blocks(capacity, config.block_size, config.prefix_sizes)
    block = blocks.block
    beams = jnp.asarray(config.beam_indices)
    dtype = params.field.distance.dtype
    slots = jnp.arange(capacity, dtype=jnp.int32)
    no_bin = jnp.full((capacity,), _NO_BIN, jnp.int32)

    def init(key: Array, pose: Array | None = None, pose_std: Array | None = None) -> MclState:
        if pose is None:
            poses = sample_free_poses(key, params.free_cells, params.field.resolution, params.field.origin[2], capacity)
        else:
            pose = jnp.asarray(pose, dtype)
            std = jnp.asarray(pose_std if pose_std is not None else (0.1, 0.1, 0.05), dtype)
            chex.assert_shape([pose, std], (3,))
            poses = pose + jax.random.normal(key, (capacity, 3), dtype) * std
            poses = poses.at[:, 2].set(se2.wrap_angle(poses[:, 2]))
        zero = jnp.zeros((), dtype)
        return MclState(
            poses=poses, log_weights=jnp.full((capacity,), -jnp.log(jnp.asarray(capacity, dtype))),
            num_active=jnp.asarray(capacity, jnp.int32), w_slow=zero, w_fast=zero,
            travel=jnp.full((2,), jnp.inf, dtype),
            estimate=jnp.full((3,), jnp.nan, dtype) if pose is None else pose,
        )

    def step(key: Array, state: MclState, control: Array, observation: Scan) -> tuple[MclState, MclInfo]:
        chex.assert_shape(control, (3,))
        chex.assert_shape(state.poses, (capacity, 3))
        k_motion, k_draw, k_coin, k_free = jax.random.split(key, 4)
        increment = jnp.asarray(control, dtype)
        num = state.num_active
        active = slots < num

        def move(start, rows):
            # a key per slot: a particle's draw does not depend on the blocks that run
            keys = jax.vmap(jax.random.fold_in, (None, 0))(k_motion, start + jnp.arange(block))
            return jax.vmap(sample_gmapping, (0, 0, None, None, None, None, None))(
                keys, rows, increment, params.srr, params.srt, params.str_, params.stt)

        poses = blocks.rows(num, move, state.poses, state.poses)
        travel = state.travel + jnp.stack([jnp.hypot(increment[0], increment[1]), jnp.abs(increment[2])])
        ranges = observation.ranges[beams].astype(dtype)
        use = observation.valid[beams] & jnp.isfinite(ranges) & (ranges > 0) & (ranges < params.max_range)
        angles = params.beam_angles[beams] + jnp.asarray(observation.angle_offset, dtype)
        used_beams = jnp.sum(use)
        updated = ((travel[0] >= params.update_min_d) | (travel[1] >= params.update_min_a)) & (used_beams > 0)

        def measure(start, rows):
            return jax.vmap(scan_log_likelihood, (None, 0, None, None, None))(params, rows, ranges, use, angles)

        zeros = jnp.zeros((capacity,), dtype)
        loglik = jax.lax.cond(updated, lambda p: blocks.rows(num, measure, p, zeros), lambda p: zeros, poses)
        loglik = jnp.where(active & jnp.isfinite(loglik), loglik, jnp.where(active, -jnp.inf, 0.0))
        prior = jnp.where(active, state.log_weights, -jnp.inf)
        power = tempering_power(prior, loglik, params.likelihood_power, params.tempering_ess * num)
        power = jnp.where(updated, power, 0.0)
        tempered = prior + power * loglik
        increment_ll = jnp.where(updated, logsumexp(tempered), 0.0)
        mean_beam = jnp.where(updated, logsumexp(prior + loglik) / jnp.maximum(used_beams, 1), 0.0)
        w_avg = jnp.exp(mean_beam)
        w_slow = jnp.where(state.w_slow > 0, state.w_slow + params.alpha_slow * (w_avg - state.w_slow), w_avg)
        w_fast = jnp.where(state.w_fast > 0, state.w_fast + params.alpha_fast * (w_avg - state.w_fast), w_avg)
        w_slow = jnp.where(updated, w_slow, state.w_slow)
        w_fast = jnp.where(updated, w_fast, state.w_fast)
        log_weights = jnp.where(updated, normalize_log_weights(tempered), prior)
        ess = effective_sample_size(log_weights)
        inject_p = jnp.maximum(0.0, 1.0 - safe_divide(w_fast, w_slow, 1.0, updated & (w_slow > 0)))
        inject_p = jnp.where(inject_p > params.inject_trigger, inject_p, 0.0)
        resampled = updated & ((ess < params.ess_threshold * num.astype(dtype)) | (inject_p > 0))
        estimate, cluster_weight, spread = _mode(blocks, num, poses, log_weights, params.bin_xy, params.bin_theta)
        estimate, cluster_weight = _kept_estimate(se2.compose(state.estimate, increment), estimate, cluster_weight,
                                                  active, poses, log_weights, params)

        def draw(key, cdf, m, start):
            # rows start .. start+block of a systematic draw of m from the weights, each
            # replaced by a free-space pose with probability p: (ancestor or -1, pose)
            ancestor = jnp.clip(systematic_rows(key, cdf, m, start, block), 0, num - 1).astype(jnp.int32)
            coin = jax.random.uniform(jax.random.fold_in(k_coin, start), (block,), dtype) < inject_p
            fresh = sample_free_poses(jax.random.fold_in(k_free, start), params.free_cells, params.field.resolution,
                                      params.field.origin[2], block)
            return jnp.where(coin, -1, ancestor), jnp.where(coin[:, None], fresh, poses[ancestor])

        def resample(_):
            # KLD: the bins of a draw of the particles in use (all of the capacity when
            # injecting: a uniform cloud needs them) bound the cloud; while the bound asks
            # for more than drawn, draw twice as many; when it asks for fewer, the cloud
            # is a draw of that many (the same rule)
            cdf = jnp.cumsum(jnp.exp(log_weights))  # once per resampling, read by every block of every draw

            def more(carry):
                m, final, bins, _, done = carry

                def draw_rows(start, _):
                    ancestor, mixed = draw(k_draw, cdf, m, start)
                    keys = bin_keys(pose_bins(mixed, params.bin_xy, params.bin_theta))
                    return mixed, ancestor, jnp.where(start + jnp.arange(block) < m, keys, _NO_BIN)

                drawn = blocks.rows(m, draw_rows, no_bin, (poses, slots, no_bin))
                counted = _distinct(blocks.sort(m, drawn[2])[0])
                target = jnp.clip(jnp.ceil(kld_bound(counted, params.kld_epsilon, params.kld_z)),
                                  config.min_particles, capacity).astype(jnp.int32)
                grow = ~final & (target > m) & (m < capacity)
                shrink = ~final & ~grow & (target < m)
                next_m = jnp.where(grow, jnp.minimum(2 * m, capacity), jnp.where(shrink, target, m))
                return next_m, shrink, jnp.where(final, bins, counted), drawn[:2], ~grow & ~shrink

            first = jnp.where(inject_p > 0, capacity, num).astype(jnp.int32)
            start = (first, jnp.zeros((), bool), jnp.zeros((), jnp.int32), (poses, slots), jnp.zeros((), bool))
            new_n, _, bins, (new_poses, ancestors), _ = jax.lax.while_loop(lambda c: ~c[-1], more, start)
            in_use = slots < new_n
            ancestors = jnp.where(in_use, ancestors, slots)
            return (new_poses, jnp.where(in_use, -jnp.log(new_n.astype(dtype)), -jnp.inf).astype(dtype), new_n,
                    ancestors, jnp.sum(in_use & (ancestors < 0)).astype(jnp.int32), bins)

        def keep(_):
            return (poses, log_weights, num, slots, jnp.zeros((), jnp.int32), jnp.zeros((), jnp.int32))

        new_poses, new_log_weights, new_n, ancestors, injected, bins = jax.lax.cond(resampled, resample, keep, None)
        new_state = MclState(
            poses=new_poses, log_weights=new_log_weights, num_active=new_n,
            w_slow=w_slow.astype(dtype), w_fast=w_fast.astype(dtype),
            travel=jnp.where(updated, jnp.zeros((2,), dtype), travel),
            estimate=estimate,
        )
        info = MclInfo(
            ess=ess, resampled=resampled, ancestors=ancestors,
            log_likelihood_increment=increment_ll, particles=new_state.num_active, injected=injected,
            updated=updated, estimate=estimate, cluster_weight=cluster_weight, spread=spread,
            occupied_bins=bins, w_slow=w_slow, w_fast=w_fast,
        )
        return new_state, info

    return ParticleFilter(init, step)


__all__ = [
    "DEFAULTS",
    "MclConfig",
    "MclInfo",
    "MclParams",
    "MclState",
    "bin_keys",
    "count_bins",
    "default_params",
    "kld_bound",
    "mcl",
    "mode_estimate",
    "pose_bins",
    "sample_free_poses",
    "scan_log_likelihood",
]
