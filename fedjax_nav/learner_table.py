"""The learners as data, the one table every layer reads (docs/learners.md, "Adding a learner"), as
`methods.py` is for the methods: a row per learner names its config sections, whether it learns
on-policy, what a federated round averages, how its greedy actor is evaluated and exported, how its
update events are counted, which saved networks its learned value reads (`value_networks`), and
where its implementation (an `agents.learners.Learner`) lives, as
a "module:attribute" string resolved only when asked (`implementation`), so that this table stays
free of jax. The config's `learner` choices are this table's keys; nothing in the package branches
on a learner's name.

Each row also declares its divergence bounds (`Bound`, docs/reliability.md, "Divergence"): which of
its per-network metrics the host checks after each chunk against which config field.

A learner added from outside the package (tests/toy_learner.py) is one module holding its
`Learner` and one row given to `register`.
"""

from __future__ import annotations

import importlib
from collections.abc import Sequence
from dataclasses import dataclass


@dataclass(frozen=True)
class Bound:
    """A divergence bound: the run stops (exit 3) at the first episode where a network's `metric`
    (one of its learner's per-network metrics, `agents.learners.Learner.metrics`; |metric| when
    `absolute`) exceeds the value of the config field `field` (dotted; 0 turns the bound off).
    `said` names the quantity in the message (docs/reliability.md, "Divergence")."""

    metric: str  # a per-network metric of the learner (a metrics.csv column): "critic_loss", "approx_kl", ...
    field: str  # the dotted config field holding the bound: "run.max_critic_loss"; its value 0 = off
    said: str  # the quantity's name in the one-line message: "the critic loss"
    absolute: bool = False  # compare |metric| (the Q estimate, the entropy: either sign diverges)


@dataclass(frozen=True)
class LearnerRow:
    name: str
    sections: tuple[str, ...]  # the config sections it reads (validate: a section's options need its learner)
    on_policy: bool  # learns from its own policy's rollout: no buffer to share, no random warm-up, no n-step
    implementation: str  # "module:attribute" of its agents.learners.Learner
    shared: tuple[str, ...]  # the agent state's fields a federated round averages
    targets: tuple[str, ...]  # the target networks' fields, averaged too with fed.include_targets
    actor_section: str  # the section of the actor's hidden, depth, activation (evaluation, export)
    export: str  # the exported actor's network kind (deploy/policy_template.py): "heads" or "squashed"
    update_every: str  # the dotted config field of the steps between two update events
    steps_per_update: tuple[str, ...]  # dotted config fields whose product is the gradient steps per event
    bounds: tuple[Bound, ...]  # its divergence bounds, checked after each chunk (training.metrics.check_finite)
    storage_size: str  # the dotted config field that sizes its storage (a memory refusal names it)
    update_size: str  # the dotted config field that sizes one update's batch (a memory refusal names it)
    recurrent: str = ""  # a dotted choice field: where its value is not "none" the actor is a GRU ("gru" export)
    plain_actor: bool = False  # evaluated by evaluation.policies.actor_policy(hidden, depth, activation)
    # the params.npz networks its learned value V(s) reads (`agents.learners.Learner.value`; the
    # evaluation's `evaluation.values`); (): no value for the evaluation to call
    value_networks: tuple[str, ...] = ()

    def learner(self):
        """Its `agents.learners.Learner` (imports the implementation's module: jax)."""
        module, attribute = self.implementation.split(":")
        return getattr(importlib.import_module(module), attribute)


# The critic's divergence (docs/reliability.md, "Divergence"): PPO's value net is its critic, so
# its value loss answers to the same field as the replay learners' critic loss.
CRITIC_LOSS = "run.max_critic_loss"
OFF_POLICY_BOUNDS = (
    Bound("q", "run.max_abs_q", "the mean |Q| estimate", absolute=True),
    Bound("critic_loss", CRITIC_LOSS, "the critic loss"),
)

