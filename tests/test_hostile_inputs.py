"""Hostile config, world and `--set` inputs (docs/reliability.md, "Hostile inputs"): each is one
line naming the file (or `--set`) and the field, raised fast, before anything is built.

In-process and without training: the whole file runs in a few seconds.
"""

import dataclasses
import io
import json
import os
import threading
import time
from contextlib import redirect_stderr
from pathlib import Path

import numpy as np
import pytest
import yaml

from fedjax_nav import cli, config, worlds
from fedjax_nav.config import ConfigError, from_dict, load_config
from fedjax_nav.config.io import MAX_FILE_BYTES, MAX_NODES
from fedjax_nav.training.hparams import dtype, hparams_from_config

ROOM = {"size": [4, 4], "starts": [[0, 0, 0]], "goals": [[1, 1]]}
INT_FIELDS = [
    f"{s}.{f.name}" for s, cls in config.SECTIONS.items() for f in dataclasses.fields(cls) if f.type in (int, "int")
]
FLOAT_FIELDS = [
    f"{s}.{f.name}" for s, cls in config.SECTIONS.items() for f in dataclasses.fields(cls) if f.type in (float, "float")
]


def alias_bomb(levels: int = 9, fanout: int = 9) -> str:
    """One YAML flow value of `levels` levels of `fanout` aliases: fanout^levels strings from a few
    hundred bytes (`&a0 [lol, ...]`, then `&a1 [*a0, *a0, ...]`, ...)."""
    value = "&a0 [" + ", ".join(["lol"] * fanout) + "]"
    for i in range(1, levels + 1):
        value = f"&a{i} [{value}, " + ", ".join([f"*a{i - 1}"] * (fanout - 1)) + "]"
    return value


def cli_one_line(argv) -> str:
    """`fedjax-nav ...` in-process: exit 2 and one `error:` line on stderr, returned."""
    err = io.StringIO()
    with redirect_stderr(err):
        rc = cli.main([str(a) for a in argv])
    lines = [ln for ln in err.getvalue().splitlines() if ln.strip()]
    assert rc == 2 and len(lines) == 1 and lines[0].startswith("error: "), (rc, err.getvalue()[-2000:])
    return lines[0]


def refused(fn, *args) -> str:
    """The one-line ConfigError / WorldError of fn(*args), and that it came in under a second."""
    t = time.perf_counter()
    with pytest.raises((ConfigError, worlds.WorldError)) as e:
        fn(*args)
    assert time.perf_counter() - t < 1.0, "refused too slowly"
    msg = str(e.value)
    assert "\n" not in msg and len(msg) < 600, msg
    return msg


def write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


# ----------------------------------------------------------------------------- alias bombs, non-regular files


def test_an_alias_bomb_is_refused_in_well_under_a_second(tmp_path):
    path = write(tmp_path / "bomb.yaml", f"run:\n  eval_suite: {alias_bomb()}\n")
    msg = refused(load_config, path)
    assert str(path) in msg and "aliases" in msg and f"{MAX_NODES:,}" in msg, msg
    msg = refused(load_config, None, [f"run.eval_suite={alias_bomb()}"])
    assert msg.startswith("--set run.eval_suite: ") and "aliases" in msg, msg
    world = write(tmp_path / "bomb.yaml", f"size: [4, 4]\nstarts: [[0, 0, 0]]\ngoals: [[1, 1]]\nname: {alias_bomb()}\n")
    assert "aliases" in refused(worlds.load, world)


def test_a_recursive_alias_is_refused(tmp_path):
    assert "recursive" in refused(load_config, None, ["env.worlds=&a [*a]"])


@pytest.mark.parametrize("device", ["/dev/zero", "/dev/urandom"])
def test_devices_are_refused_without_reading_them(device):
    assert "not a regular file" in refused(load_config, device)
    assert "not a regular file" in refused(worlds.load, device)


def test_a_fifo_is_refused_without_blocking(tmp_path):
    fifo = tmp_path / "fifo.yaml"
    os.mkfifo(fifo)
    results = []

    def load():
        for fn in (load_config, worlds.load):
            try:
                fn(fifo)
            except (ConfigError, worlds.WorldError) as e:
                results.append(str(e))

    reader = threading.Thread(target=load, daemon=True)  # the old reader blocked here forever
    reader.start()
    reader.join(timeout=10)
    assert not reader.is_alive(), "reading a FIFO blocked"
    assert len(results) == 2 and all(str(fifo) in m and "a FIFO" in m for m in results), results


def test_files_beyond_the_size_bound_are_refused_before_reading(tmp_path):
    big = tmp_path / "big.yaml"
    with open(big, "wb") as f:  # sparse: nothing is written
        f.truncate(MAX_FILE_BYTES + 1)
    assert f"at most {MAX_FILE_BYTES:,} bytes" in refused(load_config, big)
    world = tmp_path / "big.json"
    with open(world, "wb") as f:
        f.truncate(worlds.MAX_FILE_BYTES + 1)
    assert f"at most {worlds.MAX_FILE_BYTES:,} bytes" in refused(worlds.load, world)


