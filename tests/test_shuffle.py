"""agents/shuffle.py: PPO's faster permutation is jax.random.permutation's own, and its radix sort
is a stable argsort (numpy's, as the reference)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from fedjax_nav.agents import shuffle


@pytest.mark.parametrize("n", [1, 2, 3, 17, 1000, 32768, 163840])
def test_the_permutation_is_jaxs_bit_for_bit(n):
    for seed in (0, 1, 7):
        key = jax.random.key(seed)
        ours = jax.jit(shuffle.permutation, static_argnums=1)(key, n)
        assert ours.dtype == jnp.int32
        np.testing.assert_array_equal(ours, jax.random.permutation(key, n))


def test_the_permutation_is_jaxs_under_vmap():
    keys = jax.random.split(jax.random.key(3), 4)
    ours = jax.jit(jax.vmap(lambda k: shuffle.permutation(k, 5000)))(keys)
    np.testing.assert_array_equal(ours, jax.vmap(lambda k: jax.random.permutation(k, 5000))(keys))


@pytest.mark.parametrize("n, values", [(10, 2), (5000, 3), (40000, 1 << 20), (70000, 1 << 32)])
def test_the_radix_argsort_is_a_stable_argsort(n, values):
    rng = np.random.default_rng(n)
    keys = rng.integers(0, values, n, dtype=np.uint64).astype(np.uint32)  # ties when values is small
    got = jax.jit(shuffle.stable_argsort_u32)(jnp.asarray(keys))
    np.testing.assert_array_equal(got, np.argsort(keys, kind="stable"))


def test_the_rounds_are_jaxs():
    # jax sorts twice above 1,625 elements (the heuristic 3 log n / log(2^32 - 1))
    assert [shuffle.rounds(n) for n in (1, 2, 1625, 1626, 163840)] == [0, 1, 1, 2, 2]
