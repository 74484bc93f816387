"""A jittable `Box` space in gymnax's shape, for `NavEnv.observation_space` / `action_space`.

gymnax (`gymnax.environments.spaces`) is not a dependency of this package and is not installed
here (rejax 0.1.3, its main user, pins `gymnax<1.0`), so the one space the navigation task needs
is written out: the same constructor `Box(low, high, shape, dtype)`, `sample(key)` and
`contains(x)`, so code written against gymnax's spaces works with it unchanged. No gymnasium
import: `to_gymnasium` converts on demand (gymnasium is an optional extra).
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np


class Box:
    """An array-shaped space with per-element bounds, as gymnax's `spaces.Box`.

    low, high: scalars or arrays broadcastable to `shape` (jnp or numpy; may be traced).
    shape: tuple of ints. dtype: the sample dtype (default float32).
    """

    def __init__(self, low: Any, high: Any, shape: tuple[int, ...], dtype: Any = jnp.float32):
        self.low = low
        self.high = high
        self.shape = tuple(shape)
        self.dtype = dtype

    def sample(self, key: jax.Array) -> jax.Array:
        """A uniform draw in [low, high) (jittable): `dtype[shape]`."""
        return jax.random.uniform(key, self.shape, minval=self.low, maxval=self.high).astype(self.dtype)

    def contains(self, x: jax.Array) -> jax.Array:
        """bool[]: every element of `x` within [low, high] (jittable; the shape is not checked, as in gymnax)."""
        return jnp.logical_and(jnp.all(x >= self.low), jnp.all(x <= self.high))

    def to_gymnasium(self):
        """The equal `gymnasium.spaces.Box` (needs concrete bounds and gymnasium installed)."""
        from gymnasium import spaces  # optional extra

        dtype = np.dtype(self.dtype)
        low = np.broadcast_to(np.asarray(self.low, dtype), self.shape)
        high = np.broadcast_to(np.asarray(self.high, dtype), self.shape)
        return spaces.Box(low, high, self.shape, dtype=dtype)

    def __repr__(self) -> str:
        return f"Box(shape={self.shape}, dtype={np.dtype(self.dtype).name})"
