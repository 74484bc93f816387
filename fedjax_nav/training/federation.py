"""One federated round of a training run (docs/robustness.md): who takes part, what each client
sends (Byzantine clients the attack's parameters), the aggregator's update and who takes it back.
Functions of the `Trainer` (its static roles: Byzantine and real clients, and what its learner
shares: `tr.shared(agents)` -> a dict of stacked pytrees, `tr.take_shared(agents, dict)`) and one
seed's `TrainState`; the trainer calls them inside its compiled step or episode. The round never
looks inside what is shared: any learner's parameters go through it alike.

`aggregator(fed, hp)` is the one place where the config meets the aggregators: the rule named by
the method or `fed.aggregator`, its hyperparameters from the traced `fed.*` values, and the
reference an attack needs.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from fedjax_nav.federated import aggregators as agg
from fedjax_nav.federated import attacks
from fedjax_nav.training.hparams import HParams

# fold_in tag of the federated round's draws (participation, attack noise): derived from the
# state's key without consuming it, so the run's key stream is the same with and without them.
FED_STREAM = 0x0FED


def rule_name(tr) -> str:
    """The server's rule: the method's own, or the robust rule `fed.aggregator` names."""
    f = tr.cfg.fed
    return tr.method.aggregator if f.aggregator == "method" else f.aggregator


def aggregator(tr, hp: HParams) -> agg.Aggregator:
    """The run's aggregator with its traced hyperparameters (`fed.<name>` for each name the rule
    takes), wrapped to keep the last global model when the attack reads it and the rule does not."""
    name = rule_name(tr)
    rule = agg.rule(name)
    out = rule.make(**{h: getattr(hp.fed, h) for h in rule.hparams})
    if tr.cfg.fed.attack in attacks.NEEDS_REFERENCE and not rule.keeps_reference:
        out = agg.with_reference(out)
    return out


def participation(tr, key: jax.Array, hp: HParams) -> jax.Array:
    """bool[robots]: who takes part in this round, each with probability fed.participation
    (uniform [0, 1) < p: every client when p = 1)."""
    return (jax.random.uniform(key, (tr.num_robots,)) < hp.fed.participation) & jnp.asarray(tr.real)


def federated_round(tr, state, hp: HParams) -> tuple[object, dict]:
    """One round: the participants send `shared(agents)` (Byzantine ones the attack's
    parameters, and for PW/RW an inflated reward); the aggregator's update comes back to the
    honest participants. Absent clients and Byzantine ones keep their own models. A round
    with fewer than max(fed.min_clients, 1) participants is skipped: nothing is sent, the
    aggregator's state is unchanged. Returns the state and {"clients": i32 (clients that
    exchanged), "skipped": i32 (1 if skipped)}. With participation 1, min_clients <= robots
    and no attack this is exactly the thesis's round (every draw comes from
    fold_in(key, FED_STREAM): the run's key stream is untouched)."""
    f = tr.cfg.fed
    r = state.reward_sum / jnp.maximum(state.reward_steps, 1.0)
    own = tr.shared(state.agents)
    k_part, k_attack = jax.random.split(jax.random.fold_in(state.key, FED_STREAM))
    mask = participation(tr, k_part, hp)
    n = jnp.sum(mask.astype(jnp.int32))
    held = n >= jnp.maximum(hp.fed.min_clients, 1)
    sent, r_sent = own, r
    if f.attack != "none" and f.byzantine > 0:
        byz = jnp.asarray(tr.byzantine)
        ref = agg.reference(state.agg_state) if f.attack in attacks.NEEDS_REFERENCE else None
        sent = attacks.apply_attack(f.attack, own, byz, k_attack, hp.fed.attack_scale, ref)
        if tr.method.sends_rewards:
            r_sent = attacks.inflate_reward(r, byz)
    new, agg_state = aggregator(tr, hp).update(sent, r_sent, state.agg_state, mask)
    take = held & jnp.asarray(~tr.byzantine)  # absent rows of `new` are already `sent` = own
    new = agg.keep_absent(new, own, take) if f.byzantine else jax.tree.map(lambda a, b: jnp.where(held, a, b), new, own)
    agg_state = jax.tree.map(lambda a, b: jnp.where(held, a, b), agg_state, state.agg_state)
    stats = {"clients": jnp.where(held, n, 0), "skipped": (~held).astype(jnp.int32)}
    return state.replace(
        agents=tr.take_shared(state.agents, new),
        agg_state=agg_state,
        reward_sum=jnp.zeros_like(state.reward_sum),
        reward_steps=jnp.float32(0),
    ), stats
