"""Runs that can never learn are refused before training (docs/reliability.md, "Runs that cannot
learn"): a learner whose update period (its row's `update_every`: ppo.rollout, offpolicy.train_every)
is longer than the run, and an off-policy learner whose batch is more than its replay buffer has
received at the run's last update event. One line naming the field; one step more (or a value one
smaller) and the config is accepted. The refusal is held to the learners' own `due` functions: a
config is refused exactly when `due` is false at every step of the run. Nothing is trained.
"""

import dataclasses
import os

os.environ.setdefault("JAX_PLATFORMS", "cpu")

import jax.numpy as jnp  # noqa: E402
import pytest  # noqa: E402
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from fedjax_nav import learner_table, methods  # noqa: E402
from fedjax_nav.config import ConfigError, check, from_dict, load_config, values  # noqa: E402

NEVER = "no update would ever happen"
BASE = ["fed.period=1", "run.chunk_episodes=1", "run.checkpoint_every=0", "ppo.minibatches=1"]


def refusal(overrides) -> str | None:
    """The one-line ConfigError of the default config with `overrides`, or None when it loads."""
    try:
        load_config(None, BASE + list(overrides))
    except ConfigError as e:
        return str(e)
    return None


# (what, the overrides it refuses, the field its line names, the same run one step longer or with
# the field one smaller, which loads)
CASES = [
    (
        "ppo's rollout beyond the run",
        ["learner=ppo", "run.episodes=2", "env.episode_length=16", "ppo.rollout=33"],
        "ppo.rollout (33 steps)",
        [["env.episode_length=17"], ["ppo.rollout=32"]],
    ),
    (
        "a GRU ppo's rollout beyond the run",
        ["learner=ppo", "ppo.recurrent=gru", "run.episodes=1", "env.episode_length=8", "ppo.rollout=9"],
        "ppo.rollout (9 steps)",
        [["env.episode_length=9"], ["ppo.rollout=8"]],
    ),
    (
        "train_every beyond the run",
        [
            "learner=td3",
            "run.episodes=1",
            "env.episode_length=16",
            "offpolicy.batch_size=8",
            "offpolicy.train_every=17",
        ],
        "offpolicy.train_every (17 steps)",
        [["env.episode_length=17"], ["offpolicy.train_every=16"]],
    ),
    (
        # updates after steps 5, 10 (14 steps): a buffer holds 10 rows at the last one
        "a batch one buffer never holds at an update",
        ["method=iddpg", "run.episodes=1", "env.episode_length=14", "offpolicy.batch_size=11"],
        "offpolicy.batch_size (11)",
        [["env.episode_length=15"], ["offpolicy.batch_size=10"]],
    ),
    (
        # 2 environments per robot write 2 rows per step into the robot's buffer: 20 at step 10
        "a batch beyond the rows of a robot's environments",
        ["learner=sac", "method=flddpg", "env.envs_per_robot=2", "run.episodes=1", "env.episode_length=14"]
        + ["offpolicy.batch_size=21"],
        "offpolicy.batch_size (21)",
        [["env.episode_length=15"], ["offpolicy.batch_size=20"]],
    ),
    (
        # one shared buffer: every robot's rows, 5 robots x 2 environments = 10 per step, 100 at step 10
        "a batch beyond a shared buffer's rows",
        ["method=snddpg", "env.envs_per_robot=2", "run.episodes=1", "env.episode_length=14"]
        + ["offpolicy.batch_size=101", "offpolicy.buffer_size=200"],
        "offpolicy.batch_size (101)",
        [["env.episode_length=15"], ["offpolicy.batch_size=100"]],
    ),
]


@pytest.mark.parametrize("what, refused, names, accepted", CASES, ids=[c[0] for c in CASES])
def test_a_run_that_can_never_update_is_refused_naming_the_field(what, refused, names, accepted):
    msg = refusal(refused)
    assert msg is not None and "\n" not in msg and NEVER in msg and names in msg, msg
    assert msg.startswith("<defaults> (with --set): "), msg
    for more in accepted:  # one step more, or the field one smaller: an update happens, and it loads
        assert refusal(refused + more) is None, (more, refusal(refused + more))


def test_a_file_s_run_that_can_never_update_names_the_file():
    data = {"env": {"episode_length": 16}, "run": {"episodes": 2, "chunk_episodes": 1, "checkpoint_every": 0}}
    data |= {"fed": {"period": 1}, "learner": "ppo", "ppo": {"rollout": 64, "minibatches": 1}}
    with pytest.raises(ConfigError) as e:
        from_dict(data, "tiny.yaml")
    assert str(e.value).startswith("tiny.yaml: ppo.rollout (64 steps) is longer than the whole run"), str(e.value)


