"""Long runs that lose nothing: checkpoints, exact resume, clear input errors, the NaN guard.

Real `fedjax-nav train` subprocesses are killed (SIGKILL) or interrupted (SIGINT) after their first
checkpoint or before it, resumed with `--resume` (also from a damaged latest checkpoint, falling
back to the newest intact one, and with `--from-checkpoint N`), and compared with one
uninterrupted run of the same tiny config (module fixture `reference`): every metric (metrics.csv)
and every parameter (params.npz) must be bitwise identical. Each class of bad input ends with one
line naming the file and the field, exit code 2 and no traceback.

Every subprocess pays the jax import and, without a cache, the compilation of the trainer; they
share one persistent compilation cache (JAX_COMPILATION_CACHE_DIR, a temporary folder unless one
is already set), so only the first compiles.
"""

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest
import yaml
from conftest import sigint_at_default

from fedjax_nav import cli
from fedjax_nav.config import load_config
from fedjax_nav.rundir import atomic_write
from fedjax_nav.training.checkpoint import Checkpointer, CheckpointError
from fedjax_nav.training.hparams import hparams_from_config
from fedjax_nav.training.run import DivergenceError, train
from fedjax_nav.training.trainer import Trainer

EPISODES = 16
SEEDS = 2
ROBOTS = 2
TINY = {
    "method": "iddpg",
    # the smallest shipped room for both robots: every subprocess traces the trainer again, and
    # tracing and compiling grow with the rooms' obstacles (train-2 has 30)
    "env": {"worlds": ["train-0", "train-0"], "episode_length": 16},
    "offpolicy": {"hidden": 16, "depth": 2, "batch_size": 8, "buffer_size": 64},
    "run": {"episodes": EPISODES, "seeds": SEEDS, "chunk_episodes": 1, "checkpoint_every": 2, "keep_checkpoints": 3},
}
TIMEOUT = 300  # s, per subprocess (a loaded 2-core machine)


# ----------------------------------------------------------------------------- helpers


@pytest.fixture(scope="module")
def env(tmp_path_factory):
    # the subprocesses compile into conftest's shared cache, the small programs too (its settings
    # are in os.environ)
    e = dict(os.environ, JAX_PLATFORMS="cpu", PYTHONUNBUFFERED="1")
    e.setdefault("JAX_COMPILATION_CACHE_DIR", str(tmp_path_factory.mktemp("jax_cache")))
    return e


@pytest.fixture(scope="module")
def cfg_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("cfg") / "tiny.yaml"
    path.write_text(yaml.safe_dump(TINY))
    return path


def cmd(*args) -> list[str]:
    return [sys.executable, "-m", "fedjax_nav.cli", *map(str, args)]


def run_cli(env, *args) -> subprocess.CompletedProcess:
    return subprocess.run(cmd(*args), env=env, capture_output=True, text=True, timeout=TIMEOUT)


def steps(out: Path) -> list[int]:
    """Finished checkpoints (orbax renames a step's temporary folder to `<step>` once it is complete)."""
    d = out / "checkpoints"
    return sorted(int(p.name) for p in d.iterdir() if p.name.isdigit()) if d.is_dir() else []


def check_csv(path: Path) -> int:
    """metrics.csv as a reader sees it mid-run: parseable, whole episodes only. Returns the rows."""
    df = pd.read_csv(path)
    assert list(df.columns[:3]) == ["episode", "seed", "robot"]
    assert len(df) > 0 and len(df) % (SEEDS * ROBOTS) == 0
    assert np.isfinite(df["reward"].to_numpy(float)).all()
    return len(df)


def start_until(env, out: Path, ready, *args, poll: float = 0.02) -> subprocess.Popen:
    """Start `fedjax-nav train` and return once `ready(out)` holds, the process still running.
    Reads metrics.csv on every poll (atomic writes: never half-written)."""
    proc = subprocess.Popen(
        cmd("train", *args, "--quiet"),
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=sigint_at_default,
    )
    deadline = time.time() + TIMEOUT
    while not ready(out):
        if proc.poll() is not None or time.time() > deadline:
            proc.kill()
            _, err = proc.communicate()
            pytest.fail(f"the run ended before it could be stopped (rc {proc.returncode}): {err[-2000:]}")
        if (out / "metrics.csv").exists():
            check_csv(out / "metrics.csv")
        time.sleep(poll)
    assert proc.poll() is None, "the run ended before it could be interrupted; make it longer"
    return proc


