"""Each learner declares its divergence bounds with its row (docs/reliability.md, "Divergence"):
the bounds name metrics the learner emits and config fields that exist, and a PPO run crossing
any of its bounds (value loss, approx_kl, |entropy|) stops with exit 3, one line naming the
quantity, the field, the episode, seed and network; a healthy run with the defaults does not.

Every training here is the same tiny PPO program (the bounds are read on the host: one
compilation, shared through the persistent compilation cache of tests/conftest.py): 2 robots,
16 steps per episode, an update every 8 steps, 2 episodes per chunk.
"""

import argparse
import dataclasses

import pandas as pd
import pytest
import toy_learner
import yaml

from fedjax_nav import cli, config, learner_table, rundir
from fedjax_nav.agents import learners
from fedjax_nav.cli.parser import build_parser
from fedjax_nav.learner_table import LEARNERS
from fedjax_nav.training.preflight import RESUME_CHANGEABLE

ROBOTS = 2
TINY = {
    "method": "iddpg",
    "learner": "ppo",
    "env": {"worlds": ["train-0", "train-0"], "episode_length": 16},  # the smallest room: compiles fastest
    "ppo": {"hidden": 8, "depth": 1, "rollout": 8, "minibatches": 2, "epochs": 2},
    "run": {"episodes": 4, "seeds": 1, "chunk_episodes": 2, "checkpoint_every": 2},
}


@pytest.fixture
def toy():
    learner_table.register(toy_learner.ROW)
    yield toy_learner.ROW
    learner_table.unregister("toy")


def test_every_bound_names_a_metric_of_its_learner_and_a_bound_field_of_its_sections(toy):
    """A bound's metric is one its learner reports (a registered learner's too); its field is a
    float of `run` or of one of the row's sections, 0 = off, on by default; the row's bounds reach
    the trainer's learner (`agents.learners.get`), and a resumed run may change every bound field."""
    train = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction)).choices["train"]
    help_text = next(a.help for a in train._actions if "--allow-config-change" in a.option_strings)
    for name, row in LEARNERS.items():
        learner = learners.get(name)
        assert learner.bounds == row.bounds and row.bounds, name
        for b in row.bounds:
            assert b.metric in learner.metrics, (name, b.metric, learner.metrics)
            f = config.field_info(b.field)
            assert b.field.split(".")[0] in ("run", *row.sections), (name, b.field)
            assert f.type in (float, "float") and f.metadata["lo"] == 0.0 and f.default > 0, b.field
            assert b.field in RESUME_CHANGEABLE and b.field in help_text, b.field
    assert "toy" in LEARNERS and set(learner_table.bound_fields()) == {
        b.field for r in LEARNERS.values() for b in r.bounds
    }


def test_the_offpolicy_bounds_keep_their_fields_and_ppo_answers_to_its_own():
    said = {name: {b.metric: b.field for b in row.bounds} for name, row in LEARNERS.items()}
    for name in learner_table.off_policy():
        assert said[name] == {"q": "run.max_abs_q", "critic_loss": "run.max_critic_loss"}, name
    assert said["ppo"] == {
        "value_loss": "run.max_critic_loss",  # the value net is PPO's critic
        "approx_kl": "ppo.max_approx_kl",
        "entropy": "ppo.max_abs_entropy",
    }
    run, ppo = config.RunConfig(), config.PPOConfig()
    assert (run.max_abs_q, run.max_critic_loss, ppo.max_approx_kl, ppo.max_abs_entropy) == (1e6, 1e12, 1e3, 1e3)
    assert {f.name for f in dataclasses.fields(ppo)} >= {"max_approx_kl", "max_abs_entropy"}


@pytest.fixture(scope="module")
def cfg_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("cfg") / "tiny_ppo.yaml"
    path.write_text(yaml.safe_dump(TINY))
    return path


def test_a_healthy_ppo_run_with_the_default_bounds_finishes(cfg_file, tmp_path):
    out = tmp_path / "run"
    assert cli.main(["train", "--config", str(cfg_file), "--out", str(out), "--quiet"]) == 0
    df = pd.read_csv(out / "metrics.csv")
    assert len(df) == 4 * ROBOTS and (df.approx_kl < 1).all() and (df.entropy.abs() < 5).all()


@pytest.mark.full  # four tiny PPO runs, the first compiles (~50 s cold)
@pytest.mark.parametrize(
    "setting, needles, good",
    [
        # the attack: PPO's value net is its critic, so run.max_critic_loss bounds its value loss
        ("run.max_critic_loss=1", ("the value loss reached", "above run.max_critic_loss = 1,"), 1),
        ("ppo.max_approx_kl=1e-9", ("the approximate KL (approx_kl) reached", "above ppo.max_approx_kl"), 0),
        ("ppo.max_abs_entropy=1e-9", ("the |entropy| estimate reached", "above ppo.max_abs_entropy"), 0),
        # a learning rate of 1 with the default bounds: approx_kl 4e4 in the first episode
        ("ppo.lr=1.0", ("the approximate KL (approx_kl) reached", "above ppo.max_approx_kl = 1000,"), 0),
    ],
)
def test_a_crossed_ppo_bound_stops_the_run_with_exit_3(cfg_file, tmp_path, capfd, setting, needles, good):
    """The line names the quantity, its bound, the first bad episode, the seed and the network;
    metrics.csv keeps the `good` episodes before it."""
    out = tmp_path / "run"
    rc = cli.main(["train", "--config", str(cfg_file), "--out", str(out), "--quiet", "--set", setting])
    err = capfd.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert rc == 3 and len(lines) == 1 and "Traceback" not in err, err[-3000:]
    for needle in (*needles, f"at episode {good}, seed 0, network 0 (robot 0)"):
        assert needle in lines[0], (needle, lines[0])
    df = pd.read_csv(out / "metrics.csv") if good else None
    assert good == 0 or sorted(df.episode.unique()) == list(range(good))
    assert not (out / rundir.LOCK).exists()
