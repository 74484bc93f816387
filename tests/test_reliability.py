"""Nothing lost, nothing silent (docs/reliability.md): one writer per run directory, no result
overwritten by accident, divergence that stays finite stopped, the good episodes kept, resources
checked before allocating, every unreadable input one line (exit 2), a failed write one line
(exit 4), a resumed run checked against the config fingerprinted in its checkpoint, evaluation of
a diverged actor refused.

Every training here is the same tiny program (one compilation, shared through the persistent
compilation cache of tests/conftest.py): 2 robots, 16 steps per episode, 2 episodes per chunk.
Updates start once a buffer holds offpolicy.batch_size = 20 rows, i.e. in episode 1, so episode 0 is
always finite and a poisoned or bounded run diverges at episode 1, inside the first chunk.
"""

import errno
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest
import yaml

from fedjax_nav import cli, config, rundir, runlock
from fedjax_nav.config import ConfigError, load_config
from fedjax_nav.training.hparams import hparams_from_config
from fedjax_nav.training.run import DivergenceError, train

ROBOTS = 2
TINY = {
    "method": "iddpg",
    "env": {"worlds": ["train-0", "train-0"], "episode_length": 16},  # the smallest room: compiles fastest
    "offpolicy": {"hidden": 16, "depth": 2, "batch_size": 20, "buffer_size": 64},
    "run": {"episodes": 4, "seeds": 1, "chunk_episodes": 2, "checkpoint_every": 2, "keep_checkpoints": 3},
}
TIMEOUT = 300


@pytest.fixture(scope="module")
def env(tmp_path_factory):
    e = dict(os.environ, JAX_PLATFORMS="cpu", PYTHONUNBUFFERED="1")
    e.setdefault("JAX_COMPILATION_CACHE_DIR", str(tmp_path_factory.mktemp("jax_cache")))
    return e


@pytest.fixture(scope="module")
def cfg_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("cfg") / "tiny.yaml"
    path.write_text(yaml.safe_dump(TINY))
    return path


@pytest.fixture(scope="module")
def trained(cfg_file, tmp_path_factory):
    """A finished tiny run (checkpoints at episodes 2 and 4)."""
    out = tmp_path_factory.mktemp("trained") / "run"
    assert cli.main(["train", "--config", str(cfg_file), "--out", str(out), "--quiet"]) == 0
    assert not (out / rundir.LOCK).exists()
    return out


def one_line(rc: int, err: str, code: int, *needles: str) -> str:
    """Exit `code`, exactly one non-empty line on stderr, `error: ...`, holding every needle."""
    assert rc == code, err[-3000:]
    assert "Traceback" not in err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), err[-3000:]
    for n in needles:
        assert n in lines[0], (n, lines[0])
    return lines[0]


def cli_error(capfd, argv, *needles, code: int = 2) -> str:
    rc = cli.main([str(a) for a in argv])
    return one_line(rc, capfd.readouterr().err, code, *needles)


def copy_run(trained: Path, tmp_path: Path) -> Path:
    out = tmp_path / "run"
    shutil.copytree(trained, out)
    return out


# ----------------------------------------------------------------------------- 1. one writer


def test_a_second_train_on_the_same_out_gets_exit_2_and_a_stale_lock_is_taken_over(env, cfg_file, tmp_path, capfd):
    out = tmp_path / "run"
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "fedjax_nav.cli",
            "train",
            "--config",
            str(cfg_file),
            "--out",
            str(out),
            "--quiet",
            "--episodes",
            "1000",
        ],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        deadline = time.time() + TIMEOUT
        while not (out / rundir.LOCK).exists():
            assert proc.poll() is None, proc.communicate()[1][-3000:]
            assert time.time() < deadline
            time.sleep(0.05)
        line = cli_error(
            capfd,
            ["train", "--config", cfg_file, "--out", out, "--quiet", "--overwrite"],
            str(out),
            "in use",
            f"process {proc.pid}",
        )
        assert "lock" in line
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.communicate(timeout=60)
    # the killed run's lock is stale (dead PID on this host): taken over with a message, released after
    assert (out / rundir.LOCK).read_text().split()[0] == str(proc.pid)
    with runlock.RunLock(out):
        assert (out / rundir.LOCK).read_text().split()[0] == str(os.getpid())
    assert "stale lock" in capfd.readouterr().err
    assert not (out / rundir.LOCK).exists()