def start_until_checkpoint(env, out: Path, *args) -> subprocess.Popen:
    """`start_until` the first checkpoint exists."""
    proc = start_until(env, out, steps, *args)
    check_csv(out / "metrics.csv")  # written before the first checkpoint was saved
    return proc


def stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.kill()
    proc.communicate(timeout=60)


def assert_same_run(a: Path, b: Path) -> None:
    """Every metric and every parameter bitwise identical."""
    assert (a / "metrics.csv").read_bytes() == (b / "metrics.csv").read_bytes()
    da, db = pd.read_csv(a / "metrics.csv"), pd.read_csv(b / "metrics.csv")
    assert len(da) == EPISODES * SEEDS * ROBOTS
    pd.testing.assert_frame_equal(da, db, check_exact=True)
    pa, pb = np.load(a / "params.npz"), np.load(b / "params.npz")
    assert sorted(pa.files) == sorted(pb.files) and len(pa.files) > 4
    for k in pa.files:
        x, y = pa[k], pb[k]
        assert x.dtype == y.dtype and x.shape == y.shape and x.tobytes() == y.tobytes(), k
    sa, sb = (json.loads((d / "summary.json").read_text()) for d in (a, b))
    for k in ("success_last", "reward_last", "success_last_per_seed", "episodes_done", "aggregation_events"):
        assert sa[k] == sb[k], k


def no_temporaries(out: Path) -> None:
    left = [p.name for p in out.iterdir() if ".tmp-" in p.name]
    assert not left, left


@pytest.fixture(scope="module")
def reference(env, cfg_file, tmp_path_factory):
    """The uninterrupted run."""
    out = tmp_path_factory.mktemp("reference") / "run"
    r = run_cli(env, "train", "--config", cfg_file, "--out", out, "--quiet")
    assert r.returncode == 0, r.stderr[-3000:]
    assert steps(out) == [12, 14, 16]  # every 2 episodes, the last 3 kept
    return out


# ----------------------------------------------------------------------------- kill -9, Ctrl-C


def test_kill_9_mid_run_then_resume_is_bitwise_identical(reference, env, cfg_file, tmp_path):
    out = tmp_path / "run"
    proc = start_until_checkpoint(env, out, "--config", cfg_file, "--out", out)
    try:
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=60)
    finally:
        stop(proc)
    assert proc.returncode == -signal.SIGKILL
    done = steps(out)
    assert done and done[-1] < EPISODES
    check_csv(out / "metrics.csv")

    r = run_cli(env, "train", "--resume", out, "--quiet")
    assert r.returncode == 0, r.stderr[-3000:]
    assert "Traceback" not in r.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["resumed_from_episode"] == done[-1]
    assert_same_run(reference, out)


def test_sigint_saves_exits_130_and_resumes_bitwise_identical(reference, env, cfg_file, tmp_path):
    out = tmp_path / "run"
    proc = start_until_checkpoint(env, out, "--config", cfg_file, "--out", out)
    try:
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=TIMEOUT)
    finally:
        stop(proc)
    assert proc.returncode == 130, err[-3000:]
    assert "--resume" in err and str(out) in err and "Traceback" not in err
    done = steps(out)
    assert done and done[-1] < EPISODES
    assert f"interrupted after episode {done[-1]};" in err  # the chunk finished, then saved
    assert len(pd.read_csv(out / "metrics.csv")) == done[-1] * SEEDS * ROBOTS

    r = run_cli(env, "train", "--resume", out, "--quiet")
    assert r.returncode == 0, r.stderr[-3000:]
    assert json.loads((out / "summary.json").read_text())["resumed_from_episode"] == done[-1]
    assert_same_run(reference, out)


# Where a kill before the first checkpoint leaves the run: its config written, no episode yet (the
# trainer compiling), or episodes in metrics.csv (then checkpoints every 8 episodes, a field that
# changes neither the program nor its numbers, so that several chunks pass before the first one).
BEFORE_FIRST_CHECKPOINT = {
    "config": ((), lambda out: (out / "config.yaml").exists()),
    "episodes": (("--set", "run.checkpoint_every=8"), lambda out: (out / "metrics.csv").exists()),
}


