"""What one training step reports and how an episode turns it into metrics.

`StepMetrics` is one step's values; the step scan sums them over the episode in its carry and
`EPISODE_METRICS` turns the sums into the episode's metrics (docs/architecture.md). The losses are
the learner's own (`agents.learners.Learner.metrics`: critic_loss, actor_loss, q for the off-policy
learners; policy_loss, value_loss, ... for PPO): `loss_metrics` turns each into its mean over the
episode's update events.
"""

from __future__ import annotations

from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct


def all_finite(tree) -> jax.Array:
    return jnp.all(jnp.stack([jnp.all(jnp.isfinite(x)) for x in jax.tree.leaves(tree)]))


@struct.dataclass
class StepMetrics:
    """What one step reports (leaves [robots] or [nets]; scalars for the run-wide flags). The
    step scan sums them over the episode; a value that is not a sum of per-step values (a
    maximum, a count of steps with a property) is a field here that the step sets, plus its
    line in EPISODE_METRICS."""

    reward: jax.Array  # f32[robots] (the mean over a robot's environments)
    goals: jax.Array  # i32[robots] (summed over a robot's environments)
    collisions: jax.Array  # i32[robots]
    losses: dict  # learner metric -> f32[nets], 0 on steps without an update (DDPG: critic_loss, actor_loss, q)
    updates: jax.Array  # i32[] 1 on an update event
    fed_events: jax.Array  # i32[] 1 on a federated step inside the episode
    fed_clients: jax.Array  # i32[] clients that exchanged models in that step's round
    fed_skipped: jax.Array  # i32[] 1 if that round had too few participants
    # env.room_sampling = learnability only (training/rooms.py), None otherwise: per environment
    env_goals: jax.Array | None = None  # i32[environments] 1 on a goal
    env_attempts: jax.Array | None = None  # i32[environments] 1 where an attempt ends (goal, collision, time-out)
    # env.shared_rooms only (env/shared.py), None otherwise
    robot_collisions: jax.Array | None = None  # i32[robots] collisions with another robot (also in `collisions`)


def _per_update(x: jax.Array, m: StepMetrics) -> jax.Array:
    return x / jnp.maximum(m.updates, 1)


# Episode metric -> its value from the episode's summed step metrics `m` and its length T. The
# sums ride in the step scan's carry: stacked [T, ...] outputs reduced after the scan made the
# trainer 3% slower here (docs/benchmarks.md, "The redesign's speed").
EPISODE_METRICS: dict[str, Callable[[StepMetrics, int], jax.Array]] = {
    "reward": lambda m, T: m.reward / T,  # mean reward per step, per robot
    "goals": lambda m, T: m.goals,
    "collisions": lambda m, T: m.collisions,
    "fed_events": lambda m, T: m.fed_events,
    "fed_clients": lambda m, T: m.fed_clients,
    "fed_skipped": lambda m, T: m.fed_skipped,
}


def loss_metrics(sums: StepMetrics, names) -> dict:
    """Each learner loss in `names`: its mean over the episode's update events, f32[nets]."""
    return {n: _per_update(sums.losses[n], sums) for n in names}


NO_ROUND = {"clients": np.int32(0), "skipped": np.int32(0)}  # what a step without a round reports


def optional_metrics(m: StepMetrics) -> dict:
    """The episode metrics of the optional per-robot step fields that a run has (summed)."""
    return {} if m.robot_collisions is None else {"robot_collisions": m.robot_collisions}
