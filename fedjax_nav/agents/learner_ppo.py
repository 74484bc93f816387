"""PPO's functions for its entry in `learners.LEARNERS`: the rollout it stores and when it learns.

Storage is one `ppo.Rollout` per robot, [ppo.rollout, rows] (rows = the robot's environments):
step g writes slot g % T_roll, and the update runs after the slot T_roll - 1 is written, so every
update sees exactly the last T_roll steps of every environment, under the parameters that acted
(a federated round between two updates changes them; rounds at episode ends fall on update
boundaries when ppo.rollout divides env.episode_length). `reset` is the trainer's `first` flag
(obs_t starts an episode: after the episode's reset, or after a goal or collision put the robot back
at a start), `hidden` the GRU states before the rollout's first step. `terminated` and `truncated`
come from the env apart: GAE bootstraps from V(next_obs) at a time-out (agents/ppo.py).
Observations are stored raw; with ppo.normalize_obs the actor's statistics normalise them in
`explore`, `greedy` and `update`, and `update` merges each rollout into them (agents/ppo.py).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from fedjax_nav.agents import ppo
from fedjax_nav.agents.networks import ACTIVATIONS_OUTSIDE, ACTIVATIONS_PER_LAYER

METRICS = ("policy_loss", "value_loss", "entropy", "approx_kl", "clip_frac")


@struct.dataclass
class OnPolicyNets:
    ppo: ppo.Nets = struct.field(pytree_node=False)
    rollout: int = struct.field(pytree_node=False)  # T_roll


def make_nets(v: dict) -> OnPolicyNets:
    nets = ppo.make_nets(
        hidden=v["ppo.hidden"],
        depth=v["ppo.depth"],
        activation=v["ppo.activation"],
        recurrent=v["ppo.recurrent"] == "gru",
        gru=v["ppo.gru_hidden"],
        epochs=v["ppo.epochs"],
        minibatches=v["ppo.minibatches"],
        normalize_obs=v["ppo.normalize_obs"],
    )
    return OnPolicyNets(nets, v["ppo.rollout"])


def init(nets: OnPolicyNets, key, obs_size: int, hp) -> ppo.State:
    return ppo.init(nets.ppo, key, obs_size, hp.ppo.init_log_std)


def memory(nets: OnPolicyNets) -> ppo.Hidden:
    return ppo.initial_hidden(nets.ppo)


def explore(nets: OnPolicyNets, state, obs, key, hp, carry, memory, first):
    step, hidden = ppo.act(nets.ppo, state, obs, key, memory, first)
    return step.action, (step.raw_action, step.log_prob), hidden


def greedy(nets: OnPolicyNets, actor, obs, memory, first):
    return ppo.greedy_actor(nets.ppo, actor, obs, memory, first)


def value(nets: OnPolicyNets, params: dict, obs, memory, first):
    """(V(obs), memory with the value's GRU state advanced): the value net on params["value"], the
    observation normalised with params["actor"]'s statistics as `explore` does."""
    v, h = ppo.value(nets.ppo, params["actor"], params["value"], obs, memory.value, first)
    return v, memory._replace(value=h)


def storage(nets: OnPolicyNets, obs_size: int, rows: int) -> ppo.Rollout:
    T, A, H = nets.rollout, nets.ppo.action_size, nets.ppo.gru

    def z(*shape, dtype=jnp.float32):
        return jnp.zeros((T, rows, *shape), dtype)

    return ppo.Rollout(
        obs=z(obs_size),
        raw_action=z(A),
        log_prob=z(),
        reward=z(),
        next_obs=z(obs_size),
        terminated=z(),
        truncated=z(),
        reset=z(dtype=bool),
        hidden=ppo.Hidden(jnp.zeros((rows, H)), jnp.zeros((rows, H))),
    )


def store(nets: OnPolicyNets, ro: ppo.Rollout, rec, g, rows: int, hp) -> ppo.Rollout:
    """Write step g's rows at slot g % T_roll (and, at slot 0, the GRU states before it)."""
    t = g % nets.rollout
    raw, logp = rec.extra
    new = {
        "obs": rec.obs,
        "raw_action": raw,
        "log_prob": logp,
        "reward": rec.reward,
        "next_obs": rec.next_obs,
        "terminated": rec.terminated.astype(jnp.float32),
        "truncated": rec.truncated.astype(jnp.float32),
        "reset": rec.first,
    }
    ro = ro.replace(**{k: getattr(ro, k).at[t].set(v) for k, v in new.items()})
    return ro.replace(hidden=jax.tree.map(lambda old, h: jnp.where(t == 0, h, old), ro.hidden, rec.memory))


def due(nets: OnPolicyNets, g, rows: int, hp):
    return (g + 1) % nets.rollout == 0


# f32 values per rollout row (every environment's every step) of one update beside the stored
# rollout: a quarter of (5 depth + 3) x hidden (networks.ACTIVATIONS_PER_LAYER) and 6 per GRU unit,
# and ROLLOUT_COPIES copies of the rollout (the epoch's permuted copy). Measured: XLA CPU's
# temporaries of the compiled update of 5 networks do not depend on ppo.minibatches (GRU-PPO at 64
# environments: 99.9 MB with 4 and with 32; PPO 42.4 MB), and this gives 1.04-1.08x them at 64 and
# 256 environments (tests/test_memory_estimate.py).
ROLLOUT_COPIES = 1
GRU_VALUES = 6


def update_bytes(nets: OnPolicyNets, obs_size: int, rows: int) -> int:
    """Peak bytes of one update beyond the agent's state and its stored rollout: ROLLOUT_COPIES
    copies of the rollout, and the per-row values of both networks over the whole rollout."""
    p, T = nets.ppo, nets.rollout
    shapes = jax.eval_shape(lambda: storage(nets, obs_size, rows))
    rollout = sum(x.size * x.dtype.itemsize for x in jax.tree.leaves(shapes))
    per_row = (ACTIVATIONS_PER_LAYER * p.actor.depth + ACTIVATIONS_OUTSIDE) * p.actor.hidden // 4 + GRU_VALUES * p.gru
    return ROLLOUT_COPIES * rollout + 4 * per_row * T * rows


def update(nets: OnPolicyNets, state, ro, key, g, rows: int, hp):
    state, info = ppo.update(nets.ppo, state, ro, key, hp)
    return state, {m: info[m] for m in METRICS}