@pytest.mark.parametrize("when", list(BEFORE_FIRST_CHECKPOINT))
def test_kill_9_before_the_first_checkpoint_then_resume_starts_again_bitwise_identical(
    reference, env, cfg_file, tmp_path, capfd, when
):
    out = tmp_path / "run"
    extra, ready = BEFORE_FIRST_CHECKPOINT[when]
    proc = start_until(env, out, ready, "--config", cfg_file, "--out", out, *extra, poll=0.002)
    try:
        proc.send_signal(signal.SIGSTOP)  # frozen where it is: the folder can be checked, then killed
        assert steps(out) == [], "the first checkpoint was saved before the kill; lengthen the window"
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=60)
    finally:
        stop(proc)
    assert (out / ".lock").exists() and (out / "config.yaml").exists()

    # --out refuses the folder and says how to resume it (in-process: refused before compiling)
    assert cli.main(["train", "--config", str(cfg_file), "--out", str(out), "--quiet"]) == 2
    line = capfd.readouterr().err.strip().splitlines()[-1]
    assert line.startswith("error: ") and f"--resume {out}" in line and "episode 0" in line, line

    r = run_cli(env, "train", "--resume", out, "--quiet")
    assert r.returncode == 0, r.stderr[-3000:]
    assert "no complete checkpoint" in r.stderr and "starting again from episode 0" in r.stderr, r.stderr
    assert "Traceback" not in r.stderr
    assert json.loads((out / "summary.json").read_text())["resumed_from_episode"] == 0
    assert_same_run(reference, out)


def largest_state_file(ckpt: Path) -> Path:
    """The largest file of a checkpoint's state (ties broken by name: the same file every run)."""
    files = sorted((p for p in (ckpt / "state").rglob("*") if p.is_file()), key=lambda p: (p.stat().st_size, str(p)))
    return files[-1]


