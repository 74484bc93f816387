"""Live TensorBoard logging: `train --tensorboard` writes per-episode scalars that tensorboard's
own reader opens, equal to what metrics.csv (the record) says."""

import numpy as np
import pandas as pd
import pytest

from fedjax_nav import cli

event_accumulator = pytest.importorskip("tensorboard.backend.event_processing.event_accumulator")

TINY = [
    "--set",
    "env.episode_length=16",
    "--set",
    "run.episodes=4",
    "--set",
    "run.chunk_episodes=2",
    "--set",
    "ddpg.batch_size=8",
    "--set",
    "ddpg.hidden=16",
    "--set",
    "ddpg.buffer_size=64",
    "--set",
    "fed.period=1",
    "--set",
    "run.checkpoint_every=0",
    "--set",  # the smallest room: compile time grows with the obstacles
    "env.worlds=[train-0,train-0,train-0,train-0,train-0]",
    "--seeds",
    "2",
]


def read_scalars(folder):
    acc = event_accumulator.EventAccumulator(str(folder), size_guidance={event_accumulator.SCALARS: 0})
    acc.Reload()
    return {tag: {e.step: e.value for e in acc.Scalars(tag)} for tag in acc.Tags()["scalars"]}


def test_train_tensorboard_mirrors_metrics_csv(tmp_path):
    out = tmp_path / "run"
    assert cli.main(["train", "--config", "thesis/flddpg", "--out", str(out), "--quiet", "--tensorboard", *TINY]) == 0
    s = read_scalars(out / "tensorboard")
    df = pd.read_csv(out / "metrics.csv")
    per_ep = df.groupby("episode")
    for tag, col in [("mean/success", "reached_goal"), ("mean/reward", "reward"), ("mean/critic_loss", "critic_loss")]:
        assert sorted(s[tag]) == [0, 1, 2, 3], tag
        np.testing.assert_allclose([s[tag][e] for e in range(4)], per_ep[col].mean().to_numpy(), rtol=1e-5, atol=1e-7)
    robot0 = df[df.robot == 0].groupby("episode")["reached_goal"].mean().to_numpy()
    np.testing.assert_allclose([s["robot_0/success"][e] for e in range(4)], robot0, atol=1e-7)
    assert {"run/epsilon", "run/fed_events", "run/fed_bytes"} <= set(s)
    np.testing.assert_allclose(s["run/fed_events"][3], 1.0)  # fed.period = 1: one round per episode


def test_without_the_flag_nothing_is_written(tmp_path):
    out = tmp_path / "run"
    assert cli.main(["train", "--config", "thesis/flddpg", "--out", str(out), "--quiet", *TINY]) == 0
    assert not (out / "tensorboard").exists()