# ----------------------------------------------------------------------------- integer and float widths


@pytest.mark.parametrize(
    "key", ["offpolicy.train_every", "ddpg.target_every", "fed.krum_f", "fed.period", "fed.krum_m"]
)
def test_integers_beyond_int32_are_refused_naming_the_field(key):
    msg = refused(load_config, None, [f"{key}=100000000000000000000"])
    assert msg.startswith(f"--set: {key}: ") and "out of range" in msg and "2147483647" in msg, msg


def test_every_int_field_is_held_to_int32_and_every_float_field_to_float32():
    for key in INT_FIELDS:
        section, name = key.split(".")
        msg = refused(from_dict, {section: {name: 2**31}}, "c.yaml")
        assert f"c.yaml: {key}: " in msg and "out of range" in msg, msg
    for key in FLOAT_FIELDS:
        section, name = key.split(".")
        msg = refused(from_dict, {section: {name: 1e39}}, "c.yaml")  # finite in float64, inf in float32
        assert f"c.yaml: {key}: " in msg and "out of range" in msg, msg
        msg = refused(from_dict, {section: {name: 10**400}}, "c.yaml")  # an int with no float
        assert f"c.yaml: {key}: " in msg and "out of range" in msg, msg


def test_the_largest_traced_integers_reach_the_program_exactly():
    # (offpolicy.train_every is bounded by the run too: no run is 2^31 - 1 steps long, test_config.py)
    cfg = load_config(None, ["offpolicy.random_steps=2147483647", "ddpg.target_every=2147483647", "method=iddpg"])
    hp = hparams_from_config(cfg)
    assert int(hp.offpolicy.random_steps) == 2**31 - 1 and hp.offpolicy.random_steps.dtype == dtype(
        "offpolicy.random_steps"
    )
    assert int(hp.ddpg.target_every) == 2**31 - 1 and hp.ddpg.target_every.dtype == dtype("ddpg.target_every")


@pytest.mark.parametrize(
    "item",
    [
        "env.dt=1e300",
        "env.dt=11",
        "env.progress_scale=1e7",
        "env.reward_goal=1e300",
        "env.reward_collision=-2e6",
        "fed.attack_scale=1e300",
        "env.v_max=1e300",
        "fed.max_norm=1e300",
        "robot.accel_lin=1e300",
    ],
)
def test_absurd_floats_are_range_errors_not_divergence(item):
    key = item.split("=")[0]
    msg = refused(load_config, None, [item])
    assert msg.startswith(f"--set: {key}: ") and "out of range" in msg, msg


def test_a_yaml_date_stays_text(tmp_path):
    cfg = load_config(None, ["run.eval_suite=2024-01-01"])
    assert cfg.run.eval_suite == "2024-01-01"
    json.dumps(config.to_dict(cfg))
    path = write(tmp_path / "dated.yaml", yaml.safe_dump(ROOM) + "name: 2024-01-01\n")
    _, meta = worlds.load_with_meta(path)
    assert meta["name"] == "2024-01-01"
    json.dumps({k: v for k, v in meta.items()})  # the meta goes into eval.json
    assert "must be a string" in refused(worlds.from_dict, {**ROOM, "description": 5}, "w.json")


# ----------------------------------------------------------------------------- world files


@pytest.mark.parametrize(
    "field, value, needle",
    [
        ("size", [1e39, 1e39], "size"),
        ("size", [1e5, 4], "size"),
        ("circles", [[1e300, 0, 0.1]], "circles[0]"),
        ("starts", [[0, 0, 1e300]], "starts[0]"),
        ("boxes", [[1, 1, 0.5, 0.5, 1e20]], "boxes[0]"),
        ("goals", [[1, 1], [3e38, 0]], "goals[1]"),
    ],
)
def test_world_numbers_beyond_float32_or_the_world_bound_are_refused(tmp_path, field, value, needle):
    path = write(tmp_path / "far.json", json.dumps({**ROOM, field: value}))
    msg = refused(worlds.load, path)
    assert str(path) in msg and f"field '{field}'" in msg and needle in msg, msg
    line = cli_one_line(["train", "--set", f"env.worlds=[{path}]", "--memory-budget", "1", "--quiet"])
    assert str(path) in line and f"field '{field}'" in line, line


# ----------------------------------------------------------------------------- cross-field, duplicates, attribution


def test_room_spec_without_procedural_rooms_is_refused():
    msg = refused(load_config, None, ["env.room_spec=walls_max=2"])
    assert "env.room_spec" in msg and "env.rooms" in msg and "procedural" in msg, msg
    assert load_config(None, ["env.rooms=procedural", "env.room_spec=walls_max=2"]).env.room_spec == "walls_max=2"