@pytest.mark.parametrize("how", ["damaged", "asked"])
def test_resume_falls_back_from_a_damaged_checkpoint_or_starts_where_asked(reference, env, tmp_path, how):
    """A damaged latest checkpoint: `--resume` continues from the newest intact one, a line naming
    both; `--from-checkpoint 12`: from that one. The newer ones are removed and saved again."""
    out = tmp_path / "run"
    shutil.copytree(reference, out)
    if how == "damaged":
        victim = largest_state_file(out / "checkpoints" / "16")
        victim.write_bytes(victim.read_bytes()[: victim.stat().st_size // 3])
        r = run_cli(env, "train", "--resume", out, "--quiet")
        start, needles = 14, (str(out / "checkpoints" / "16"), "corrupted", "checkpoint 14", "newest intact")
    else:
        r = run_cli(env, "train", "--resume", out, "--from-checkpoint", 12, "--quiet")
        start, needles = 12, ("checkpoint 12", "(14, 16) are removed")
    assert r.returncode == 0, r.stderr[-3000:]
    notices = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(notices) == 1 and all(n in notices[0] for n in needles), r.stderr[-3000:]
    assert json.loads((out / "summary.json").read_text())["resumed_from_episode"] == start
    assert steps(out) == [12, 14, 16]
    assert_same_run(reference, out)


def test_a_short_run_of_any_length_follows_with_its_chunk_and_resumes_bitwise(reference, env, tmp_path):
    """`--episodes N` that the file's chunk (4) does not divide: the chunk becomes the largest
    divisor of N (2), the checkpoints a multiple of it (4, unchanged); extending that run with
    `--resume --episodes 16` gives the reference's numbers bitwise (chunking changes no number).
    An extension the kept chunk does not divide is refused in one line."""
    path = tmp_path / "chunk4.yaml"
    path.write_text(yaml.safe_dump({**TINY, "run": {**TINY["run"], "chunk_episodes": 4, "checkpoint_every": 4}}))
    out = tmp_path / "run"
    r = run_cli(env, "train", "--config", path, "--episodes", 2, "--out", out, "--quiet")
    assert r.returncode == 0, r.stderr[-3000:]
    saved = load_config(out / "config.yaml").run
    assert (saved.episodes, saved.chunk_episodes, saved.checkpoint_every) == (2, 2, 4)
    r = run_cli(env, "train", "--resume", out, "--episodes", 7, "--allow-config-change", "--quiet")
    assert r.returncode == 2 and "--episodes 7" in r.stderr and "chunks of 2 episodes" in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1, r.stderr
    r = run_cli(env, "train", "--resume", out, "--episodes", EPISODES, "--allow-config-change", "--quiet")
    assert r.returncode == 0, r.stderr[-3000:]
    assert steps(out) == [8, 12, 16]
    assert_same_run(reference, out)


@pytest.mark.parametrize("layout", ["saved", "old-ddpg-section"])
def test_resuming_a_finished_run_rewrites_the_same_results(reference, env, tmp_path, layout):
    """A kill after the last checkpoint but before the result files: --resume finishes them. Also
    for a run directory written before the offpolicy section, whose config.yaml holds the off-policy
    settings in `ddpg:` (docs/learners.md, "Configuration"): it resumes as the same run."""
    out = tmp_path / "run"
    shutil.copytree(reference, out)
    for f in ("metrics.csv", "summary.json", "params.npz"):
        (out / f).unlink()
    if layout == "old-ddpg-section":
        data = yaml.safe_load((out / "config.yaml").read_text())
        data["ddpg"] = {**data.pop("offpolicy"), **data["ddpg"]}
        (out / "config.yaml").write_text(yaml.safe_dump(data))
        assert load_config(out / "config.yaml") == load_config(reference / "config.yaml")
    r = run_cli(env, "train", "--resume", out, "--quiet")
    assert r.returncode == 0, r.stderr[-3000:]
    assert_same_run(reference, out)


# ----------------------------------------------------------------------------- bad input: exit 2


def expect_error(rc: int, err: str, *needles: str) -> str:
    """Exit code 2, one line `error: ...` holding every needle, no traceback."""
    assert rc == 2, err[-3000:]
    assert "Traceback" not in err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), err[-3000:]
    for n in needles:
        assert n in lines[0], (n, lines[0])
    return lines[0]


def cli_error(capfd, argv, *needles) -> str:
    """In-process `fedjax-nav ...` (these fail before any compilation)."""
    rc = cli.main([str(a) for a in argv])
    return expect_error(rc, capfd.readouterr().err, *needles)


def write_cfg(tmp_path: Path, **sections) -> Path:
    data = json.loads(json.dumps(TINY))
    for s, v in sections.items():
        if isinstance(v, dict):
            data.setdefault(s, {}).update(v)
        else:
            data[s] = v
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def test_unknown_config_key(tmp_path, capfd):
    path = write_cfg(tmp_path, offpolicy={"hiden": 32})
    cli_error(capfd, ["train", "--config", path, "--out", tmp_path / "run"], str(path), "offpolicy.hiden", "allowed")


def test_wrong_type(tmp_path, capfd):
    path = write_cfg(tmp_path, offpolicy={"batch_size": "eight"})
    cli_error(
        capfd,
        ["train", "--config", path, "--out", tmp_path / "run"],
        str(path),
        "offpolicy.batch_size",
        "expected an integer",
    )


def test_out_of_range_value(tmp_path, capfd):
    path = write_cfg(tmp_path, offpolicy={"gamma": 1.5})
    cli_error(
        capfd,
        ["train", "--config", path, "--out", tmp_path / "run"],
        str(path),
        "offpolicy.gamma",
        "out of range",
        "allowed [0.0, 1.0]",
    )


def test_buffer_smaller_than_batch(tmp_path, capfd):
    path = write_cfg(tmp_path, offpolicy={"buffer_size": 4, "batch_size": 8})
    cli_error(
        capfd,
        ["train", "--config", path, "--out", tmp_path / "run"],
        str(path),
        "offpolicy.buffer_size",
        "offpolicy.batch_size",
    )


@pytest.mark.parametrize(
    "sections, fields",
    [
        ({"method": "flddpg", "fed": {"period": EPISODES + 1}}, ("fed.period", "run.episodes")),
        ({"run": {"chunk_episodes": 2, "checkpoint_every": 3}}, ("run.checkpoint_every", "run.chunk_episodes")),
    ],
)
def test_inconsistent_periods(tmp_path, capfd, sections, fields):
    path = write_cfg(tmp_path, **sections)
    cli_error(capfd, ["train", "--config", path, "--out", tmp_path / "run"], str(path), *fields)


def test_bad_world_file(tmp_path, capfd):
    world = tmp_path / "room.json"
    world.write_text(json.dumps({"size": [4.0, 4.0], "starts": [[0.0, 0.0, 0.0]]}))  # no goals
    path = write_cfg(tmp_path, env={"worlds": ["train-0", str(world)]})
    cli_error(capfd, ["train", "--config", path, "--out", tmp_path / "run"], str(world), "goals")


def test_resume_with_a_changed_config_lists_the_fields(reference, tmp_path, capfd):
    out = tmp_path / "run"
    out.mkdir()
    shutil.copy(reference / "config.yaml", out / "config.yaml")
    line = cli_error(
        capfd,
        ["train", "--resume", out, "--set", "offpolicy.hidden=32", "--set", "offpolicy.gamma=0.5"],
        str(out / "config.yaml"),
        "offpolicy.hidden",
        "offpolicy.gamma",
    )
    assert "run.episodes" not in line


@pytest.mark.parametrize("damage", ["truncate", "garble"])
def test_corrupted_checkpoint_is_detected(reference, env, tmp_path, damage):
    """Asked for by `--from-checkpoint` (no fallback), a damaged checkpoint is one line, exit 2."""
    out = tmp_path / "run"
    shutil.copytree(reference, out)
    ckpt = out / "checkpoints" / "16"
    victim = largest_state_file(ckpt)
    data = bytearray(victim.read_bytes())
    if damage == "truncate":  # tensorstore cannot read the arrays in it
        data, needles = data[: len(data) // 3], ("cannot be read",)
    else:  # same size, 16 bytes flipped in the middle: it decodes to other numbers (the checksum
        # catches it) or, where the bytes hit the storage's framing, does not decode at all; both
        # are a detected corruption (one line, exit 2, naming the field)
        for i in range(len(data) // 2, len(data) // 2 + 16):
            data[i] ^= 0x5A
        needles = ("does not match the checksum", "cannot be read")
    victim.write_bytes(bytes(data))
    r = run_cli(env, "train", "--resume", out, "--from-checkpoint", 16, "--quiet")
    line = expect_error(r.returncode, r.stderr, str(ckpt), "field", "corrupted", "--from-checkpoint N (12, 14)")
    assert any(n in line for n in needles), line


def test_incompatible_checkpoint_names_the_path_and_a_field(reference, env, tmp_path):
    """A checkpoint of other network sizes (config.yaml edited after training): `--resume` stops at
    the config fingerprinted in the checkpoint; a restore into other shapes names the field."""
    out = tmp_path / "run"
    shutil.copytree(reference, out)
    data = yaml.safe_load((out / "config.yaml").read_text())
    data["offpolicy"]["hidden"] = 32
    (out / "config.yaml").write_text(yaml.safe_dump(data))
    r = run_cli(env, "train", "--resume", out, "--quiet")
    expect_error(r.returncode, r.stderr, str(out / "checkpoints" / "16"), "offpolicy.hidden", "differs")
    cfg = load_config(out / "config.yaml")
    template = Trainer(cfg).init_seeds(jnp.arange(SEEDS), hparams_from_config(cfg))
    ck = Checkpointer(out)
    try:
        with pytest.raises(CheckpointError) as info:
            ck.restore(template)
    finally:
        ck.close()
    line = str(info.value)
    assert str(out / "checkpoints" / "16") in line and "field" in line, line
    assert re.search(r"has shape \[[0-9, ]*16\], the config needs \[[0-9, ]*32\]", line), line


# ----------------------------------------------------------------------------- NaN guard


def test_injected_nan_stops_the_run_and_keeps_the_last_good_checkpoint(env, cfg_file, tmp_path):
    out = tmp_path / "run"
    r = run_cli(
        env,
        "train",
        "--config",
        cfg_file,
        "--out",
        out,
        "--quiet",
        "--set",
        "run.episodes=2",
        "--set",
        "run.checkpoint_every=1",
    )
    assert r.returncode == 0, r.stderr[-3000:]
    assert steps(out) == [1, 2]
    good = dict(np.load(out / "params.npz"))

    # Continue to 4 episodes with a NaN learning rate: the first update of episode 2 poisons the nets.
    cfg = load_config(out / "config.yaml", ["run.episodes=4"])
    nan_hp = hparams_from_config(cfg) | {"offpolicy.lr": jnp.float32(jnp.nan)}
    with pytest.raises(DivergenceError) as info:
        train(cfg, out, progress=False, hp=nan_hp, resume=True, allow_config_change=True)
    msg = str(info.value)
    assert "NaN/Inf" in msg and "episode 2," in msg and "seed 0," in msg and "robot 0" in msg, msg

    assert steps(out) == [1, 2]  # nothing saved from the diverged episode
    assert len(pd.read_csv(out / "metrics.csv")) == 2 * SEEDS * ROBOTS
    trainer = Trainer(cfg)
    template = trainer.init_seeds(jnp.arange(SEEDS), hparams_from_config(cfg))
    ck = Checkpointer(out)
    try:
        assert ck.latest() == 2
        states, metrics = ck.restore(template)
    finally:
        ck.close()
    assert metrics["reward"].shape[:2] == (SEEDS, 2)
    # the last good checkpoint holds exactly the parameters the 2-episode run ended with
    for name in ("actor", "critic"):
        for kp, leaf in jax.tree_util.tree_flatten_with_path(getattr(states.agents, name))[0]:
            key = name + "/" + "/".join(str(getattr(k, "key", k)) for k in kp)
            np.testing.assert_array_equal(np.asarray(leaf), good[key])
            assert np.isfinite(np.asarray(leaf)).all()


# ----------------------------------------------------------------------------- atomic writes


def test_atomic_write_keeps_the_old_file_and_leaves_no_temporary(tmp_path):
    target = tmp_path / "metrics.csv"
    atomic_write(target, lambda p: Path(p).write_text("a,b\n1,2\n"))
    assert target.read_text() == "a,b\n1,2\n"

    def crash(p):  # e.g. a full disk halfway through
        Path(p).write_text("a,b\n3,")
        raise OSError(28, "No space left on device")

    with pytest.raises(OSError):
        atomic_write(target, crash)
    assert target.read_text() == "a,b\n1,2\n"
    assert [p.name for p in tmp_path.iterdir()] == ["metrics.csv"]


def test_run_directory_has_no_temporaries(reference):
    no_temporaries(reference)
    for f in ("config.yaml", "metrics.csv", "summary.json", "params.npz", "learning_curves.png"):
        assert (reference / f).stat().st_size > 0, f
    check_csv(reference / "metrics.csv")


def test_a_checksum_mismatch_names_the_field(tmp_path, monkeypatch):
    """The checksum comparison itself, independent of where a corruption lands in the storage's
    files (the garble case above may hit the framing instead): a restored field whose CRC differs
    from the one saved is an error naming that field."""
    from fedjax_nav.training import checkpoint as ck

    states = {"a": jnp.arange(4.0), "b": {"c": jnp.ones(3)}}
    c = ck.Checkpointer(tmp_path / "run", async_save=False)
    c.save(1, states, {"reward": np.zeros(2)})
    c.wait()
    real = ck._checksums

    def tampered(s):  # the CRC of the second field read back differs from the saved one
        crc = np.array(real(s))
        crc[1] ^= 1
        return crc

    monkeypatch.setattr(ck, "_checksums", tampered)
    with pytest.raises(ck.CheckpointError, match=r"field b\.c does not match the checksum"):
        c.restore(states)
    c.close()


def test_zero_size_leaves_come_back_as_the_templates_own_arrays(tmp_path):
    """A feed-forward PPO's empty GRU state is stored as one zero element (orbax refuses size 0);
    restored, it is the template's array itself, placed as the run placed it. A numpy stand-in
    there made a resumed PPO sweep on two devices trace its chunk twice (the restored leaf, then
    the chunk's sharded output), measured on generalization_1e8: "compilations per group: 2"."""
    from fedjax_nav.training import checkpoint as ck

    states = {"gru": jnp.zeros((2, 5, 0)), "w": jnp.arange(4.0)}
    c = ck.Checkpointer(tmp_path / "run", async_save=False)
    c.save(1, states, {"reward": np.zeros(2)})
    c.wait()
    template = {"gru": jnp.zeros((2, 5, 0)), "w": jnp.zeros(4)}
    restored, _ = c.restore(template)
    c.close()
    assert restored["gru"] is template["gru"]
    np.testing.assert_array_equal(restored["w"], states["w"])
