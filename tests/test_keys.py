"""jaxslam.runtime.keys: keys made on the host are JAX's, bit for bit."""

from __future__ import annotations

import jax
import numpy as np
import pytest

from jaxslam.runtime.keys import seed_key, split_keys, threefry2x32


@pytest.mark.parametrize("seed", [0, 1, 7, 42, 123456789, 2**31 - 1, -1, -5, -(2**31), np.int32(3), np.int64(9)])
def test_seed_key_is_prngkey(seed):
    np.testing.assert_array_equal(seed_key(seed), np.asarray(jax.random.PRNGKey(seed)))
    assert seed_key(seed).dtype == np.uint32


@pytest.mark.parametrize("seed", [0, 5, -1, -(2**33), 2**40 + 3, 2**63 - 1])
def test_seed_key_is_prngkey_with_64_bit_types(seed):
    with jax.enable_x64(True):
        np.testing.assert_array_equal(seed_key(seed), np.asarray(jax.random.PRNGKey(seed)))


@pytest.mark.parametrize("seed", [0, 3, 2**31 - 1, -7])
@pytest.mark.parametrize("num", [1, 2, 5, 1000, 13631])
def test_split_keys_is_jax_split(seed, num):
    key = np.asarray(jax.random.PRNGKey(seed))
    np.testing.assert_array_equal(split_keys(key, num), np.asarray(jax.random.split(key, num)))


def test_split_of_a_split_key_and_the_hash_itself():
    key = np.asarray(jax.random.split(jax.random.PRNGKey(11), 3))[2]
    np.testing.assert_array_equal(split_keys(key, 64), np.asarray(jax.random.split(key, 64)))
    # Threefry-2x32's known-answer test (Salmon et al.'s Random123, 20 rounds): key and
    # counters all ones.
    ones = np.uint32(0xFFFFFFFF)
    out = threefry2x32(ones, ones, np.array([ones]), np.array([ones]))
    assert (int(out[0][0]), int(out[1][0])) == (0x1CB996FC, 0xBB002BE7)


def test_a_key_that_is_not_raw_threefry_goes_to_jax():
    typed = jax.random.key(4)
    np.testing.assert_array_equal(np.asarray(jax.random.key_data(split_keys(typed, 3))),
                                  np.asarray(jax.random.key_data(jax.random.split(typed, 3))))
    with jax.threefry_partitionable(False):
        key = np.asarray(jax.random.PRNGKey(2))
        np.testing.assert_array_equal(np.asarray(split_keys(key, 6)), np.asarray(jax.random.split(key, 6)))
