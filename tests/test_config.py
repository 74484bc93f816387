"""Config: validation (each error names its key), overrides, round trips, the shipped presets
against the thesis's Table 2 (docs/reproduction.md), and the CLI's exit code 2 on a bad config."""

from pathlib import Path

import pytest
import yaml

from fedjax_nav import cli
from fedjax_nav.config import (
    SECTIONS,
    TOP_LEVEL,
    Config,
    ConfigError,
    apply_overrides,
    diff,
    from_dict,
    load_config,
    save_config,
    to_dict,
    traced_fields,
)

ROOT = Path(__file__).resolve().parents[1]
THESIS = sorted((ROOT / "configs" / "thesis").glob("*.yaml"))
PAPER = ROOT / "configs" / "paper" / "flddpg.yaml"
SHIPPED = THESIS + [PAPER]


def test_the_shipped_configs_are_all_there():
    names = sorted(p.stem for p in THESIS)
    assert names == sorted(["iddpg", "seddpg", "snddpg", "flddpg", "pwddpg", "rwddpg", "gsddpg", "flsddpg"])


# ----------------------------------------------------------------------------- rejections


@pytest.mark.parametrize(
    "data, key, what",
    [
        ({"ddpg": {"gama": 0.9}}, "ddpg.gama", "unknown key"),
        ({"ddpgs": {"gamma": 0.9}}, "ddpgs", "unknown key"),
        ({"env": {"worlds": ["train-0"], "dt_s": 0.1}}, "env.dt_s", "unknown key"),
        ({"offpolicy": {"batch_size": "big"}}, "offpolicy.batch_size", "integer"),
        ({"offpolicy": {"batch_size": 8.5}}, "offpolicy.batch_size", "integer"),
        ({"offpolicy": {"batch_size": True}}, "offpolicy.batch_size", "integer"),
        ({"offpolicy": {"gamma": "0.9"}}, "offpolicy.gamma", "number"),
        ({"offpolicy": {"gamma": float("nan")}}, "offpolicy.gamma", "finite"),
        ({"fed": {"include_targets": 1}}, "fed.include_targets", "true or false"),
        ({"env": {"worlds": "train-0"}}, "env.worlds", "list"),
        ({"env": {"worlds": []}}, "env.worlds", "list"),
        ({"method": 3}, "method", "string"),
        ({"method": "ppo"}, "method", "not one of"),
        ({"env": {"collision_test": "sonar"}}, "env.collision_test", "not one of"),
        ({"offpolicy": {"gamma": 1.5}}, "offpolicy.gamma", "out of range"),
        ({"ddpg": {"rho": -0.1}}, "ddpg.rho", "out of range"),
        ({"fed": {"tau": 2}}, "fed.tau", "out of range"),
        ({"env": {"episode_length": 0}}, "env.episode_length", "out of range"),
        ({"run": {"seeds": 0}}, "run.seeds", "out of range"),
        ({"ddpg": "fast"}, "ddpg", "mapping"),
        ({"offpolicy": "fast"}, "offpolicy", "mapping"),
    ],
)
def test_invalid_values_are_rejected_naming_the_key(data, key, what):
    with pytest.raises(ConfigError) as e:
        from_dict(data, "bad.yaml")
    msg = str(e.value)
    assert "bad.yaml" in msg and key in msg and what in msg, msg


@pytest.mark.parametrize(
    "data, keys",
    [
        ({"offpolicy": {"buffer_size": 64, "batch_size": 128}}, ["offpolicy.buffer_size", "offpolicy.batch_size"]),
        (
            {"offpolicy": {"buffer_size": 64, "batch_size": 8, "buffer_alloc": 32}},
            ["offpolicy.buffer_alloc", "offpolicy.buffer_size"],
        ),
        ({"fed": {"period": 10}, "run": {"episodes": 4, "chunk_episodes": 1}}, ["fed.period", "run.episodes"]),
        (
            {
                "fed": {"period_unit": "steps", "period": 100},
                "env": {"episode_length": 16},
                "run": {"episodes": 4, "chunk_episodes": 1},
            },
            ["fed.period"],
        ),
        ({"run": {"episodes": 10, "chunk_episodes": 3}}, ["run.episodes", "run.chunk_episodes"]),
        (
            {"run": {"episodes": 10, "chunk_episodes": 5, "checkpoint_every": 7}},
            ["run.checkpoint_every", "run.chunk_episodes"],
        ),
    ],
)
def test_inconsistent_fields_are_rejected_naming_them(data, keys):
    with pytest.raises(ConfigError) as e:
        from_dict(data, "bad.yaml")
    for k in keys:
        assert k in str(e.value), str(e.value)


