"""The attack battery (`scripts/attack.py`, docs/reliability.md "Re-running the attack") guarded:
its cases are derived from the parser and the config's field bounds, its judge catches every kind
of failure it counts (a traceback, a hang, a signal, a wrong exit, a multi-line error, the memory
cap), a few of its real command lines pass, and the inputs it found are refused with one line.

Fake commands (`python -c ...`) test the judge without importing jax; the real command lines are
refused before anything is compiled.
"""

import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import pytest

os.environ.setdefault("JAX_PLATFORMS", "cpu")

ROOT = Path(__file__).resolve().parents[1]
spec = importlib.util.spec_from_file_location("attack", ROOT / "scripts" / "attack.py")
attack = importlib.util.module_from_spec(spec)
sys.modules["attack"] = attack
spec.loader.exec_module(attack)


@pytest.fixture(scope="module")
def fixtures(tmp_path_factory):
    return attack.Fixtures(tmp_path_factory.mktemp("attack"))


@pytest.fixture(scope="module")
def cases(fixtures):
    from fedjax_nav.cli.parser import build_parser

    return attack.cli_cases(fixtures, build_parser())


def test_the_command_lines_cover_every_command_and_are_distinct(cases):
    from fedjax_nav.cli.parser import build_parser

    names = [c.name for c in cases]
    assert len(cases) >= 300 and len(set(names)) == len(names)
    for verb in attack.verbs(build_parser()):
        assert any(c.argv[: len(verb.split())] == verb.split() for c in cases), verb
    # every flag of `evaluate` that takes a value is given bad values, --memory-budget among them
    assert {"evaluate-memory-budget-inf", "evaluate-attempts-0", "evaluate-world-fifo"} <= set(names)


def test_a_bad_value_replaces_the_tiny_settings_own():
    """`train --episodes -1` must not be followed by TINY's `--episodes 3` (the last one wins)."""
    base = {"pos": [], "flags": {"--quiet": None}, "tail": attack.TINY}
    argv = attack.command_line("train", base, flags={"--episodes": "-1"})
    assert argv.count("--episodes") == 1 and argv[argv.index("--episodes") + 1] == "-1"


def test_field_values_follow_the_declared_bounds():
    got = {t: e for t, _, e in attack.config_values("int", {"lo": 1, "hi": 1000})}
    assert got["0"] == got["1001"] == got["2147483648"] == got[".nan"] == got["abc"] == "refuse"
    floats = {t: e for t, _, e in attack.config_values("float", {"lo": 0.0, "hi": None})}
    assert floats["2147483648"] == "any" and floats["1e39"] == floats["-0.001"] == "refuse"


FAKE = {  # (python code, expect) -> the failure the judge must name
    "traceback": ("raise RuntimeError('boom')", "refuse", "traceback"),
    "hang": ("import time; time.sleep(30)", "refuse", "hang"),
    "signal": ("import os, signal; os.kill(os.getpid(), signal.SIGKILL)", "refuse", "signal SIGKILL"),
    "accepted": ("pass", "refuse", "wrong exit: 0"),
    "multi-line": ("import sys; print('error: a\\nerror: b', file=sys.stderr); sys.exit(2)", "refuse", "multi-line"),
    "memory-cap": ("b = bytearray(3 << 30)", "refuse", "traceback"),  # MemoryError under the 1 GiB cap
    "refused": ("import sys; print('error: one line', file=sys.stderr); sys.exit(2)", "refuse", None),
}


@pytest.mark.parametrize("name", list(FAKE))
def test_the_judge_names_each_failure(tmp_path, name):
    code, expect, needle = FAKE[name]
    runner = attack.Runner(tmp_path, mem_bytes=1 << 30)
    case = attack.Case("t", name, ["-c", code], expect, timeout=3 if name == "hang" else 30, prog=(sys.executable,))
    got = attack.run_case(runner, case)
    if needle is None:
        assert got.failures == [], got
    else:
        assert any(needle in f for f in got.failures), got


SUBSET = [
    "top-unknown-command",
    "train-unknown-flag",
    "train-seeds-nan",
    "train-set-alias-bomb",
    "sweep-file-seeds-text",
    "render-steps--1",
    "worlds-generate-seed-nope",
    "configs-extra-positional",
]


def test_a_subset_of_the_battery_passes(tmp_path, cases):
    """Eight real command lines, two at a time: each refused with one line, exit 2."""
    import concurrent.futures

    runner = attack.Runner(tmp_path, mem_bytes=4 << 30)
    chosen = [c for c in cases if c.name in SUBSET]
    assert len(chosen) == len(SUBSET)
    with concurrent.futures.ThreadPoolExecutor(2) as pool:
        outcomes = list(pool.map(lambda c: attack.run_case(runner, c), chosen))
    assert [(o.name, o.failures) for o in outcomes if o.failures] == []
    assert {o.rc for o in outcomes} == {2}


def cli(*argv) -> subprocess.CompletedProcess:
    env = dict(os.environ, JAX_PLATFORMS="cpu")
    return subprocess.run(
        [sys.executable, "-m", "fedjax_nav.cli", *argv], env=env, capture_output=True, text=True, timeout=120
    )


# ----------------------------------------------------------------------------- what the battery found


