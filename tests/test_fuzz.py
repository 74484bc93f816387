"""Property-based fuzzing of every input reader (docs/reliability.md): the config loader, the world
loader and `--set`, fed random bytes, random YAML and random values, either return a valid object
or raise their one-line error (ConfigError / WorldError); the CLI in-process answers exit 2 with
one line on stderr. Never a traceback. YAML alias trees are refused exactly when they expand
beyond the loader's budget, and an integer or float a config accepts fits the program's int32 /
float32. In-process, no training: the whole file runs in seconds.
"""

import dataclasses
import io
import json
import tempfile
import time
from contextlib import redirect_stderr
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fedjax_nav import cli, config, worlds
from fedjax_nav.config import ConfigError
from fedjax_nav.config.io import MAX_NODES
from fedjax_nav.training.hparams import hparams_from_config

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


def test_a_set_key_with_a_newline_is_named_on_one_line():
    """Found by test_set_random_values: the key was printed raw, so its newline split the error."""
    with pytest.raises(ConfigError) as e:
        config.load_config(None, ["0\n0=["])
    assert "\n" not in str(e.value) and "'0\\n0'" in str(e.value)


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
    """`train --set offpolicy.gamma=<random>`: a bad value is one line, exit 2; a good one reaches the
    memory check, which a 1-byte budget refuses (exit 2, one line): nothing is ever trained."""
    err = io.StringIO()
    with redirect_stderr(err):
        rc = cli.main(["train", "--set", f"offpolicy.gamma={raw}", "--memory-budget", "1", "--quiet"])
    lines = [ln for ln in err.getvalue().splitlines() if ln.strip()]
    assert rc == 2 and len(lines) == 1 and lines[0].startswith("error: "), err.getvalue()


# ----------------------------------------------------------------------------- YAML aliases


def alias_tree(levels: int, fanout: int, mapping: bool) -> tuple[str, int]:
    """A YAML flow value whose level i holds `fanout` uses of level i - 1 (the first one anchored,
    the rest aliases), as a list or a mapping; and the values it stands for once expanded (each
    node counted every time it is used, mapping keys included)."""
    value, size = "&a0 [" + ", ".join(["x"] * fanout) + "]", 1 + fanout
    for i in range(1, levels + 1):
        uses = [value] + [f"*a{i - 1}"] * (fanout - 1)
        if mapping:
            entries = ", ".join(f"k{j}: {u}" for j, u in enumerate(uses))
            value, size = f"&a{i} {{{entries}}}", 1 + fanout * (1 + size)
        else:
            value, size = f"&a{i} [{', '.join(uses)}]", 1 + fanout * size
    return value, size


@settings(max_examples=40, deadline=None, database=None, suppress_health_check=list(HealthCheck))
@given(
    levels=st.integers(1, 9),
    fanout=st.integers(1, 9),
    mapping=st.booleans(),
    field=st.sampled_from(["env.worlds", "run.eval_suite", "offpolicy.gamma", "method"]),
    in_file=st.booleans(),
)
def test_yaml_aliases_are_refused_exactly_beyond_the_budget(folder, levels, fanout, mapping, field, in_file):
    """An alias tree as a `--set` value or a config file's value: refused as an alias expansion
    iff it stands for more than MAX_NODES values (the file's own 4 nodes added), in well under a
    second whatever its size; otherwise a Config or an ordinary one-line error."""
    value, size = alias_tree(levels, fanout, mapping)
    section, name = field.split(".") if "." in field else (None, field)
    if in_file:
        path = folder / "aliases.yaml"
        path.write_text(f"{section}:\n  {name}: {value}\n" if section else f"{name}: {value}\n")
        size += 4 if section else 2
        args = (path, None)
    else:
        args = (None, [f"{field}={value}"])
    t = time.perf_counter()
    try:
        cfg = config.load_config(*args)
    except ConfigError as e:
        msg = str(e)
        assert "\n" not in msg and len(msg) < 1000, msg[:2000]
        assert ("YAML aliases expand" in msg) == (size > MAX_NODES), (size, msg)
    else:
        assert size <= MAX_NODES and isinstance(cfg, config.Config)
    assert time.perf_counter() - t < 1.0 or size <= MAX_NODES, "a refused alias tree must be refused fast"


# ----------------------------------------------------------------------------- integer and float widths

INT_FIELDS = [
    f"{s}.{f.name}" for s, cls in config.SECTIONS.items() for f in dataclasses.fields(cls) if f.type in (int, "int")
]
FLOAT_FIELDS = [
    f"{s}.{f.name}" for s, cls in config.SECTIONS.items() for f in dataclasses.fields(cls) if f.type in (float, "float")
]
WIDTHS = [0, 2**31 - 1, 2**31, 2**32, 2**53, 2**63 - 1, 2**63, 2**64, 10**20, 10**300]
near_widths = st.sampled_from(WIDTHS).flatmap(lambda b: st.integers(b - 2, b + 2)) | st.integers(-(2**80), 2**80)
as_yaml = st.sampled_from([str, lambda n: hex(n) if n >= 0 else "-" + hex(-n), lambda n: f"{float(n):e}"])


@SETTINGS
@given(key=st.sampled_from(INT_FIELDS), n=near_widths, sign=st.sampled_from([1, -1]), fmt=as_yaml)
def test_an_accepted_integer_fits_int32_and_reaches_the_program_exactly(key, n, sign, fmt):
    try:
        raw = fmt(sign * n)
    except OverflowError:  # float(10**300 ...) is fine; beyond 1e308 it has no float text
        return
    try:
        cfg = config.load_config(None, [f"{key}={raw}"])
    except ConfigError as e:
        msg = str(e)
        assert "\n" not in msg and len(msg) < 1000 and (key in msg or "out of range" not in msg), msg
        return
    value = config.get(cfg, key)
    assert -(2**31) <= value < 2**31, (key, value)
    hp = hparams_from_config(cfg).to_flat()
    if key in hp:
        assert int(hp[key]) == value and hp[key].dtype == np.int32, (key, value, hp[key])


@SETTINGS
@given(
    key=st.sampled_from(FLOAT_FIELDS),
    v=st.floats(allow_nan=True, allow_infinity=True)
    | st.sampled_from([3.4028234663852886e38, 3.4028235e38, 3.5e38, 1e39, 1e300]).map(lambda x: x * 1.0),
    sign=st.sampled_from([1.0, -1.0]),
)
def test_an_accepted_float_is_finite_in_float32(key, v, sign):
    try:
        cfg = config.load_config(None, [f"{key}={sign * v!r}"])
    except ConfigError as e:
        assert "\n" not in str(e) and len(str(e)) < 1000, str(e)
        return
    value = config.get(cfg, key)
    assert np.isfinite(np.float32(value)), (key, value)
    hp = hparams_from_config(cfg).to_flat()
    if key in hp:
        assert np.isfinite(np.asarray(hp[key])), (key, value)