def test_every_shipped_config_and_the_default_updates():
    from fedjax_nav.configs import names

    for name in names("config"):
        load_config(name)
    load_config(None)


# ----------------------------------------------------------------------------- the learners' own `due`

METHODS = ("iddpg", "flddpg", "seddpg", "snddpg")


def update_events(cfg) -> int:
    """How many update events the learner's own `due` (agents/learners.py) gives over the run's
    steps, with the trainer's rows per buffer (training/trainer.py: environments / buffers)."""
    from fedjax_nav.agents import learners
    from fedjax_nav.training.hparams import hparams_from_config

    learner = learners.get(cfg.learner)
    method = methods.get(cfg.method)
    robots = cfg.num_robots
    writes = robots * cfg.env.envs_per_robot // (1 if method.shared_buffer else robots)
    g = jnp.arange(cfg.run.episodes * cfg.env.episode_length, dtype=jnp.int32)
    due = learner.due(learner.make_nets(values(cfg)), g, writes, hparams_from_config(cfg))
    return int(jnp.sum(jnp.broadcast_to(due, g.shape)))


REFERENCE = load_config(None, BASE + ["env.worlds=[train-0,train-2]"])


@settings(max_examples=60, deadline=None, database=None, suppress_health_check=list(HealthCheck))
@given(
    learner=st.sampled_from(sorted(learner_table.LEARNERS)),
    method=st.sampled_from(METHODS),
    episodes=st.integers(1, 3),
    length=st.integers(1, 24),
    every=st.integers(1, 40),
    batch=st.integers(1, 120),
    envs=st.integers(1, 3),
)
def test_the_refusal_is_exactly_a_run_without_an_update_event(learner, method, episodes, length, every, batch, envs):
    row = learner_table.get(learner)
    if row.on_policy and methods.get(method).shared_buffer and not methods.get(method).shared_network:
        return  # refused for its own reason (an on-policy learner cannot share a buffer)
    r = REFERENCE
    cfg = dataclasses.replace(
        r,
        learner=learner,
        method=method,
        env=dataclasses.replace(r.env, episode_length=length, envs_per_robot=envs),
        run=dataclasses.replace(r.run, episodes=episodes),
        ppo=dataclasses.replace(r.ppo, rollout=every),
        offpolicy=dataclasses.replace(r.offpolicy, train_every=every, batch_size=batch, buffer_size=max(batch, 8)),
    )
    try:
        check(cfg)
        refused = None
    except ConfigError as e:
        refused = str(e)
        assert NEVER in refused, refused  # no other check applies to these configs
    assert (refused is not None) == (update_events(cfg) == 0), (refused, update_events(cfg))


# ----------------------------------------------------------------------------- runs already trained


def test_a_saved_run_that_could_never_update_is_still_read_and_can_be_extended(tmp_path):
    """A run directory trained before the check (the old README smoke run: 2 x 32 steps, batch 512)
    is read back for evaluate, export and plots (`rundir.read_config`), and resumed as it was; a
    resume that changes its config is checked, so extending it to a run that updates is accepted."""
    import argparse

    from fedjax_nav import rundir
    from fedjax_nav.cli.train import _resumed_config
    from fedjax_nav.config import save_config

    sets = ["run.episodes=2", "env.episode_length=32", "run.chunk_episodes=2", "run.checkpoint_every=0"]
    ok = load_config("thesis/flddpg", sets + ["offpolicy.batch_size=32"])
    old = dataclasses.replace(ok, offpolicy=dataclasses.replace(ok.offpolicy, batch_size=512))
    run = tmp_path / "run"
    run.mkdir()
    save_config(old, run / rundir.CONFIG)
    with pytest.raises(ConfigError, match=NEVER):
        load_config(run / rundir.CONFIG)
    assert rundir.read_config(run) == old
    args = argparse.Namespace(resume=str(run), config=None, episodes=None, allow_config_change=True)
    assert _resumed_config(args, [])[0] == old  # resumed as it was started
    assert _resumed_config(args, ["run.episodes=20"])[0].run.episodes == 20  # 640 steps: a batch of 512 by step 515
    with pytest.raises(ConfigError, match=NEVER):
        _resumed_config(args, ["run.episodes=4"])  # 128 steps x 1 row < 512
