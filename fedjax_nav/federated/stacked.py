"""Pytrees stacked over clients (every leaf `[K, ...]`): the few operations every federated rule,
robust center and attack shares, written once.

The weighted sum is a multiply-and-reduce, never a `dot`: on GPUs a dot may run in TF32, and the
soft FedAvg of the thesis and the robust rules' mean must agree to the bit on every backend
(on this CPU the two forms are bitwise equal for up to 8 clients; tests/test_programme_fingerprint.py
holds the thesis programme to the numbers it had with a dot).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp


def rows(v: jax.Array, leaf: jax.Array) -> jax.Array:
    """A per-client vector [K] shaped to broadcast against a stacked leaf [K, ...]."""
    return v.reshape(v.shape + (1,) * (leaf.ndim - 1))


def num_clients(params) -> int:
    """K, the (static) leading axis shared by every leaf; ValueError when leaves disagree."""
    leaves = jax.tree.leaves(params)
    if not leaves:
        raise ValueError("params has no leaves")
    k = leaves[0].shape[0] if leaves[0].ndim else None
    if k is None or any(x.ndim == 0 or x.shape[0] != k for x in leaves):
        raise ValueError(
            f"every leaf of params must be stacked [K, ...] with one K; got shapes {[tuple(x.shape) for x in leaves]}"
        )
    return k


def weighted_sum(params, w: jax.Array):
    """sum_k w_k theta_k (w f32[K]) over the client axis, accumulated in at least float32 and
    returned in each leaf's dtype."""

    def leaf(p):
        acc = jnp.promote_types(p.dtype, jnp.float32)
        return jnp.sum(rows(w.astype(acc), p) * p.astype(acc), axis=0).astype(p.dtype)

    return jax.tree.map(leaf, params)


def select(mask: jax.Array, a, b):
    """Row k of every leaf from `a` where mask[k], else from `b` (mask bool[K])."""
    return jax.tree.map(lambda x, y: jnp.where(rows(mask, x), x, y), a, b)


def zero_out(params, mask: jax.Array):
    """Rows outside `mask` set to 0, so that inf/NaN there cannot leak through a product."""
    return jax.tree.map(lambda p: jnp.where(rows(mask, p), p, jnp.zeros((), p.dtype)), params)


def mean_over_clients(params):
    """The plain mean over the client axis (a pytree without it)."""
    return jax.tree.map(lambda p: jnp.mean(p, axis=0), params)
