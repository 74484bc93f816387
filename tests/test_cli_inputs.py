"""Bad command lines and sweep files end in one `error:` line and exit 2 (docs/reliability.md):
argparse's own errors (no pages of usage), counts that must be positive, sweep files whose
`seeds:` or `thesis:` have the wrong type, and memory budgets that are not sizes. Each used to
end in a traceback, a usage dump or exit 0."""

from __future__ import annotations

import io
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path

import pytest
import yaml
from conftest import sigint_at_default

from fedjax_nav import cli
from fedjax_nav.config.sweepfile import SweepError, load_sweep
from fedjax_nav.configs import resolve
from fedjax_nav.training.sweep import parse_bytes

BASE = str(resolve("thesis/flddpg"))


def one_error_line(argv) -> str:
    """Run `fedjax-nav argv` in-process: exit 2 and exactly one `error:` line on stderr."""
    err, out = io.StringIO(), io.StringIO()
    with redirect_stderr(err), redirect_stdout(out):
        try:
            rc = cli.main([str(a) for a in argv])
        except SystemExit as e:  # argparse exits through SystemExit
            rc = e.code
    lines = [ln for ln in err.getvalue().splitlines() if ln.strip()]
    assert rc == 2 and len(lines) == 1 and lines[0].startswith("error: "), (rc, err.getvalue()[-1500:])
    return lines[0]


@pytest.mark.parametrize(
    "argv, needle",
    [
        (["train", "--bogus"], "unrecognized arguments: --bogus"),
        (["nonsense"], "invalid choice: 'nonsense'"),
        (["evaluate"], "required: RUN_DIR"),
        (["train", "--devices", "0"], "--devices: expected an integer >= 1, got 0"),
        (["train", "--devices", "-1"], "--devices: expected an integer >= 1, got -1"),
        (["sweep", "tau", "--devices", "0"], "--devices"),
        (["evaluate", "RUN", "--attempts", "0"], "--attempts"),
        (["evaluate", "RUN", "--max-steps", "0"], "--max-steps"),
        (["render", "--steps", "-1"], "--steps"),
        (["train", "--devices", "two"], "expected an integer >= 1, got 'two'"),
    ],
)
def test_argparse_errors_are_one_line_and_exit_2(argv, needle):
    line = one_error_line(argv)
    assert needle in line and "--help" in line and "usage:" not in line, line


def _sweep(tmp_path: Path, **fields) -> Path:
    spec = {"name": "t", "base": BASE, "grid": {"fed.tau": [0.1]}, **fields}
    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump(spec))
    return path


@pytest.mark.parametrize("seeds", ["abc", [1, 2], float("inf"), "1e3", True, 0, 5000, 2.0])
def test_a_sweep_files_seeds_must_be_a_count(tmp_path, seeds):
    path = _sweep(tmp_path, seeds=seeds)
    with pytest.raises(SweepError, match="seeds must be an integer in 1..4096"):
        load_sweep(path)
    assert "seeds must be an integer" in one_error_line(["sweep", path, "--out", tmp_path / "o"])


def test_a_sweep_files_thesis_must_be_a_mapping_and_dates_are_text(tmp_path):
    assert "thesis must be a mapping" in one_error_line(["sweep", _sweep(tmp_path, thesis=5)])
    path = tmp_path / "d.yaml"
    path.write_text(f"name: d\nbase: {BASE}\ngrid:\n  fed.tau: [2026-01-01]\n")  # a YAML date
    assert "fed.tau: expected a number, got '2026-01-01'" in one_error_line(["sweep", path])


@pytest.mark.parametrize("text", ["inf", "nan", "-1G", "0", "1e400", "lots", -5, float("inf")])
def test_a_memory_budget_must_be_a_positive_size(text):
    with pytest.raises(SweepError, match="expected a positive size"):
        parse_bytes(text)


def test_memory_budgets_that_are_sizes_still_parse():
    assert parse_bytes("4G") == 4 * 2**30 and parse_bytes("512M") == 512 * 2**20 and parse_bytes(2e9) == 2_000_000_000
    assert parse_bytes("1.5GB") == int(1.5 * 2**30) and parse_bytes(" 1k ") == 1024


