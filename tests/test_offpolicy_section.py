"""The offpolicy section (docs/learners.md, "Configuration"): the settings the replay learners share,
and their old names `ddpg.<field>` read as `offpolicy.<field>` wherever a field is written: a config
file, a run's saved config.yaml, `--set`, a sweep file's keys. A config spelled either way is the
same Config with the same point id; one field given two values under its two names is refused in
one line naming both. Nothing here trains."""

from __future__ import annotations

from dataclasses import fields
from pathlib import Path

import pytest
import yaml

from fedjax_nav import rundir
from fedjax_nav.config import (
    LEGACY_ALIASES,
    SECTIONS,
    Config,
    ConfigError,
    DDPGConfig,
    OffPolicyConfig,
    apply_overrides,
    canonical,
    field_info,
    from_dict,
    get,
    load_config,
    to_dict,
    traced_fields,
)
from fedjax_nav.config import sweepfile as sf
from fedjax_nav.configs import names

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "configs" / "paper" / "flddpg.yaml"
THESIS = ROOT / "configs" / "thesis" / "flddpg.yaml"
DDPG_OWN = ("rho", "target_every", "epsilon_start", "epsilon_decay")


def old_layout(data: dict) -> dict:
    """A config mapping as it was written before the offpolicy section: its fields in `ddpg:`."""
    data = {k: dict(v) if isinstance(v, dict) else v for k, v in data.items()}
    moved = data.pop("offpolicy", None) or {}
    data["ddpg"] = {**moved, **(data.get("ddpg") or {})}
    return data


def write(path: Path, data: dict) -> Path:
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


# ----------------------------------------------------------------------------- the schema


def test_the_sections_split_the_old_ddpg_fields_without_sharing_a_name():
    own, shared = {f.name for f in fields(DDPGConfig)}, {f.name for f in fields(OffPolicyConfig)}
    assert own == set(DDPG_OWN) and not own & shared
    assert set(LEGACY_ALIASES) == {f"ddpg.{n}" for n in shared}  # derived: every offpolicy field has its old name
    assert all(canonical(old) == new for old, new in LEGACY_ALIASES.items())
    assert canonical("ddpg.rho") == "ddpg.rho" and canonical("fed.tau") == "fed.tau"
    assert list(SECTIONS)[:3] == ["env", "offpolicy", "ddpg"]
    # the traced declaration moved with the fields: the trainer's HParams reads hp.offpolicy.gamma
    assert {"offpolicy.gamma", "offpolicy.lr", "offpolicy.buffer_size", "offpolicy.random_steps"} <= set(
        traced_fields()
    )
    assert not {n for n in traced_fields() if n.startswith("ddpg.")} - {f"ddpg.{n}" for n in DDPG_OWN}
    # the old name reads the same field
    assert field_info("ddpg.gamma") is field_info("offpolicy.gamma")
    assert get(Config(), "ddpg.batch_size") == Config().offpolicy.batch_size == 512


def test_the_replay_learners_read_the_offpolicy_section():
    from fedjax_nav.learner_table import LEARNERS

    for name in ("ddpg", "td3", "sac"):
        row = LEARNERS[name]
        assert row.sections[0] == "offpolicy" and row.actor_section == "offpolicy"
        assert (row.update_every, row.steps_per_update) == ("offpolicy.train_every", ("offpolicy.gradient_steps",))
    assert LEARNERS["ddpg"].sections == ("offpolicy", "ddpg")
    assert "offpolicy" not in LEARNERS["ppo"].sections


def test_hparams_hold_the_offpolicy_struct():
    from fedjax_nav.config.traced import HParams, hparams_from_config

    hp = hparams_from_config(load_config(PAPER))
    assert float(hp.offpolicy.lr) == pytest.approx(1e-4) and float(hp.ddpg.rho) == pytest.approx(0.01)
    assert not hasattr(hp.ddpg, "gamma")
    assert set(HParams().to_flat()) == set(traced_fields())


# ----------------------------------------------------------------------------- config files


def test_an_old_ddpg_section_is_read_into_offpolicy(tmp_path):
    old = write(tmp_path / "old.yaml", {"method": "iddpg", "ddpg": {"gamma": 0.99, "hidden": 32, "rho": 0.5}})
    new = write(
        tmp_path / "new.yaml", {"method": "iddpg", "offpolicy": {"gamma": 0.99, "hidden": 32}, "ddpg": {"rho": 0.5}}
    )
    cfg = load_config(old)
    assert (cfg.offpolicy.gamma, cfg.offpolicy.hidden, cfg.ddpg.rho) == (0.99, 32, 0.5)
    assert cfg == load_config(new) and sf.point_id(cfg) == sf.point_id(load_config(new))


