r"""PRNG keys made on the host: the bits of ``jax.random.PRNGKey(seed)`` and of
``jax.random.split(key, n)`` computed with NumPy, without running a JAX program.

Called eagerly, each of those runs a small compiled program of its own (``stage`` and
``_threefry_seed`` for the seed, ``_threefry_split`` for the split, the last one
compiled again for every step count ``n``). A cold grid run compiled the three in about
0.7 s of XLA time and looked them up in the compilation cache when warm, before its
filter's own programs. The driver (:func:`jaxslam.grid.driver.run_filter`) and
:func:`jaxslam.grid.experiment.run_grid_slam` make their keys here instead; inside a
traced program :func:`jaxslam.runtime.driver.step_keys` stays ``jax.random.split``.

JAX's default key is a pair of 32-bit words. ``PRNGKey(seed)`` is :math:`(k_1, k_2) =
(\lfloor s / 2^{32} \rfloor, s \bmod 2^{32})` of the seed as JAX's integer type (so a
negative 32-bit seed has :math:`k_1 = 0`, and :math:`2^{32} - 1` under 64-bit types),
and with JAX's partitionable Threefry (``jax_threefry_partitionable``, the default)
``split(key, n)[t]`` is the Threefry-2x32 hash (Salmon et al. 2011, 20 rounds) of the
counter pair :math:`(\lfloor t / 2^{32} \rfloor, t \bmod 2^{32})` under the key.
Where JAX is configured otherwise (another PRNG implementation, the older split), the
functions call JAX. Tests compare them with JAX bit for bit
(``tests/test_keys.py``).
"""

from __future__ import annotations

import numpy as np

ROTATIONS = ((13, 15, 26, 6), (17, 29, 16, 24))
"""Threefry-2x32's rotation constants, alternating groups of four rounds."""

PARITY = np.uint32(0x1BD11BDA)
"""Threefry's key-schedule parity constant."""

__all__ = ["PARITY", "ROTATIONS", "host_keys_supported", "seed_key", "split_keys", "threefry2x32"]


def host_keys_supported() -> bool:
    """Whether JAX's keys are the raw Threefry-2x32 keys with the partitionable split,
    which this module reproduces."""
    import jax

    return (str(jax.config.jax_default_prng_impl) == "threefry2x32"
            and bool(jax.config.jax_threefry_partitionable))


def _rotl(x: np.ndarray, r: int) -> np.ndarray:
    return (x << np.uint32(r)) | (x >> np.uint32(32 - r))


def threefry2x32(k1, k2, x1: np.ndarray, x2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The Threefry-2x32 hash of the counters ``(x1, x2)`` (uint32 arrays) under the
    key ``(k1, k2)``: five groups of four rounds, a key injection after each."""
    with np.errstate(over="ignore"):
        ks = (np.uint32(k1), np.uint32(k2), np.uint32(k1) ^ np.uint32(k2) ^ PARITY)
        x = [np.asarray(x1, np.uint32) + ks[0], np.asarray(x2, np.uint32) + ks[1]]
        for i in range(5):
            for r in ROTATIONS[i % 2]:
                x[0] = x[0] + x[1]
                x[1] = _rotl(x[1], r) ^ x[0]
            x[0] = x[0] + ks[(i + 1) % 3]
            x[1] = x[1] + ks[(i + 2) % 3] + np.uint32(i + 1)
    return x[0], x[1]


def seed_key(seed: int) -> np.ndarray:
    """``jax.random.PRNGKey(seed)`` as a NumPy ``uint32 (2,)`` array."""
    import jax

    if not host_keys_supported() or isinstance(seed, (bool, np.bool_)):
        return np.asarray(jax.random.PRNGKey(seed))
    seed = int(seed)
    x64 = bool(jax.config.jax_enable_x64)
    low, high = (-(2**63), 2**63) if x64 else (-(2**31), 2**31)
    if not low <= seed < high:  # JAX's own error for a seed its integer type cannot hold
        return np.asarray(jax.random.PRNGKey(seed))
    bits = seed % (2**64 if x64 else 2**32)  # the seed's two's complement in its type
    k1 = (bits >> 32) & 0xFFFFFFFF
    return np.array([k1, bits & 0xFFFFFFFF], np.uint32)


def split_keys(key, num: int) -> np.ndarray:
    """``jax.random.split(key, num)`` of a raw ``uint32 (2,)`` key, as NumPy
    ``uint32 (num, 2)`` (any other key: JAX's split itself)."""
    import jax

    raw = getattr(key, "dtype", None) == np.uint32 and np.shape(key) == (2,)
    if not raw or not host_keys_supported():  # a typed key, or JAX configured otherwise
        return jax.random.split(key, num)
    key = np.asarray(key)
    count = np.arange(int(num), dtype=np.uint64)
    high = (count >> np.uint64(32)).astype(np.uint32)
    low = (count & np.uint64(0xFFFFFFFF)).astype(np.uint32)
    bits1, bits2 = threefry2x32(key[0], key[1], high, low)
    return np.stack([bits1, bits2], axis=-1)
