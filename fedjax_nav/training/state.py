"""One seed's state of a training run, the carry of the trainer's compiled program
(`training.trainer`: `Trainer.init` makes it, `Trainer.episode` steps it)."""

from __future__ import annotations

from typing import Any

import jax
from flax import struct

from fedjax_nav import worlds
from fedjax_nav.env.nav import EnvState


@struct.dataclass
class TrainState:
    """One seed. Leading axes: agents [n_nets], buffers [n_bufs], env_state/obs/memory/first
    [environments] (robots x env.envs_per_robot, robot-major), reward_sum [robots]."""

    agents: Any  # the learner's state (ddpg.AgentState, td3.State, sac.State, ppo.State)
    buffers: Any  # the learner's storage: replay rows (buffer.Transition) or a rollout (ppo.Rollout)
    env_state: EnvState
    obs: jax.Array  # f32[environments, obs]
    explore: Any  # the learner's exploration carry (learner.explore_init; DDPG: its epsilon f32[], else ())
    agg_state: Any  # the aggregator's state (a NamedTuple of fedjax_nav.federated.aggregators; no client axis)
    reward_sum: jax.Array  # f32[robots] since the last federated step
    reward_steps: jax.Array  # f32[]
    key: jax.Array
    # procedural rooms only (env.rooms = procedural; training/rooms.py), None otherwise:
    world: worlds.World | None = None  # the robots' current rooms [robots]
    room_stream: jax.Array | None = None  # u32[] this seed's offset in the training room stream
    bank: Any = None  # env.room_sampling = learnability: rooms.RoomBank (each environment's rooms and scores)
    # learners with a memory (PPO: its GRU states, empty without a GRU), None otherwise:
    memory: Any = None  # the learner's per-environment carry [environments, ...]
    first: jax.Array | None = None  # bool[environments]: obs starts an episode
