"""`permutation(key, n)`: `jax.random.permutation(key, n)` bit for bit, sorted faster on XLA CPU.

PPO draws a permutation of its rollout's rows every epoch (agents/ppo.py). `jax.random.permutation`
draws `rounds(n)` arrays of random u32 keys and stable-sorts the indices by each in turn with
`lax.sort_key_val`. XLA CPU sorts key-value pairs through a compiled comparator (70 ms for 163,840
pairs on the development machine: 12-14% of a PPO episode's op time, docs/benchmarks.md "where
PPO's time goes"), but a single u32 array on a fast path (11 ms). Here each stable argsort is a
least-significant-digit radix sort whose passes are such single-array sorts: a pass sorts the
words `digit << b | position`, b the bits of n - 1, so every word is unique and the pass keeps the
order of equal digits (stable); (32 / (32 - b)) passes cover a key: 3 for PPO's 163,840 rows,
2 for 32,768. The same keys are drawn from the same key splits as jax's, so the result is the
same permutation (tests/test_shuffle.py compares the two, and the radix sort with numpy's stable
argsort on keys full of ties).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

EXPONENT = 3  # jax's rounds heuristic (jax/_src/random: tjablin's analysis)


def rounds(n: int) -> int:
    """Sorting rounds `jax.random.permutation` makes for n elements."""
    return int(np.ceil(EXPONENT * np.log(max(1, n)) / np.log(np.iinfo(np.uint32).max)))


def stable_argsort_u32(keys: jax.Array) -> jax.Array:
    """`jnp.argsort(keys, stable=True)` (int32) for u32 keys [n], by single-array sorts."""
    n = keys.shape[0]
    b = max(1, (n - 1).bit_length())  # bits of a position
    if b > 24:  # digits of under 8 bits: more passes than the pair sort is worth
        return jnp.argsort(keys, stable=True).astype(jnp.int32)
    digit, mask = 32 - b, jnp.uint32((1 << b) - 1)
    positions = jnp.arange(n, dtype=jnp.uint32)
    order = None  # the indices sorted by the digits so far (None: 0..n-1)
    for shift in range(0, 32, digit):
        d = (keys if order is None else keys[order]) >> shift
        d = d & jnp.uint32((1 << min(digit, 32 - shift)) - 1)
        slots = (jnp.sort((d << b) | positions) & mask).astype(jnp.int32)
        order = slots if order is None else order[slots]
    return order


def permutation(key: jax.Array, n: int) -> jax.Array:
    """A random permutation of range(n), int32: `jax.random.permutation(key, n)`'s own. Off the
    CPU backend it is jax's call itself (the radix passes are measured faster on XLA CPU only)."""
    if jax.default_backend() != "cpu":
        return jax.random.permutation(key, n).astype(jnp.int32)
    x = jnp.arange(n, dtype=jnp.int32)
    for _ in range(rounds(n)):
        key, subkey = jax.random.split(key)
        x = x[stable_argsort_u32(jax.random.bits(subkey, (n,), jnp.uint32))]
    return x