def one_line(capfd, argv, *needles) -> str:
    """`fedjax-nav ARGV` in-process: exit 2 and one `error:` line holding every needle."""
    from fedjax_nav import cli

    try:
        rc = cli.main([str(a) for a in argv])
    except SystemExit as e:  # argparse leaves through SystemExit
        rc = e.code
    err = capfd.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert rc == 2 and len(lines) == 1 and lines[0].startswith("error: "), (rc, err[-2000:])
    for n in needles:
        assert n in lines[0], (n, lines[0])
    return lines[0]


@pytest.mark.parametrize(
    "argv, flag",
    [
        (["train", "--resume", "", "--memory-budget", "1"], "--resume"),  # before: a new run from scratch
        (["train", "--config", " ", "--memory-budget", "1"], "--config"),
        (["evaluate", "no-run", "--robot", ""], "--robot"),  # before: the run's own robot model
        (["evaluate", "no-run", "--suite", ""], "--suite"),  # before: the world, not a suite
        (["evaluate", "no-run", "--out", ""], "--out"),  # before: into the working folder
        (["reproduce", "--only", "", "--seeds", "0"], "--only"),  # before: every experiment
        (["export", "no-run", "--out", "x", "--seed", ""], "--seed"),
    ],
    ids=["resume", "config", "robot", "suite", "out", "only", "export-seed"],
)
def test_an_empty_text_value_is_refused_not_taken_as_the_default(capfd, argv, flag):
    one_line(capfd, argv, f"argument {flag}: expected a value, got ")


@pytest.mark.parametrize(
    "argv, needle",
    [
        (["evaluate", "no-run", "--seed", str(2**64)], "--seed: expected an integer in"),  # an OverflowError
        (["render", "train-0", "--seed", str(2**64)], "--seed: expected an integer in"),
        (["render", "train-0", "--steps", str(2**31)], "--steps: expected an integer in [1, 100,000]"),
        (
            ["evaluate", "no-run", "--range-noise", "1e300"],
            "--range-noise: the noise std must be finite and in [0, 10000]",
        ),  # inf in f32
        (["reproduce", "--only", ",,"], "--only ',,': names no experiment"),
    ],
    ids=["evaluate-seed", "render-seed", "render-steps", "noise", "only-commas"],
)
def test_values_beyond_what_the_program_takes_are_one_line(capfd, argv, needle):
    one_line(capfd, argv, needle)


def test_an_out_path_that_cannot_be_a_folder_is_bad_input(tmp_path, capfd):
    """A file, a path below a file: exit 2 (before: 4, "a write failed", and for evaluate and
    render a hint about checkpoints they do not have)."""
    (tmp_path / "f").write_text("x")
    one_line(
        capfd, ["sweep", "tau", "--out", tmp_path / "f" / "sub"], "cannot create the sweep folder (Not a directory)"
    )
    line = one_line(
        capfd, ["worlds", "generate", "--family", "cylinders", "--seed", "1", "--out", tmp_path / "f" / "w.json"]
    )
    assert "checkpoint" not in line, line


@pytest.mark.parametrize("command", [["train", "--quiet"], ["sweep", "tau", "--quiet"]])
def test_a_device_count_beyond_a_process_is_one_line(command):
    """Before: XLA's flag parser aborted with its 94-line flag listing, exit 1 (a subprocess: the
    count must reach XLA_FLAGS before jax starts)."""
    r = cli(*command, "--devices", "99999999999999999999")
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert r.returncode == 2 and len(lines) == 1, r.stderr[-2000:]
    assert "--devices 99999999999999999999: at most 256 devices per process" in lines[0]


def tiny_run(root: Path, params: bool = True) -> Path:
    """A run directory of a tiny IDDPG config (2 robots, T = 16), untrained: config.yaml and,
    with `params`, a params.npz of zero actors."""
    import numpy as np

    from fedjax_nav.config import from_dict, save_config

    root.mkdir(parents=True)
    cfg = {
        "method": "iddpg",
        "env": {"worlds": ["train-0", "train-2"], "episode_length": 16},
        "offpolicy": {"hidden": 8, "depth": 1, "batch_size": 8, "buffer_size": 64},
        "run": {"episodes": 2, "chunk_episodes": 1, "checkpoint_every": 1},
    }
    save_config(from_dict(cfg), root / "config.yaml")
    if params:
        np.savez(root / "params.npz", **{"actor/params/Dense_0/kernel": np.zeros((1, 2, 28, 8), np.float32)})
    return root


def test_a_params_file_that_is_a_fifo_is_refused_without_blocking(tmp_path):
    """Before: np.load opened the FIFO and waited for a writer forever (evaluate and export)."""
    run = tiny_run(tmp_path / "run", params=False)
    os.mkfifo(run / "params.npz")
    r = cli("evaluate", str(run), "--no-figures")
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert r.returncode == 2 and len(lines) == 1, r.stderr[-2000:]
    assert f"{run / 'params.npz'}: is not a regular file" in lines[0]


def test_resuming_with_a_file_as_checkpoints_folder_is_refused_before_training(tmp_path, capfd):
    """Before: the run trained its episodes again from 0, then every save failed (exit 4), and the
    console script hung on orbax's threads after printing its line."""
    run = tiny_run(tmp_path / "run")
    (run / "checkpoints").write_text("x")
    one_line(capfd, ["train", "--resume", run, "--quiet"], f"{run / 'checkpoints'}: exists and is not a directory")
    assert not (run / "metrics.csv").exists()