@pytest.mark.parametrize(
    "overrides, sizes",
    [
        (["run.episodes=2"], (2, 2, 24)),  # the smoke run: chunk 5 -> 2, checkpoints 25 -> 24
        (["run.episodes=7"], (7, 1, 25)),  # a prime: chunks of one episode
        (["run.episodes=12"], (12, 4, 24)),
        (["run.episodes=4", "run.checkpoint_every=0"], (4, 4, 0)),  # 0 (only at the end) stays
        (["run.chunk_episodes=1"], (125, 1, 25)),
        (["run.episodes=10", "run.chunk_episodes=2"], (10, 2, 24)),
        (["run.episodes=125"], (125, 5, 25)),  # a config that passes is unchanged
    ],
)
def test_the_chunk_and_checkpoint_sizes_follow_the_command_line(overrides, sizes):
    r = load_config(ROOT / "configs" / "thesis" / "iddpg.yaml", overrides).run
    assert (r.episodes, r.chunk_episodes, r.checkpoint_every) == sizes


@pytest.mark.parametrize(
    "overrides, flag",
    [
        (["run.episodes=2", "run.chunk_episodes=3"], "--set run.chunk_episodes=3"),
        (["run.chunk_episodes=2"], "--set run.chunk_episodes=2"),  # 125 episodes
        (["run.checkpoint_every=7"], "--set run.checkpoint_every=7"),
        (["run.episodes=2", "run.checkpoint_every=3"], "--set run.checkpoint_every=3"),
    ],
)
def test_sizes_set_on_the_command_line_that_conflict_are_refused_naming_the_flag(overrides, flag):
    with pytest.raises(ConfigError) as e:
        load_config(ROOT / "configs" / "thesis" / "iddpg.yaml", overrides)
    msg = str(e.value)
    assert msg.startswith(flag + ":") and "\n" not in msg, msg


def test_the_defaults_are_the_thesis_flddpg_preset():
    # `fedjax-nav train` without --config names this preset as what the defaults train
    from fedjax_nav.cli.train import DEFAULT_PRESET
    from fedjax_nav.config import Config, diff

    assert diff(Config(), load_config(DEFAULT_PRESET)) == []


@pytest.mark.parametrize("method", ["iddpg", "seddpg", "snddpg"])
def test_the_federated_period_does_not_constrain_methods_without_a_federated_step(method):
    # `--episodes 1` with the thesis presets (E_update = 2) is a smoke run, not an error, when no
    # federated step exists
    cfg = load_config(
        ROOT / "configs" / "thesis" / f"{method}.yaml",
        ["run.episodes=1", "run.chunk_episodes=1", "run.checkpoint_every=0"],
    )
    assert cfg.run.episodes == 1 and cfg.fed.period == 2
    with pytest.raises(ConfigError, match="fed.period"):
        load_config(
            ROOT / "configs" / "thesis" / "flddpg.yaml",
            ["run.episodes=1", "run.chunk_episodes=1", "run.checkpoint_every=0"],
        )


def test_a_config_symlink_loop_is_named_as_one(tmp_path):
    loop = tmp_path / "loop.yaml"
    loop.symlink_to(loop)
    with pytest.raises(ConfigError) as e:
        load_config(loop)
    assert str(e.value).startswith(f"{loop}: is a symlink loop") and "no such" not in str(e.value), str(e.value)