@pytest.mark.parametrize("name", names("config"))
def test_every_shipped_config_spelled_the_old_way_is_the_same_config_and_point(name, tmp_path):
    """The shipped configs are written with `offpolicy:`; the same file with `ddpg:` holding those
    fields (as every config before the section was) is an equal Config with the same point id."""
    cfg = load_config(name)
    old = old_layout(to_dict(cfg))
    assert set(old["ddpg"]) == {f.name for s in ("offpolicy", "ddpg") for f in fields(SECTIONS[s])}
    again = load_config(write(tmp_path / "old.yaml", old))
    assert again == cfg and sf.point_id(again) == sf.point_id(cfg)
    assert from_dict(old_layout(yaml.safe_load((ROOT / "configs" / f"{name}.yaml").read_text()))) == cfg


def test_one_field_under_both_names_with_two_values_is_one_line_naming_both(tmp_path):
    bad = write(tmp_path / "both.yaml", {"ddpg": {"gamma": 0.9}, "offpolicy": {"gamma": 0.99}})
    with pytest.raises(ConfigError) as e:
        load_config(bad)
    msg = str(e.value)
    assert msg.startswith(str(bad)) and "ddpg.gamma (0.9)" in msg and "offpolicy.gamma (0.99)" in msg
    assert "\n" not in msg
    # the same value twice is the field once; 0.001 and YAML 1.1's string "1e-3" are one number
    same = write(tmp_path / "same.yaml", {"ddpg": {"gamma": 0.99, "lr": 0.001}, "offpolicy": {"gamma": 0.99}})
    (tmp_path / "lr.yaml").write_text("ddpg:\n  lr: 0.001\noffpolicy:\n  lr: 1e-3\n")
    assert load_config(same).offpolicy.gamma == 0.99 and load_config(tmp_path / "lr.yaml").offpolicy.lr == 1e-3


@pytest.mark.parametrize(
    "data, needles",
    [
        ({"ddpg": {"gamma": 1.5}}, ["bad.yaml: ddpg.gamma: 1.5 is out of range"]),  # named as written
        ({"offpolicy": {"gamma": 1.5}}, ["bad.yaml: offpolicy.gamma: 1.5 is out of range"]),
        ({"ddpg": {"gama": 0.9}}, ["unknown key 'ddpg.gama'", "rho, target_every", "gamma"]),
        ({"offpolicy": {"rho": 0.5}}, ["unknown key 'offpolicy.rho'", "allowed in 'offpolicy'"]),
        ({"ddpg": {"gamma": 0.9}, "offpolicy": "fast"}, ["'offpolicy' must be a mapping"]),
        (
            {"ddpg": {"buffer_size": 64, "batch_size": 128}},
            ["offpolicy.buffer_size (64)", "offpolicy.batch_size (128)"],
        ),
    ],
)
def test_errors_name_the_field_as_written(data, needles):
    with pytest.raises(ConfigError) as e:
        from_dict(data, "bad.yaml")
    assert all(n in str(e.value) for n in needles) and "\n" not in str(e.value), str(e.value)


# ----------------------------------------------------------------------------- --set


def test_set_by_the_old_name_is_the_new_field():
    assert load_config(PAPER, ["ddpg.gamma=0.99"]) == load_config(PAPER, ["offpolicy.gamma=0.99"])
    cfg = load_config(PAPER, ["ddpg.gamma=0.99", "ddpg.rho=0.5"])
    assert (cfg.offpolicy.gamma, cfg.ddpg.rho) == (0.99, 0.5)
    with pytest.raises(ConfigError, match=r"^--set: ddpg\.gamma: 2 is out of range"):
        load_config(PAPER, ["ddpg.gamma=2"])


def test_set_replaces_the_field_under_either_name(tmp_path):
    """`--set` overrides a field whichever name the file gave it: no conflict with the file."""
    old = write(tmp_path / "old.yaml", {"ddpg": {"gamma": 0.9}})
    new = write(tmp_path / "new.yaml", {"offpolicy": {"gamma": 0.9}})
    for path in (old, new):
        for key in ("ddpg.gamma", "offpolicy.gamma"):
            assert load_config(path, [f"{key}=0.8"]).offpolicy.gamma == 0.8
    out = apply_overrides({"ddpg": {"gamma": 0.9, "rho": 0.5}}, ["offpolicy.gamma=0.8"])
    assert out == {"ddpg": {"rho": 0.5}, "offpolicy": {"gamma": 0.8}}
    # repeated, the last one wins, as for any key given twice
    assert load_config(None, ["ddpg.gamma=0.5", "offpolicy.gamma=0.6"]).offpolicy.gamma == 0.6


