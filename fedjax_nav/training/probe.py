"""Periodic evaluation during training (`run.eval_every`; docs/generalization.md): the greedy
policy of every network on a small held-out suite, inside the compiled program.

The probe is the training layer's own small rollout (training may not import evaluation): every
network x room x goal of the suite (`run.eval_suite`, default the group "probe": 4 rooms per
family, 2 goals each, from the test stream, disjoint from the "heldout" suites) driven from start
0 by the greedy actor, noiseless, under the run's robot model (`config.envs.make_env(cfg,
"eval", noise=False)`: the model's dynamics, no sensor noise), at most `env.episode_length` steps; an
episode succeeds when the robot reaches the goal before any collision. `success` gives the
fraction of successful episodes per network, f32[n_nets]; the trainer reports it as the
`eval_success` metric on every `eval_every`-th episode (NaN on the others). The policy is the
learner's greedy one (`agents.learners.Learner.greedy` on `Learner.policy(agents)`); a recurrent
one carries its memory through the episode from an episode start.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from fedjax_nav.config import envs
from fedjax_nav.worlds.suites import suite_rooms

CHUNK = 64  # steps per inner scan; the outer while_loop stops once every episode is over


class Probe:
    def __init__(self, cfg, learner, nets, suite: str = "probe"):
        self.world, self.families, self.seeds = suite_rooms(suite)
        self.env = envs.make_env(cfg, "eval", noise=False)
        self.learner, self.nets = learner, nets
        self.T = cfg.env.episode_length
        self.G = int(self.world.goals.shape[1])

    def success(self, actors, hp) -> jax.Array:
        """Success rate f32[n_nets] of the greedy policies `actors` (leaves [n_nets, ...]) on the suite."""
        params = envs.env_params(self.world, hp)
        goals = jnp.arange(self.G)

        def episode(actor, p, g):  # one network, one room, one goal
            obs, state = self.env.reset(jax.random.key(0), p.replace(goal_index=g))
            memory = self.learner.memory(self.nets)  # None: a policy without memory
            first = None if memory is None else jnp.bool_(True)
            return obs, state, jnp.bool_(False), jnp.bool_(False), memory, first

        def step(actor, p, carry):
            obs, state, done, success, memory, first = carry
            action, memory = self.learner.greedy(self.nets, actor, obs, memory, first)
            obs2, state2, _, term, trunc, info = self.env.step(jax.random.key(0), state, action, p)
            first = None if first is None else jnp.bool_(False)
            new = (
                obs2,
                state2,
                done | term | trunc,
                success | (~done & info["goal"] & ~info["collision"]),
                memory,
                first,
            )
            return jax.tree.map(lambda n, o: jnp.where(done, o, n), new, carry)

        def run(actor, p, g):
            carry = episode(actor, p, g)
            n_chunks = -(-self.T // CHUNK)

            def body(c):
                i, carry = c
                carry = jax.lax.fori_loop(0, CHUNK, lambda _, x: step(actor, p, x), carry)
                return i + 1, carry

            _, carry = jax.lax.while_loop(lambda c: (c[0] < n_chunks) & ~c[1][2], body, (jnp.int32(0), carry))
            return carry[3] & (g < p.world.num_goals), g < p.world.num_goals

        per_goal = jax.vmap(run, in_axes=(None, None, 0))
        per_room = jax.vmap(per_goal, in_axes=(None, 0, None))
        ok, valid = jax.vmap(per_room, in_axes=(0, None, None))(actors, params, goals)  # [nets, rooms, goals]
        return jnp.sum(ok, (1, 2)) / jnp.maximum(jnp.sum(valid, (1, 2)), 1)