def test_default_run_folders_of_runs_started_together_differ(capfd):
    # refused for memory before anything is created: only the announced folder name is compared
    names = []
    for _ in range(2):
        assert cli.main(["train", "--set", "offpolicy.buffer_size=9e7", "--quiet"]) == 2
        names.append(capfd.readouterr().out.strip().rsplit("-> ", 1)[1])
    assert names[0] != names[1] and all(n.startswith("runs/flddpg-") for n in names)
    assert not any(Path(n).exists() for n in names)


def test_out_holding_results_is_refused_without_overwrite(cfg_file, tmp_path, capfd):
    out = tmp_path / "run"
    out.mkdir()
    (out / "metrics.csv").write_text("episode\n0\n")
    cli_error(capfd, ["train", "--config", cfg_file, "--out", out, "--quiet"], str(out), "metrics.csv", "--overwrite")
    assert (out / "metrics.csv").read_text() == "episode\n0\n"


def test_overwrite_removes_the_old_results_first(trained, cfg_file, tmp_path):
    out = copy_run(trained, tmp_path)
    (out / "eval" / "eval").mkdir(parents=True)
    (out / "eval" / "eval" / "eval.json").write_text("{}")
    assert cli.main(["train", "--config", str(cfg_file), "--out", str(out), "--quiet", "--overwrite"]) == 0
    assert not (out / "eval").exists()
    assert sorted(int(p.name) for p in (out / "checkpoints").iterdir() if p.name.isdigit()) == [2, 4]
    assert len(pd.read_csv(out / "metrics.csv")) == 4 * ROBOTS


# ----------------------------------------------------------------------------- 2-3. divergence


@pytest.mark.parametrize(
    "bound, needle", [("run.max_abs_q=1e-9", "mean |Q| estimate"), ("run.max_critic_loss=1e-12", "critic loss")]
)
def test_a_crossed_divergence_bound_stops_the_run_and_keeps_the_good_episodes(cfg_file, tmp_path, capfd, bound, needle):
    out = tmp_path / "run"
    line = cli_error(
        capfd,
        ["train", "--config", cfg_file, "--out", out, "--quiet", "--set", bound],
        needle,
        bound.split("=")[0],
        "episode 1,",
        "seed 0,",
        "robot",
        "metrics.csv",
        code=3,
    )
    assert "no checkpoint was saved yet" in line  # the first chunk (episodes 0-1) never finished
    df = pd.read_csv(out / "metrics.csv")
    assert sorted(df.episode.unique()) == [0] and len(df) == ROBOTS
    assert not (out / rundir.LOCK).exists()


def test_nan_at_episode_1_keeps_the_metrics_of_episode_0(cfg_file, tmp_path):
    out = tmp_path / "run"
    cfg = load_config(cfg_file)
    nan_hp = hparams_from_config(cfg) | {"offpolicy.lr": jnp.float32(jnp.nan)}
    with pytest.raises(DivergenceError) as info:
        train(cfg, out, progress=False, hp=nan_hp)
    msg = str(info.value)
    assert "NaN/Inf" in msg and "episode 1," in msg and "no checkpoint" in msg and "episodes 0-0" in msg, msg
    df = pd.read_csv(out / "metrics.csv")
    assert sorted(df.episode.unique()) == [0] and np.isfinite(df.reward).all()


# ----------------------------------------------------------------------------- 4. resources


@pytest.mark.parametrize(
    "override, needles",
    [
        ("offpolicy.buffer_size=5e7", ("offpolicy.buffer_size = 50000000", "GiB", "memory")),
        ("offpolicy.buffer_size=1e10", ("offpolicy.buffer_size", "out of range")),
        ("env.episode_length=1e10", ("env.episode_length", "out of range")),
        ("offpolicy.hidden=1e8", ("offpolicy.hidden", "out of range")),
        ("offpolicy.depth=100", ("offpolicy.depth", "out of range")),
        ("run.episodes=1e12", ("run.episodes", "out of range")),
        ("run.seeds=100000", ("run.seeds", "out of range")),
    ],
)
def test_resources_are_checked_before_allocating(cfg_file, tmp_path, capfd, override, needles):
    cli_error(capfd, ["train", "--config", cfg_file, "--out", tmp_path / "run", "--quiet", "--set", override], *needles)
    assert not (tmp_path / "run").exists()


def test_step_counters_fit_int32(cfg_file, tmp_path, capfd):
    """The step counters are int32: a run of 2^31 transitions or more is refused, naming the fields."""
    sets = ["--set", "env.episode_length=1000000", "--set", "run.episodes=1100"]
    cli_error(
        capfd,
        ["train", "--config", cfg_file, "--out", tmp_path / "run", "--quiet", *sets],
        "run.episodes x env.episode_length x robots x env.envs_per_robot = 2,200,000,000",
        "at most 2^31 - 1",
    )