_OFF_POLICY = {  # the replay learners' shared settings: the offpolicy section
    "on_policy": False,
    "bounds": OFF_POLICY_BOUNDS,
    "storage_size": "offpolicy.buffer_size",
    "update_size": "offpolicy.batch_size",
    "actor_section": "offpolicy",
    "update_every": "offpolicy.train_every",
    "steps_per_update": ("offpolicy.gradient_steps",),
}

LEARNERS: dict[str, LearnerRow] = {
    r.name: r
    for r in [
        LearnerRow(
            "ddpg",
            ("offpolicy", "ddpg"),
            implementation="fedjax_nav.agents.learners:DDPG",
            shared=("actor", "critic"),
            targets=("actor_targ", "critic_targ"),
            export="heads",  # agents/networks.Actor: sigmoid and tanh heads
            value_networks=("actor", "critic"),  # Q(s, mu(s))
            plain_actor=True,  # the thesis's evaluation program
            **_OFF_POLICY,
        ),
        LearnerRow(
            "td3",
            ("offpolicy", "td3"),
            implementation="fedjax_nav.agents.learners:TD3",
            shared=("actor", "critics"),
            targets=("actor_targ", "critics_targ"),
            export="heads",  # DDPG's actor
            value_networks=("actor", "critics"),  # the twins' min Q(s, mu(s))
            **_OFF_POLICY,
        ),
        LearnerRow(
            "sac",
            ("offpolicy", "sac"),
            implementation="fedjax_nav.agents.learners:SAC",
            shared=("actor", "critics", "log_alpha"),
            targets=("critics_targ",),
            export="squashed",  # SquashedGaussianActor's mean (its log-std head is not needed)
            value_networks=("actor", "critics"),  # the twins' min Q at the greedy action (no entropy term)
            **_OFF_POLICY,
        ),
        LearnerRow(
            "ppo",
            ("ppo",),
            on_policy=True,
            implementation="fedjax_nav.agents.learners:PPO",
            shared=("actor", "log_std", "value"),
            targets=(),
            actor_section="ppo",
            export="squashed",  # MeanNet: the Gaussian's mean through the tanh squash
            recurrent="ppo.recurrent",  # RecurrentMLP with its GRU
            value_networks=("actor", "value"),  # the value net; the actor for its observation statistics
            update_every="ppo.rollout",
            steps_per_update=("ppo.epochs", "ppo.minibatches"),
            storage_size="ppo.rollout",  # [rollout, environments] per robot
            update_size="ppo.rollout",  # the whole rollout, in minibatches
            bounds=(
                Bound("value_loss", CRITIC_LOSS, "the value loss"),
                Bound("approx_kl", "ppo.max_approx_kl", "the approximate KL (approx_kl)"),
                Bound("entropy", "ppo.max_abs_entropy", "the |entropy| estimate", absolute=True),
            ),
        ),
    ]
}


class _Names(Sequence):
    """The table's names as a live sequence: the config's `learner` choices (a registered row counts)."""

    def __getitem__(self, i):
        return tuple(LEARNERS)[i]

    def __len__(self) -> int:
        return len(LEARNERS)

    def __contains__(self, name) -> bool:
        return name in LEARNERS

    def __repr__(self) -> str:
        return repr(tuple(LEARNERS))


NAMES = _Names()


def get(name: str) -> LearnerRow:
    try:
        return LEARNERS[name]
    except KeyError:
        raise ValueError(f"unknown learner {name!r}; allowed: {', '.join(LEARNERS)}") from None


def off_policy() -> tuple[str, ...]:
    """The names of the learners that learn from a replay buffer."""
    return tuple(n for n, r in LEARNERS.items() if not r.on_policy)


def bound_fields() -> tuple[str, ...]:
    """The config fields that hold a learner's divergence bound, each once, in the table's order."""
    return tuple(dict.fromkeys(b.field for r in LEARNERS.values() for b in r.bounds))


def register(row: LearnerRow) -> None:
    """Add a learner's row (a name not yet in the table): the config accepts it from then on."""
    if row.name in LEARNERS:
        raise ValueError(f"learner {row.name!r} is already in the table")
    LEARNERS[row.name] = row


def unregister(name: str) -> None:
    """Remove a row that `register` added."""
    del LEARNERS[name]
