"""A jittable ring replay buffer for one learner (vmap it for several).

Rows are allocated once (`alloc`, static); the active capacity is a traced value <= alloc, so a
sweep over buffer sizes compiles once. The write position and fill level are derived from the
number of rows ever written (`count`), which the trainer knows from the global step.

n-step returns need windows of consecutive rows of one environment and where episodes end:
`EpisodeRows` keeps a truncation flag beside the rows (`done` is terminated only) and
`sample_windows` draws windows. The trainer writes `rows` rows per step (one per environment, in
the same order every step: learners.py `_store_replay`), so an environment's next row is `rows`
positions further on in the ring.

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


@struct.dataclass
class EpisodeRows:
    """Replay rows and, beside them, where an episode was cut by its time limit: what n-step
    windows need (`rows.done` is 1 on termination only)."""

    rows: Transition  # [alloc, ...]
    truncated: jax.Array  # f32[alloc] 1 on an episode's last step (a time-out), 0 otherwise


def init_episode_rows(alloc: int, obs_size: int, action_size: int = 2) -> EpisodeRows:
    return EpisodeRows(init(alloc, obs_size, action_size), jnp.zeros((alloc,), jnp.float32))


def add_episode_rows(
    buf: EpisodeRows, rows: Transition, truncated: jax.Array, count: jax.Array, capacity: jax.Array
) -> EpisodeRows:
    """`add` for the rows and their truncation flags f32[w]."""
    idx = (count + jnp.arange(truncated.shape[0])) % capacity
    return EpisodeRows(add(buf.rows, rows, count, capacity), buf.truncated.at[idx].set(truncated))


def sample_windows(
    buf: EpisodeRows, key: jax.Array, batch: int, count: jax.Array, capacity: jax.Array, n: int, stride: int
) -> tuple[Transition, jax.Array]:
    """`batch` windows of n consecutive steps of one environment. The first row of each is drawn
    as `sample` draws its rows (the same key: the same rows); step k of a window is k * stride
    positions further on in the ring (stride: rows written per step, static), which is the same
    environment k steps later as long as it was written. Returns (windows: Transition, fields
    [batch, n, ...]; end: f32[batch, n], 1 where step k ends its episode (terminated or truncated)
    or is the newest row of its environment, its next step not written yet). Steps after a window's
    first end are whatever the ring holds there: `offpolicy.nstep` leaves them out."""
    size = jnp.minimum(count, capacity)
    first = jax.random.randint(key, (batch,), 0, size)
    newer = (count - 1 - first) % capacity  # rows written after the first one (first < size <= count)
    offset = jnp.arange(n) * stride
    idx = (first[:, None] + offset) % capacity
    windows = jax.tree.map(lambda b: b[idx], buf.rows)
    written_next = (offset + stride)[None, :] <= newer[:, None]
    end = jnp.maximum(jnp.maximum(windows.done, buf.truncated[idx]), 1.0 - written_next.astype(jnp.float32))
    return windows, end