def test_memory_budget_flag(cfg_file, tmp_path, capfd):
    cli_error(
        capfd,
        ["train", "--config", cfg_file, "--out", tmp_path / "run", "--memory-budget", "10K"],
        "compiling the program alone takes about 1.2 GiB: raise --memory-budget",
        "memory budget",
        "10.0 KiB",
    )


def test_world_files_are_bounded(tmp_path):
    from fedjax_nav import worlds

    spec = {"size": [4, 4], "circles": [[1.5, 1.5, 0.01]] * 5001, "starts": [[0, 0, 0]], "goals": [[1, 0]]}
    with pytest.raises(worlds.WorldError, match="field 'circles' has 5001 rows; at most 5000"):
        worlds.from_dict(spec, "many.json")


# ----------------------------------------------------------------------------- 5. one line per input


def write(path: Path, data: bytes | str) -> Path:
    path.write_bytes(data if isinstance(data, bytes) else data.encode())
    return path


def unreadable_cases(tmp: Path, cfg_file: Path, trained: Path):
    """(argv, needles) per unreadable input."""
    bad_yaml = write(tmp / "broken.yaml", "ddpg:\n  gamma: 0.9\n   hidden: [16\n")
    latin = write(tmp / "latin.yaml", b"ddpg:\n  gamma: 0.9 # \xe9t\xe9\n")
    folder = tmp / "folder.yaml"
    folder.mkdir()
    world_bin = write(tmp / "room.json", b"\x89PNG\r\n\x1a\n\x00\x00")
    world_cfg = write(tmp / "wcfg.yaml", yaml.safe_dump({**TINY, "env": {"worlds": [str(world_bin), str(folder)]}}))
    run_cfg_dir = tmp / "rundir"
    (run_cfg_dir / "config.yaml").mkdir(parents=True)
    shutil.copy(trained / "params.npz", run_cfg_dir / "params.npz")
    return [
        (["train", "--config", bad_yaml], (str(bad_yaml), "not valid YAML", "line 3, column")),
        (["train", "--config", latin], (str(latin), "not UTF-8")),
        (["train", "--config", folder], (str(folder), "is a directory")),
        (
            ["train", "--config", cfg_file, "--set", "offpolicy.gamma=[1"],
            ("--set offpolicy.gamma", "not valid YAML", "line 1"),
        ),
        (["train", "--config", world_cfg, "--out", tmp / "w"], (str(world_bin), "not UTF-8")),
        (["sweep", folder], (str(folder), "is a directory", "sweep")),
        (["evaluate", run_cfg_dir], (str(run_cfg_dir / "config.yaml"), "is a directory")),
        (["train", "--resume", run_cfg_dir], (str(run_cfg_dir / "config.yaml"),)),
    ]


def test_every_unreadable_input_is_one_line_exit_2(cfg_file, trained, tmp_path, capfd):
    for argv, needles in unreadable_cases(tmp_path, cfg_file, trained):
        cli_error(capfd, argv, *needles)


def test_yaml_1_1_exponents_are_numbers(tmp_path):
    path = tmp_path / "c.yaml"
    data = json.loads(json.dumps(TINY))
    data["offpolicy"].update(lr="1e-3", buffer_size="1e2")  # how YAML 1.1 reads 1e-3 and 1e2
    path.write_text(yaml.safe_dump(data).replace("'1e-3'", "1e-3").replace("'1e2'", "1e2"))
    cfg = load_config(path, ["offpolicy.gamma=9.0e-1", "run.episodes=1.0e1"])
    assert (cfg.offpolicy.lr, cfg.offpolicy.buffer_size, cfg.offpolicy.gamma, cfg.run.episodes) == (1e-3, 100, 0.9, 10)
    assert isinstance(cfg.offpolicy.buffer_size, int)
    with pytest.raises(ConfigError, match="offpolicy.hidden: expected an integer"):
        load_config(path, ["offpolicy.hidden=1.5e0"])


def test_a_full_disk_is_one_line_exit_4(cfg_file, tmp_path, capfd, monkeypatch):
    def full(cfg, path):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(config, "save_config", full)
    line = cli_error(
        capfd,
        ["train", "--config", cfg_file, "--out", tmp_path / "run", "--quiet"],
        "config.yaml",
        "No space left on device",
        code=4,
    )
    assert "kept" in line
    assert not (tmp_path / "run" / rundir.LOCK).exists()
    assert [p.name for p in (tmp_path / "run").iterdir() if ".tmp-" in p.name] == []


