"""Property-based fuzzing of every input reader (docs/reliability.md): the config loader, the world
loader and `--set`, fed random bytes, random YAML and random values, either return a valid object
or raise their one-line error (ConfigError / WorldError); the CLI in-process answers exit 2 with
one line on stderr. Never a traceback. In-process, no training: the whole file runs in seconds.
"""

import io
import json
import tempfile
from contextlib import redirect_stderr
from pathlib import Path

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fedjax_nav import cli, config, worlds
from fedjax_nav.config import ConfigError

SETTINGS = settings(max_examples=60, deadline=None, database=None, suppress_health_check=list(HealthCheck))

scalars = st.one_of(
    st.none(), st.booleans(), st.integers(-(10**30), 10**30), st.floats(allow_nan=True), st.text(max_size=12)
)
values = st.recursive(
    scalars,
    lambda inner: st.one_of(st.lists(inner, max_size=4), st.dictionaries(st.text(max_size=8), inner, max_size=4)),
    max_leaves=12,
)
FIELDS = ["method"] + [
    f"{s}.{f.name}" for s, cls in config.SECTIONS.items() for f in __import__("dataclasses").fields(cls)
]
# a random config: real section and field names (so validation, not just the key check, is hit)
configs = st.dictionaries(
    st.sampled_from(FIELDS) | st.text(max_size=6).map(lambda s: f"run.{s}"), values, max_size=6
).map(
    lambda d: (
        {k: v for k, v in d.items() if "." not in k}
        | {s: {k.split(".")[1]: v for k, v in d.items() if k.startswith(s + ".")} for s in config.SECTIONS}
    )
)
WORLD_KEYS = ["size", "boxes", "segments", "circles", "starts", "goals", "name", "description", "extra"]
rows = st.lists(st.lists(st.floats(-10, 10) | st.integers(-5, 5) | scalars, max_size=6), max_size=4)
world_specs = st.dictionaries(
    st.sampled_from(WORLD_KEYS) | st.text(max_size=4) | st.integers(0, 3), rows | values, max_size=7
)


@pytest.fixture(scope="module")
def folder():
    with tempfile.TemporaryDirectory() as d:
        yield Path(d)


def load_file(path: Path):
    try:
        return config.load_config(path)
    except ConfigError as e:
        assert "\n" not in str(e) and str(path) in str(e), str(e)
        return None


def load_world(path: Path):
    try:
        return worlds.load(path)
    except worlds.WorldError as e:
        assert "\n" not in str(e) and str(path) in str(e), str(e)
        return None


@SETTINGS
@given(data=st.binary(max_size=200))
def test_config_loader_random_bytes(folder, data):
    path = folder / "random.yaml"
    path.write_bytes(data)
    cfg = load_file(path)
    assert cfg is None or isinstance(cfg, config.Config)


@SETTINGS
@given(data=configs)
def test_config_loader_random_yaml(folder, data):
    path = folder / "random.yaml"
    path.write_text(yaml.safe_dump(data, allow_unicode=True))
    cfg = load_file(path)
    assert cfg is None or isinstance(cfg, config.Config)


@SETTINGS
@given(key=st.sampled_from(FIELDS) | st.text(max_size=12), raw=st.text(max_size=20) | values.map(json.dumps))
def test_set_random_values(key, raw):
    try:
        cfg = config.load_config(None, [f"{key}={raw}"])
    except ConfigError as e:
        assert "\n" not in str(e)
    else:
        assert isinstance(cfg, config.Config)


@SETTINGS
@given(data=st.binary(max_size=200), suffix=st.sampled_from([".json", ".yaml"]))
def test_world_loader_random_bytes(folder, data, suffix):
    path = folder / f"room{suffix}"
    path.write_bytes(data)
    load_world(path)


@SETTINGS
@given(spec=world_specs, suffix=st.sampled_from([".json", ".yaml"]))
def test_world_loader_random_specs(folder, spec, suffix):
    path = folder / f"room{suffix}"
    path.write_text(json.dumps(spec) if suffix == ".json" else yaml.safe_dump(spec, allow_unicode=True))
    w = load_world(path)
    assert w is None or isinstance(w, worlds.World)


@settings(max_examples=15, deadline=None, database=None, suppress_health_check=list(HealthCheck))
@given(data=st.binary(max_size=120) | configs.map(lambda d: yaml.safe_dump(d).encode()))
def test_cli_evaluate_random_config_is_one_line_exit_2(folder, data):
    """A run directory whose config.yaml is random (and params.npz absent or garbage): exit 2, one line."""
    run = folder / "run"
    run.mkdir(exist_ok=True)
    (run / "config.yaml").write_bytes(data)
    (run / "params.npz").write_bytes(data[:20])
    err = io.StringIO()
    with redirect_stderr(err):
        rc = cli.main(["evaluate", str(run), "--no-figures"])
    lines = [ln for ln in err.getvalue().splitlines() if ln.strip()]
    assert rc == 2 and len(lines) == 1 and lines[0].startswith("error: "), err.getvalue()


@settings(max_examples=15, deadline=None, database=None, suppress_health_check=list(HealthCheck))
@given(raw=st.text(max_size=20))
def test_cli_set_random_value_is_one_line_or_refused_for_memory(raw):
    """`train --set ddpg.gamma=<random>`: a bad value is one line, exit 2; a good one reaches the
    memory check, which a 1-byte budget refuses (exit 2, one line): nothing is ever trained."""
    err = io.StringIO()
    with redirect_stderr(err):
        rc = cli.main(["train", "--set", f"ddpg.gamma={raw}", "--memory-budget", "1", "--quiet"])
    lines = [ln for ln in err.getvalue().splitlines() if ln.strip()]
    assert rc == 2 and len(lines) == 1 and lines[0].startswith("error: "), err.getvalue()
