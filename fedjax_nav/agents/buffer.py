"""A jittable ring replay buffer for one learner (vmap it for several).

Rows are allocated once (`alloc`, static); the active capacity is a traced value <= alloc, so a
sweep over buffer sizes compiles once. The write position and fill level are derived from the
number of rows ever written (`count`), which the trainer knows from the global step.

A hand-written ring buffer measured 0.6-0.8 ms per add+sample here against 1.0-3.2 ms for
flashbax (measured on this 2-core CPU when the project started), and keeps the state a plain
pytree we can checkpoint.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct


@struct.dataclass
class Transition:
    obs: jax.Array  # f32[..., obs]
    action: jax.Array  # f32[..., 2]
    reward: jax.Array  # f32[...]
    next_obs: jax.Array  # f32[..., obs]
    done: jax.Array  # f32[...] 1 on terminal (goal/collision), 0 otherwise (time-outs included)


def init(alloc: int, obs_size: int, action_size: int = 2) -> Transition:
    z = lambda *s: jnp.zeros((alloc, *s), jnp.float32)  # noqa: E731
    return Transition(obs=z(obs_size), action=z(action_size), reward=z(), next_obs=z(obs_size), done=z())


def add(buf: Transition, rows: Transition, count: jax.Array, capacity: jax.Array) -> Transition:
    """Write `rows` (leading axis w) at positions count .. count + w - 1 modulo `capacity`."""
    w = rows.reward.shape[0]
    idx = (count + jnp.arange(w)) % capacity
    return jax.tree.map(lambda b, r: b.at[idx].set(r), buf, rows)


def sample(buf: Transition, key: jax.Array, batch: int, count: jax.Array, capacity: jax.Array) -> Transition:
    """Uniform batch from the filled rows (count must be >= 1)."""
    size = jnp.minimum(count, capacity)
    idx = jax.random.randint(key, (batch,), 0, size)
    return jax.tree.map(lambda b: b[idx], buf)
