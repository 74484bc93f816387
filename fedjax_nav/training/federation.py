"""One federated round of a training run (docs/robustness.md): who takes part, what each client
sends (Byzantine clients the attack's parameters), the aggregator's update and who takes it back.
Functions of a `Round` (what a run fixes about its rounds when it is built: the rule, the
attack, the clients' static roles, what its learner shares) and one seed's `TrainState`; the
trainer calls them inside its compiled step or episode. The round never looks inside what is
shared: any learner's parameters go through it alike.

`aggregator(rnd, hp)` is the one place where the config meets the aggregators: the rule named by
the method or `fed.aggregator`, its hyperparameters from the traced `fed.*` values, and the
reference an attack needs.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from fedjax_nav.federated import aggregators as agg
from fedjax_nav.federated import attacks
from fedjax_nav.training.hparams import HParams

# fold_in tag of the federated round's draws (participation, attack noise): derived from the
# state's key without consuming it, so the run's key stream is the same with and without them.
FED_STREAM = 0x0FED


@dataclass(frozen=True, eq=False)
class Round:
    """What a federated round of a run needs, fixed when the run is built (`describe`)."""

    rule: str  # the server's rule: the method's own (soft, pw, rw, gs; none) or fed.aggregator's robust one
    attack: str  # fed.attack
    sends_rewards: bool  # PW/RW: each client's mean reward travels with its parameters
    real: np.ndarray  # bool[clients]: False on the clients padded in for a mesh (never take part)
    byzantine: np.ndarray  # bool[clients]: the last fed.byzantine real clients
    learner: Any  # the agents.learners.Learner: what a client sends (`shared`) and takes back
    include_targets: bool  # fed.include_targets: the learner's target networks travel too

    def shared(self, agents) -> dict:
        """What a client sends: the learner's SHARED fields (and its TARGETS with fed.include_targets)."""
        return self.learner.shared(agents, self.include_targets)

    def take_shared(self, agents, new: dict):
        """The agents with what a round sent back (`shared`'s keys) put in place."""
        return self.learner.take_shared(agents, new)


def describe(fed, method, learner, real: np.ndarray, byzantine: np.ndarray) -> Round:
    """The `Round` of a run: `fed` its config section (config.FedConfig), `method` its methods row."""
    rule = method.aggregator if fed.aggregator == "method" else fed.aggregator
    return Round(rule, fed.attack, method.sends_rewards, real, byzantine, learner, fed.include_targets)


def aggregator(rnd: Round, hp: HParams) -> agg.Aggregator:
    """The run's aggregator with its traced hyperparameters (`fed.<name>` for each name the rule
    takes), wrapped to keep the last global model when the attack reads it and the rule does not."""
    rule = agg.rule(rnd.rule)
    out = rule.make(**{h: getattr(hp.fed, h) for h in rule.hparams})
    if rnd.attack in attacks.NEEDS_REFERENCE and not rule.keeps_reference:
        out = agg.with_reference(out)
    return out


def participation(rnd: Round, key: jax.Array, hp: HParams) -> jax.Array:
    """bool[robots]: who takes part in this round, each with probability fed.participation
    (uniform [0, 1) < p: every client when p = 1)."""
    return (jax.random.uniform(key, rnd.real.shape) < hp.fed.participation) & jnp.asarray(rnd.real)


def federated_round(rnd: Round, state, hp: HParams) -> tuple[object, dict]:
    """One round: the participants send `shared(agents)` (Byzantine ones the attack's
    parameters, and for PW/RW an inflated reward); the aggregator's update comes back to the
    honest participants. Absent clients and Byzantine ones keep their own models. A round
    with fewer than max(fed.min_clients, 1) participants is skipped: nothing is sent, the
    aggregator's state is unchanged. Returns the state and {"clients": i32 (clients that
    exchanged), "skipped": i32 (1 if skipped)}. With participation 1, min_clients <= robots
    and no attack this is exactly the thesis's round (every draw comes from
    fold_in(key, FED_STREAM): the run's key stream is untouched). Its three halves
    (`sent`, `exchange`, `settle`) are also the Flower fleet's (docs/fleet.md)."""
    own, r = sent(rnd, state)
    new, agg_state, stats = exchange(rnd, hp, own, r, state.key, state.agg_state)
    return settle(rnd, state, new, agg_state), stats


def sent(rnd: Round, state) -> tuple[dict, jax.Array]:
    """What the clients send: (their shared fields, leaves [clients, ...]; their mean reward per
    step since the last round, f32[clients])."""
    return rnd.shared(state.agents), state.reward_sum / jnp.maximum(state.reward_steps, 1.0)


def exchange(
    rnd: Round, hp: HParams, own: dict, r: jax.Array, key: jax.Array, agg_state, answered: jax.Array | None = None
) -> tuple[dict, object, dict]:
    """The server's half of a round, over what every client sent (`sent`): who takes part (drawn
    from fold_in(key, FED_STREAM), `key` the run's key at the round), the attack on the
    Byzantine clients' sends, the aggregator's update. Returns (what each client holds after the
    round, the aggregator's new state, the round's stats); see `federated_round`. `answered`
    (bool[clients], a fleet's: the robots whose reply arrived) leaves the others out as absent
    clients; None (the program's round) adds nothing."""
    k_part, k_attack = jax.random.split(jax.random.fold_in(key, FED_STREAM))
    mask = participation(rnd, k_part, hp)
    if answered is not None:
        mask = mask & answered
    n = jnp.sum(mask.astype(jnp.int32))
    held = n >= jnp.maximum(hp.fed.min_clients, 1)
    out, r_sent = own, r
    has_byzantine = bool(rnd.byzantine.any())
    if rnd.attack != "none" and has_byzantine:
        byz = jnp.asarray(rnd.byzantine)
        ref = agg.reference(agg_state) if rnd.attack in attacks.NEEDS_REFERENCE else None
        out = attacks.apply_attack(rnd.attack, own, byz, k_attack, hp.fed.attack_scale, ref)
        if rnd.sends_rewards:
            r_sent = attacks.inflate_reward(r, byz)
    new, new_state = aggregator(rnd, hp).update(out, r_sent, agg_state, mask)
    take = held & jnp.asarray(~rnd.byzantine)  # absent rows of `new` are already `out` = own
    new = (
        agg.keep_absent(new, own, take) if has_byzantine else jax.tree.map(lambda a, b: jnp.where(held, a, b), new, own)
    )
    new_state = jax.tree.map(lambda a, b: jnp.where(held, a, b), new_state, agg_state)
    return new, new_state, {"clients": jnp.where(held, n, 0), "skipped": (~held).astype(jnp.int32)}


def settle(rnd: Round, state, new: dict, agg_state):
    """The clients' half after the exchange: `new` (what `exchange` sent back) in place, the
    aggregator's state kept, the reward sums of the next round started."""
    return state.replace(
        agents=rnd.take_shared(state.agents, new),
        agg_state=agg_state,
        reward_sum=jnp.zeros_like(state.reward_sum),
        reward_steps=jnp.float32(0),
    )