def test_a_budget_too_small_for_a_sweep_is_one_line(tmp_path):
    """The planner's refusal (a SweepError raised after the file was read) is bad input too."""
    line = one_error_line(["sweep", "tau", "--out", tmp_path / "o", "--memory-budget", "1K", "--quiet"])
    assert "more than the memory budget" in line and "raise --memory-budget" in line, line
    for argv in (["sweep", "tau", "--memory-budget", "inf"], ["train", "--memory-budget=-1G"]):
        assert "expected a positive size" in one_error_line(argv)


def test_a_grid_of_too_many_points_is_refused_at_once(tmp_path):
    import time

    path = _sweep(tmp_path, grid={"fed.tau": [i / 300 for i in range(300)], "fed.beta": list(range(300))})
    t = time.perf_counter()
    assert "the grid has 90,000 points, more than 10,000" in one_error_line(["sweep", path])
    assert time.perf_counter() - t < 5


def test_a_single_seed_point_larger_than_the_budget_is_refused(tmp_path):
    """The planner checked only points of several seeds: one seed of a huge buffer went through."""
    path = _sweep(tmp_path, seeds=1, set=["offpolicy.buffer_size=100000000"])
    line = one_error_line(["sweep", path, "--out", tmp_path / "o", "--memory-budget", "1G", "--quiet"])
    assert "needs 1 rows" in line and "more than the memory budget" in line, line


def _interrupted_train(tmp_path, signals: int, wait: float):
    """`fedjax-nav train` in a subprocess, Ctrl-C'd `signals` times `wait` s after it said what it
    trains (start-up and compilation still running): (exit code, stderr)."""
    import os
    import signal
    import subprocess
    import sys
    import time

    cmd = [sys.executable, "-m", "fedjax_nav.cli", "train", "--config", "thesis/flddpg", "--out", tmp_path / "run"]
    cmd += ["--episodes", "1000", "--set", "env.episode_length=64", "--set", "run.chunk_episodes=1", "--quiet"]
    # without PYTHONUNBUFFERED, as a user's shell has it: the start line must be flushed by the CLI
    env = {k: v for k, v in os.environ.items() if k not in ("XLA_FLAGS", "PYTHONUNBUFFERED")} | {"JAX_PLATFORMS": "cpu"}
    p = subprocess.Popen(
        [str(c) for c in cmd],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        preexec_fn=sigint_at_default,
    )
    try:
        assert p.stdout.readline().startswith("training ")
        time.sleep(wait)
        for _ in range(signals):
            p.send_signal(signal.SIGINT)
            time.sleep(0.3)
        _, err = p.communicate(timeout=300)
    finally:
        p.kill()
    return p.returncode, err


@pytest.mark.parametrize("signals", [1, 2])
def test_ctrl_c_while_a_run_starts_is_one_line_and_130(tmp_path, signals):
    """A Ctrl-C during start-up and compilation (and a second one after it) used to print pages of
    KeyboardInterrupt traceback, and sometimes end in a segmentation fault."""
    rc, err = _interrupted_train(tmp_path, signals, wait=0.2)
    lines = [ln for ln in err.splitlines() if ln.strip()]
    # with a warm compilation cache the loop may already run: the first Ctrl-C then saves and says
    # how to resume; either way one line, 130, no traceback
    assert rc == 130 and len(lines) == 1 and "Traceback" not in err, (rc, err[-2000:])
    assert "interrupted" in lines[0], lines


def test_a_run_started_with_ctrl_c_ignored_keeps_ignoring_it():
    """A script's background job starts with SIGINT ignored (POSIX); the run's deferred handler
    installed itself over that, so such a job stopped on a Ctrl-C that Python would have ignored."""
    import signal

    from fedjax_nav.training.run import _DeferredInterrupt

    before = signal.getsignal(signal.SIGINT)
    try:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        guard = _DeferredInterrupt()
        assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN
        guard.restore()
        signal.signal(signal.SIGINT, signal.default_int_handler)
        guard = _DeferredInterrupt()
        assert signal.getsignal(signal.SIGINT) == guard._on_sigint
        guard.restore()
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    finally:
        signal.signal(signal.SIGINT, before)


def test_train_without_a_config_is_refused_naming_the_preset_and_the_list(tmp_path):
    """A bare `train --out X` trained the whole thesis preset, silently (docs/reliability.md)."""
    line = one_error_line(["train", "--out", tmp_path / "x", "--quiet"])
    assert "--config thesis/flddpg" in line and "fedjax-nav configs" in line and "125 episodes" in line, line
    assert not (tmp_path / "x").exists()
