"""A learner from outside the package, for tests/test_toy_learner.py: DDPG's networks, replay and
update with Gaussian exploration noise instead of epsilon-greedy (no exploration carry). All of it
is this module's `TOY` and the row `ROW`; nothing in fedjax_nav is edited to add it
(docs/learners.md, "Adding a learner")."""

from __future__ import annotations

import jax.numpy as jnp

from fedjax_nav.agents import ddpg, learners, td3
from fedjax_nav.learner_table import OFF_POLICY_BOUNDS, LearnerRow

NOISE = 0.3  # exploration noise std, in box half-widths


def _explore(nets, state, obs, key, hp, carry, memory, first):
    return td3.act(nets, state.actor, obs, key, jnp.float32(NOISE)), (), memory


# DDPG's functions with another exploration; the carry functions back at the Learner's defaults
_defaults = learners.Learner._field_defaults
TOY = learners.DDPG._replace(
    explore=_explore,
    greedy=learners.DDPG.greedy,
    explore_init=_defaults["explore_init"],
    explore_next=_defaults["explore_next"],
    explore_metric=_defaults["explore_metric"],
)

ROW = LearnerRow(
    "toy",
    ("offpolicy", "ddpg"),  # the replay settings, and DDPG's target mix and period
    on_policy=False,
    implementation=f"{__name__}:TOY",
    shared=("actor", "critic"),
    targets=("actor_targ", "critic_targ"),
    actor_section="offpolicy",
    export="heads",
    update_every="offpolicy.train_every",
    steps_per_update=("offpolicy.gradient_steps",),
    bounds=OFF_POLICY_BOUNDS,  # DDPG's metrics, so DDPG's bounds: |Q| and the critic loss
    storage_size="offpolicy.buffer_size",  # DDPG's replay rows and batch (a memory refusal names them)
    update_size="offpolicy.batch_size",
)
assert ddpg.Actor is not None  # the actor the row's "heads" export reads