def test_the_train_command_line_reads_the_old_name(tmp_path):
    from fedjax_nav.cli.parser import build_parser
    from fedjax_nav.cli.train import _train_config

    argv = ["train", "--config", str(PAPER), "--set", "ddpg.gamma=0.99", "--set", "ddpg.batch_size=64"]
    cfg, _, src = _train_config(build_parser().parse_args([*argv, "--out", str(tmp_path / "run")]))
    assert cfg == load_config(PAPER, ["offpolicy.gamma=0.99", "offpolicy.batch_size=64"]) and "with --set" in src


# ----------------------------------------------------------------------------- sweeps


def sweep_file(folder: Path, name: str, **spec) -> Path:
    return write(folder / f"{name}.yaml", {"name": name, "base": str(THESIS), "seeds": 1, **spec})


def test_a_sweep_over_the_old_name_keeps_it_in_labels_and_points(tmp_path):
    old = sf.load_sweep(sweep_file(tmp_path, "old", grid={"ddpg.gamma": [0.8, 0.99]}, set=["ddpg.batch_size=64"]))
    new = sf.load_sweep(
        sweep_file(tmp_path, "new", grid={"offpolicy.gamma": [0.8, 0.99]}, set=["offpolicy.batch_size=64"])
    )
    assert [p.cfg for p in old.points] == [p.cfg for p in new.points]
    assert [p.id for p in old.points] == [p.id for p in new.points]
    assert [p.cfg.offpolicy.gamma for p in old.points] == [0.8, 0.99] and old.points[0].cfg.offpolicy.batch_size == 64
    # what the user wrote is what the tables show (results.csv's column, the labels)
    assert old.keys == ("ddpg.gamma",) and old.points[1].values == {"ddpg.gamma": 0.99}
    assert old.points[1].label == "ddpg.gamma=0.99" and new.points[1].label == "offpolicy.gamma=0.99"
    # --only by either name
    assert sf.select(old, ["offpolicy.gamma=0.99"]) == sf.select(old, ["ddpg.gamma=0.99"]) == (old.points[1],)


def test_a_sweep_over_both_names_of_one_field_is_refused(tmp_path):
    path = sweep_file(tmp_path, "both", grid={"ddpg.gamma": [0.8], "offpolicy.gamma": [0.9]})
    with pytest.raises(sf.SweepError, match="ddpg.gamma and offpolicy.gamma are one field"):
        sf.load_sweep(path)
    path = sweep_file(tmp_path, "both_points", points=[{"offpolicy.lr": 0.01, "ddpg.lr": 0.02}])
    with pytest.raises(sf.SweepError, match="offpolicy.lr and ddpg.lr are one field"):
        sf.load_sweep(path)


def test_the_buffer_scale_reads_a_base_of_either_layout(tmp_path):
    cfg = load_config(THESIS)
    base = write(tmp_path / "old_base.yaml", old_layout(to_dict(cfg)))
    for b in (base, THESIS):
        (p,) = sf.load_sweep(sweep_file(tmp_path, "scaled", base=str(b)), buffer_scale=0.02).points
        assert p.cfg.offpolicy.buffer_size == 512  # 10000 x 0.02 = 200, at least the batch (512)


# ----------------------------------------------------------------------------- an old run directory


def test_an_old_run_directory_loads_and_its_checkpoint_config_compares_equal(tmp_path):
    """A run saved before the section: config.yaml and the config in its checkpoints hold `ddpg:`.
    `--resume` reads config.yaml to the same Config and finds the checkpoint's config unchanged;
    a value changed since is named by its name now."""
    from fedjax_nav.training.preflight import check_resumable, to_dict_flat

    cfg = load_config(THESIS, ["run.episodes=10"])
    old = old_layout(to_dict(cfg))
    run = tmp_path / "run"
    run.mkdir()
    write(run / rundir.CONFIG, old)
    assert rundir.read_config(run) == cfg

    class Saved:  # a Checkpointer whose checkpoint holds the old layout
        def __init__(self, saved):
            self.saved, self.dir = saved, run / "checkpoints"

        def saved_config(self, step=None):
            return self.saved

    check_resumable(Saved(old), cfg, run, allow_config_change=False, step=4)
    changed = old_layout(to_dict(load_config(THESIS, ["run.episodes=10", "offpolicy.gamma=0.5"])))
    with pytest.raises(ConfigError, match=r"offpolicy\.gamma"):
        check_resumable(Saved(changed), cfg, run, allow_config_change=False, step=4)
    # the fallback comparison (a saved config this code cannot read) names the fields the same way
    assert to_dict_flat(old)["offpolicy.gamma"] == 0.9 and "ddpg.gamma" not in to_dict_flat(old)