def test_a_full_disk_during_a_checkpoint_is_one_line_exit_4(env, cfg_file, tmp_path):
    """A real failed write: files are limited to 8 KiB (RLIMIT_FSIZE; SIGXFSZ ignored, so writes
    fail with EFBIG as on a full disk); the first checkpoint cannot be saved."""
    import shlex

    out = tmp_path / "run"
    argv = [sys.executable, "-m", "fedjax_nav.cli", "train", "--config", str(cfg_file), "--out", str(out), "--quiet"]
    # no compilation cache: jax writes its entries in place (a truncated one must not be shared) and
    # warns when it cannot
    private = {k: v for k, v in env.items() if k != "JAX_COMPILATION_CACHE_DIR"} | {
        "JAX_ENABLE_COMPILATION_CACHE": "false"
    }
    r = subprocess.run(
        ["bash", "-c", "trap '' XFSZ; ulimit -f 8; exec " + shlex.join(argv)],
        env=private,
        capture_output=True,
        text=True,
        timeout=TIMEOUT,
    )
    one_line(r.returncode, r.stderr, 4, str(out / "checkpoints"), "cannot save a checkpoint", "kept")
    # the metrics of the finished episodes were written; the run did not claim to finish
    assert sorted(pd.read_csv(out / "metrics.csv").episode.unique())[:2] == [0, 1]
    assert not (out / "summary.json").exists() and not (out / rundir.LOCK).exists()
    assert list((out / "checkpoints").iterdir()) == []  # the unfinished save's folder is removed


def test_a_checkpoint_without_its_manifest_is_one_line(trained, env, tmp_path):
    """Every checkpoint without its manifests (with an intact older one, `--resume` would fall back to it)."""
    out = copy_run(trained, tmp_path)
    manifests = list((out / "checkpoints").rglob("manifest.ocdbt"))
    assert {m.relative_to(out / "checkpoints").parts[0] for m in manifests} == {"2", "4"}
    for m in manifests:
        m.unlink()
    r = subprocess.run(
        [sys.executable, "-m", "fedjax_nav.cli", "train", "--resume", str(out), "--quiet"],
        env=env,
        capture_output=True,
        text=True,
        timeout=TIMEOUT,
    )
    line = one_line(r.returncode, r.stderr, 2, str(out / "checkpoints" / "4"))
    assert len(line) < 400 and "{" not in line and "tensorstore_spec" not in line, line


# ----------------------------------------------------------------------------- 6. config fingerprints


def test_resume_refuses_a_hand_edited_config(trained, tmp_path, capfd):
    out = copy_run(trained, tmp_path)
    data = yaml.safe_load((out / "config.yaml").read_text())
    data["method"], data["offpolicy"]["gamma"] = "seddpg", 0.5
    (out / "config.yaml").write_text(yaml.safe_dump(data))
    line = cli_error(
        capfd,
        ["train", "--resume", out, "--quiet"],
        str(out / "config.yaml"),
        str(out / "checkpoints" / "4"),
        "method",
        "offpolicy.gamma",
        "--allow-config-change",
    )
    assert "run.episodes" not in line.split("; resuming")[0]
    cli_error(capfd, ["train", "--resume", out, "--quiet", "--allow-config-change"], "method", "offpolicy.gamma")


def test_allow_config_change_extends_a_run(trained, tmp_path, capfd):
    out = copy_run(trained, tmp_path)
    cli_error(capfd, ["train", "--resume", out, "--quiet", "--episodes", "6"], "run.episodes")
    assert cli.main(["train", "--resume", str(out), "--quiet", "--episodes", "6", "--allow-config-change"]) == 0
    assert load_config(out / "config.yaml").run.episodes == 6
    assert sorted(pd.read_csv(out / "metrics.csv").episode.unique()) == list(range(6))
    assert json.loads((out / "summary.json").read_text())["resumed_from_episode"] == 4


# ----------------------------------------------------------------------------- 7. evaluation


def test_evaluating_a_nan_actor_is_refused(trained, tmp_path, capfd):
    out = copy_run(trained, tmp_path)
    params = dict(np.load(out / "params.npz"))
    key = next(k for k in params if k.startswith("actor/"))
    params[key] = np.full_like(params[key], np.nan)
    np.savez(out / "params.npz", **params)
    cli_error(capfd, ["evaluate", out, "--no-figures"], str(out / "params.npz"), "NaN/Inf", "seed 0")


@pytest.mark.parametrize("flag", ["--range-noise", "--action-noise"])
def test_non_finite_evaluation_noise_is_refused(trained, capfd, flag):
    cli_error(capfd, ["evaluate", trained, flag, "nan"], flag, "finite")