def test_missing_and_malformed_files(tmp_path):
    with pytest.raises(ConfigError, match="no such config file"):
        load_config(tmp_path / "nope.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("offpolicy: [unclosed\n")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_config(bad)
    bad.write_text("- just\n- a list\n")
    with pytest.raises(ConfigError, match="mapping"):
        load_config(bad)


def test_cli_train_with_a_bad_config_returns_2_and_names_the_key(tmp_path, capsys):
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump({"method": "flddpg", "offpolicy": {"gamma": 0.9, "learning_rate": 0.1}}))
    assert cli.main(["train", "--config", str(bad), "--out", str(tmp_path / "run"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error:") and "offpolicy.learning_rate" in err and str(bad) in err
    assert len(err.strip().splitlines()) == 1  # one line, no traceback
    assert not (tmp_path / "run").exists()  # nothing started
    # a bad --set is reported the same way
    good = tmp_path / "good.yaml"
    good.write_text(yaml.safe_dump({"method": "iddpg"}))
    assert (
        cli.main(
            ["train", "--config", str(good), "--set", "offpolicy.gamma=2", "--quiet", "--out", str(tmp_path / "run")]
        )
        == 2
    )
    assert "offpolicy.gamma" in capsys.readouterr().err


# ----------------------------------------------------------------------------- overrides


def test_set_overrides_parse_yaml_values_and_validate():
    cfg = load_config(
        PAPER,
        [
            "offpolicy.gamma=0.99",
            "env.worlds=[train-0, eval]",
            "fed.include_targets=true",
            "method=gsddpg",
            "offpolicy.batch_size=64",
            "ddpg.rho=0.5",
        ],
    )
    assert cfg.offpolicy.gamma == 0.99 and isinstance(cfg.offpolicy.gamma, float)
    assert cfg.env.worlds == ("train-0", "eval") and cfg.num_robots == 2
    assert cfg.fed.include_targets is True and cfg.method == "gsddpg" and cfg.offpolicy.batch_size == 64
    base = load_config(PAPER)
    assert sorted(diff(base, cfg)) == sorted(
        ["method", "env.worlds", "offpolicy.gamma", "offpolicy.batch_size", "fed.include_targets", "ddpg.rho"]
    )
    with pytest.raises(ConfigError, match="key=value"):
        load_config(PAPER, ["offpolicy.gamma"])
    with pytest.raises(ConfigError, match="unknown key 'optim.lr'"):
        load_config(PAPER, ["optim.lr=0.1"])
    with pytest.raises(ConfigError, match="offpolicy.lrate"):
        load_config(PAPER, ["offpolicy.lrate=0.1"])
    with pytest.raises(ConfigError, match="offpolicy.lr"):
        load_config(PAPER, ["offpolicy.lr=fast"])


def test_apply_overrides_does_not_mutate_the_callers_dict():
    data = {"offpolicy": {"gamma": 0.9}, "fed": None}
    out = apply_overrides(data, ["offpolicy.gamma=0.5", "fed.tau=1.0", "run.seeds=3"])
    assert data == {"offpolicy": {"gamma": 0.9}, "fed": None}
    assert out == {"offpolicy": {"gamma": 0.5}, "fed": {"tau": 1.0}, "run": {"seeds": 3}}


# ----------------------------------------------------------------------------- round trips


@pytest.mark.parametrize("path", SHIPPED, ids=lambda p: f"{p.parent.name}/{p.stem}")
def test_round_trip_to_dict_from_dict_and_save_load(path, tmp_path):
    cfg = load_config(path)
    assert cfg.method == path.stem
    assert from_dict(to_dict(cfg)) == cfg
    save_config(cfg, tmp_path / "c.yaml")
    assert load_config(tmp_path / "c.yaml") == cfg
    # the saved file is plain YAML with every section and field (one to one with the dataclasses)
    saved = yaml.safe_load((tmp_path / "c.yaml").read_text())
    assert set(saved) == {*TOP_LEVEL, *SECTIONS} and list(saved)[:2] == ["method", "learner"]
    assert set(saved["offpolicy"]) == set(to_dict(Config())["offpolicy"])
    assert set(saved["ddpg"]) == set(to_dict(Config())["ddpg"])


def test_defaults_round_trip_and_traced_fields():
    """Every env/offpolicy/ddpg/fed field is either traced or documented as static, never both: the
    `traced=True` metadata is the one declaration (tests/test_sweep.py checks that the trained
    program reads every traced field)."""
    from dataclasses import fields

    from fedjax_nav.config import SECTIONS

    assert from_dict({}) == Config() == load_config(None)
    t = set(traced_fields())
    for section in ("env", "offpolicy", "ddpg", "fed"):
        for f in fields(SECTIONS[section]):
            name = f"{section}.{f.name}"
            static = "(static" in f.metadata["doc"]
            assert static != (name in t), f"{name}: traced={name in t} but doc says {f.metadata['doc']!r}"
    assert not {n for n in t if n.startswith("run.")}  # run fields are bookkeeping, never in the program
    assert {"env.v_max", "env.collision_distance", "offpolicy.buffer_size", "fed.period"} <= t


# ----------------------------------------------------------------------------- presets (Table 2)

THESIS_BUFFERS = {"iddpg": 30_000, "seddpg": 50_000, "snddpg": 70_000, "flddpg": 10_000}


@pytest.mark.parametrize("path", THESIS, ids=lambda p: p.stem)
def test_thesis_presets_match_table2(path):
    c = load_config(path)
    assert c.num_robots == 5 and "train-1" not in c.env.worlds
    assert (c.run.episodes, c.env.episode_length) == (125, 1024)
    assert (c.offpolicy.train_every, c.ddpg.target_every, c.offpolicy.batch_size) == (5, 5, 512)
    assert (c.ddpg.epsilon_start, c.ddpg.epsilon_decay) == (0.9, 0.99997)
    assert (c.offpolicy.lr, c.offpolicy.gamma, c.ddpg.rho, c.offpolicy.hidden) == (1e-3, 0.9, 1.0, 64)
    assert c.env.v_max == 0.25
    assert (c.fed.period_unit, c.fed.period, c.fed.tau) == ("episodes", 2, 0.5)
    if path.stem in THESIS_BUFFERS:
        assert c.offpolicy.buffer_size == THESIS_BUFFERS[path.stem]


def test_paper_preset_matches_table2():
    c = load_config(PAPER)
    assert c.num_robots == 6 and c.method == "flddpg"
    assert (c.run.episodes, c.env.episode_length, c.offpolicy.buffer_size) == (1000, 256, 50_000)
    assert (c.ddpg.epsilon_start, c.ddpg.epsilon_decay, c.offpolicy.lr) == (0.9, 0.99995, 1e-4)
    assert (c.offpolicy.gamma, c.ddpg.rho, c.offpolicy.batch_size, c.offpolicy.hidden) == (0.9, 0.01, 512, 512)
    assert c.env.v_max == 1.0 and (c.fed.period_unit, c.fed.period, c.fed.tau) == ("episodes", 1, 0.5)