@pytest.mark.parametrize(
    "text, key",
    [
        ("offpolicy:\n  gamma: 0.5\n  gamma: 0.7\n", "'gamma'"),
        ("run:\n  seeds: 2\nrun:\n  seeds: 3\n", "'run'"),
        ("method: iddpg\nmethod: flddpg\n", "'method'"),
    ],
)
def test_duplicate_yaml_keys_are_refused_naming_the_key_and_the_file(tmp_path, text, key):
    path = write(tmp_path / "dup.yaml", text)
    msg = refused(load_config, path)
    assert str(path) in msg and f"duplicate key {key}" in msg, msg


def test_duplicate_world_keys_are_refused(tmp_path):
    path = write(tmp_path / "dup.yaml", yaml.safe_dump(ROOM) + "size: [5, 5]\n")
    assert "duplicate key 'size'" in refused(worlds.load, path)
    path = write(tmp_path / "dup.json", json.dumps(ROOM)[:-1] + ', "size": [5, 5]}')
    assert "duplicate key 'size'" in refused(worlds.load, path)


def test_yaml_merge_keys_may_still_be_overridden():
    assert config.parse_yaml("a: &b {x: 1, y: 2}\nc:\n  <<: *b\n  x: 3\n", "m.yaml")["c"] == {"x": 3, "y": 2}


@pytest.mark.parametrize(
    "text, needle",
    [
        ("- 1\n", "must be a mapping"),
        ("ddpg: [1, 2]\n", "'ddpg' must be a mapping"),
        ("offpolicy:\n  gamma: 5\n", "offpolicy.gamma: 5 is out of range"),
        ("ddpg:\n  gamma: 5\n", "ddpg.gamma: 5 is out of range"),  # the old name, named as written
        ("ddpg:\n  gama: 0.9\n", "unknown key 'ddpg.gama'"),
    ],
)
def test_an_error_in_the_file_names_the_file_even_with_set(tmp_path, text, needle):
    path = write(tmp_path / "c.yaml", text)
    msg = refused(load_config, path, ["offpolicy.lr=0.01"])
    assert msg.startswith(f"{path}: ") and needle in msg and "--set" not in msg, msg


def test_an_error_in_a_set_value_names_set_not_the_file(tmp_path):
    path = write(tmp_path / "c.yaml", "ddpg:\n  gamma: 0.9\n")
    for item, needle in [
        ("offpolicy.gamma=5", "--set: offpolicy.gamma: "),
        ("ddpg.gama=1", "--set: unknown key 'ddpg.gama'"),
    ]:
        msg = refused(load_config, path, [item])
        assert msg.startswith(needle) and str(path) not in msg, msg


# ----------------------------------------------------------------------------- long names and values


def test_an_over_long_config_name_is_exit_2_with_a_short_line():
    line = cli_one_line(["train", "--config", "a" * 5000, "--memory-budget", "1", "--quiet"])
    assert "cannot be read as a config file" in line and "(5,000 chars)" in line and len(line) < 600, line
    line = cli_one_line(["train", "--set", f"env.worlds=[{'b' * 5000}]", "--memory-budget", "1", "--quiet"])
    assert "world file" in line and len(line) < 600, line


def test_an_over_long_sweep_or_run_name_is_exit_2_with_a_short_line():
    """Every command: a name longer than the OS allows is bad input (exit 2, one short line),
    not a failed write (exit 4)."""
    for argv in (["sweep", "a" * 5000], ["evaluate", "r" * 5000], ["export", "r" * 5000, "--out", "x"]):
        line = cli_one_line(argv)
        assert len(line) < 600, line


def test_long_values_are_cut_in_error_messages(tmp_path):
    path = write(tmp_path / "long.yaml", f"method: {'x' * 500_000}\n")
    msg = refused(load_config, path)
    assert str(path) in msg and "method" in msg and "(500,002 chars)" in msg, msg  # repr adds the quotes
    msg = refused(load_config, None, [f"env.room_families=[{'y' * 100_000}]"])
    assert "env.room_families" in msg and "(100,002 chars)" in msg, msg
    huge = write(tmp_path / "huge.yaml", f"method: {'x' * 30_000_000}\n")  # over the size bound
    assert f"at most {MAX_FILE_BYTES:,} bytes" in refused(load_config, huge)
    from fedjax_nav.worlds.rooms import parse_overrides  # env.room_spec's fields

    assert "(5,000 chars)" in refused(parse_overrides, ["x" * 5000 + "=1"])
    assert "(5,002 chars)" in refused(parse_overrides, ["cylinders_max=" + "9" * 5000])
    big = parse_overrides(["cylinders_max=" + "9" * 4000])
    assert "(4,000 chars)" in refused(lambda: worlds.make_spec("cylinders", **big))


# ----------------------------------------------------------------------------- what ships still loads


def test_every_shipped_config_and_world_loads_under_the_bounds():
    from fedjax_nav.configs import names

    for name in names("config"):
        assert isinstance(load_config(name), config.Config), name
    for name in worlds.SHIPPED:
        w = worlds.load(name)
        assert np.all(np.abs(np.asarray(w.segments)) <= worlds.MAX_COORD), name
