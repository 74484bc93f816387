"""Live TensorBoard logging: `train --tensorboard` writes per-episode scalars that tensorboard's
own reader opens, equal to what metrics.csv (the record) says."""

import json

import numpy as np
import pandas as pd
import pytest
import yaml

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
    "offpolicy.batch_size=8",
    "--set",
    "offpolicy.hidden=16",
    "--set",
    "offpolicy.buffer_size=64",
    "--set",
    "fed.period=1",
    "--set",
    "run.checkpoint_every=0",
    "--set",  # the smallest room: compile time grows with the obstacles
    "env.worlds=[train-0,train-0,train-0,train-0,train-0]",
    "--seeds",
    "2",
]


STEPS = 16 * 5  # agent-steps per episode: env.episode_length x 5 robots x 1 environment each


def accumulator(folder):
    guidance = {event_accumulator.SCALARS: 0, event_accumulator.TENSORS: 0}
    acc = event_accumulator.EventAccumulator(str(folder), size_guidance=guidance)
    acc.Reload()
    return acc


def read_scalars(folder):
    acc = accumulator(folder)
    return {tag: {e.step: e.value for e in acc.Scalars(tag)} for tag in acc.Tags()["scalars"]}


def test_train_tensorboard_mirrors_metrics_csv(tmp_path):
    out = tmp_path / "run"
    assert cli.main(["train", "--config", "thesis/flddpg", "--out", str(out), "--quiet", "--tensorboard", *TINY]) == 0
    s = read_scalars(out / "tensorboard")
    df = pd.read_csv(out / "metrics.csv")
    per_ep = df.groupby("episode")
    # the x-axis: agent-steps at the end of each episode (environment steps over the fleet)
    steps = [STEPS * (e + 1) for e in range(4)]
    assert s["run/episode"] == {STEPS * (e + 1): e for e in range(4)}
    for tag, col in [("mean/success", "reached_goal"), ("mean/reward", "reward"), ("mean/critic_loss", "critic_loss")]:
        assert sorted(s[tag]) == steps, tag
        np.testing.assert_allclose([s[tag][t] for t in steps], per_ep[col].mean().to_numpy(), rtol=1e-5, atol=1e-7)
    robot0 = df[df.robot == 0].groupby("episode")["reached_goal"].mean().to_numpy()
    np.testing.assert_allclose([s["robot_0/success"][t] for t in steps], robot0, atol=1e-7)
    assert {"run/epsilon", "run/fed_events", "run/fed_bytes"} <= set(s)
    np.testing.assert_allclose(s["run/fed_events"][steps[-1]], 1.0)  # fed.period = 1: one round per episode
    # the HParams metric: summary.json's success_last, at the last step
    summary = json.loads((out / "summary.json").read_text())
    np.testing.assert_allclose(s["hparam/success_last"][steps[-1]], summary["success_last"], atol=1e-6)


def test_train_tensorboard_logs_the_hyperparameters_and_the_config(tmp_path):
    """Every config field reaches the HParams dashboard (its session start info), and config.yaml
    the text tag `config`."""
    from tensorboard.plugins.hparams import plugin_data_pb2

    out = tmp_path / "run"
    argv = ["train", "--config", "thesis/flddpg", "--out", str(out), "--quiet", "--tensorboard", *TINY]
    assert cli.main([*argv, "--set", "offpolicy.gamma=0.95"]) == 0
    acc = accumulator(out / "tensorboard")
    content = acc.PluginTagToContent("hparams")
    start = [plugin_data_pb2.HParamsPluginData.FromString(c) for t, c in content.items() if "session_start" in t]
    assert len(start) == 1
    hp = start[0].session_start_info.hparams
    assert hp["offpolicy.gamma"].number_value == pytest.approx(0.95) and hp["method"].string_value == "flddpg"
    assert hp["env.worlds"].string_value == ",".join(["train-0"] * 5) and hp["run.tensorboard"].bool_value
    saved = yaml.safe_load((out / "config.yaml").read_text())
    assert len(hp) == sum(len(v) if isinstance(v, dict) else 1 for v in saved.values())
    experiment = [plugin_data_pb2.HParamsPluginData.FromString(c) for t, c in content.items() if "experiment" in t]
    assert [m.name.tag for m in experiment[0].experiment.metric_infos] == ["hparam/success_last"]
    text = acc.Tensors("config/text_summary")[0].tensor_proto.string_val[0].decode()
    assert "gamma: 0.95" in text and "method: flddpg" in text


def test_without_the_flag_nothing_is_written(tmp_path):
    out = tmp_path / "run"
    assert cli.main(["train", "--config", "thesis/flddpg", "--out", str(out), "--quiet", *TINY]) == 0
    assert not (out / "tensorboard").exists()


def test_a_resumed_log_counts_the_episodes_done_before_in_the_success_metric(tmp_path):
    """After `train --resume`, the episodes already done (`remember`) are not written again but
    count towards `hparam/success_last`, which then equals summary.json's success_last over the
    whole run (`rundir.success_last_per_seed`); the x-axis unit follows the fleet's size."""
    from fedjax_nav import rundir
    from fedjax_nav.config import load_config
    from fedjax_nav.training.tblog import TensorBoardLog

    cfg = load_config("thesis/flddpg", ["env.episode_length=16", "env.envs_per_robot=2", "run.episodes=40"])
    rng = np.random.default_rng(0)
    df = pd.DataFrame(
        [
            {"episode": e, "seed": s, "robot": r, "reached_goal": bool(rng.random() < e / 40), "reward": rng.random()}
            for e in range(40)
            for s in range(2)
            for r in range(5)
        ]
    )
    log = TensorBoardLog(tmp_path, cfg)
    log.remember(df[df.episode < 30])
    log.episodes(df[df.episode >= 30])
    log.close()
    s = read_scalars(tmp_path / "tensorboard")
    unit = 16 * 5 * 2  # steps x robots x environments per robot
    assert sorted(s["mean/reward"]) == [unit * (e + 1) for e in range(30, 40)]  # only the new episodes
    expected = float(rundir.success_last_per_seed(df).mean())
    assert expected != float(rundir.success_last_per_seed(df[df.episode >= 30]).mean())  # the window matters
    np.testing.assert_allclose(s["hparam/success_last"][unit * 40], expected, atol=1e-6)
