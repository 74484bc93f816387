"""A real two-process run: two `fedjax-nav train --distributed` processes on localhost (CPU
collectives through gloo, one CPU device each, the 4 clients split 2 + 2) train FLDDPG and
match the single-process run; only process 0 writes the run directory; both processes restore
its checkpoint and the resumed run equals the uninterrupted one bitwise.

"Match": the same tolerance as tests/test_sharding.py (the clients live in two partitioned
executables, so the federated mean is summed in another order): every metric column within
1e-6 relative (max |a - b| <= 1e-6 max |a|), every network within 1e-6 of its largest weight,
goals, collisions and federated events equal. The flags are also read from the usual
environment variables (checked in this process, without starting anything).
"""

import json
import os
import shutil
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from test_sharding import ROBOTS, tiny_worlds  # the same four small rooms

RTOL = 1e-6
EPISODES = 4
TIMEOUT = 300  # s per run: a cold compilation cache on a loaded 2-core machine


def tiny_config(folder: Path) -> Path:
    """FLDDPG in four small rooms, 4 episodes of 32 steps, a checkpoint every 2 episodes."""
    worlds = tiny_worlds(folder)
    cfg = {
        "method": "flddpg",
        "env": {"worlds": worlds, "episode_length": 32},
        "offpolicy": {"hidden": 16, "depth": 2, "batch_size": 8, "buffer_size": 64},
        "fed": {"period": 1},
        "run": {"episodes": EPISODES, "seeds": 1, "chunk_episodes": 1, "checkpoint_every": 2},
    }
    path = folder / "tiny.yaml"
    path.write_text(yaml.safe_dump(cfg))
    return path


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("localhost", 0))
        return s.getsockname()[1]


def cli(*args) -> list[str]:
    return [sys.executable, "-m", "fedjax_nav.cli", "train", *map(str, args), "--quiet"]


@pytest.fixture(scope="module")
def env():
    e = dict(os.environ, JAX_PLATFORMS="cpu", PYTHONUNBUFFERED="1")
    e.pop("XLA_FLAGS", None)  # one CPU device per process
    for k in ("JAX_COORDINATOR_ADDRESS", "JAX_NUM_PROCESSES", "JAX_PROCESS_ID"):
        e.pop(k, None)
    return e


def run_two(env, *args) -> list[subprocess.CompletedProcess]:
    """Start processes 0 and 1 with the same flags; kill both if either fails or time runs out."""
    port = free_port()
    procs = [
        subprocess.Popen(
            cli(*args, "--distributed", "--coordinator", f"localhost:{port}", "--num-processes", 2, "--process-id", i),
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for i in range(2)
    ]
    deadline = time.time() + TIMEOUT
    try:
        while any(p.poll() is None for p in procs):
            if time.time() > deadline or any(p.poll() not in (None, 0) for p in procs):
                break
            time.sleep(0.1)
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
        outs = [p.communicate(timeout=60) for p in procs]
    res = [subprocess.CompletedProcess(p.args, p.returncode, o, e) for p, (o, e) in zip(procs, outs)]
    for i, r in enumerate(res):
        assert r.returncode == 0, f"process {i} (rc {r.returncode}):\n{r.stderr[-3000:]}"
    return res


@pytest.fixture(scope="module")
def runs(tmp_path_factory, env):
    folder = tmp_path_factory.mktemp("distributed")
    cfg = tiny_config(folder)
    t = time.time()
    ref = subprocess.run(
        cli("--config", cfg, "--out", folder / "single"), env=env, capture_output=True, text=True, timeout=TIMEOUT
    )
    assert ref.returncode == 0, ref.stderr[-3000:]
    t_single = time.time() - t
    t = time.time()
    two = run_two(env, "--config", cfg, "--out", folder / "two")
    return {
        "folder": folder,
        "single": folder / "single",
        "two": folder / "two",
        "outputs": two,
        "seconds": {"single": t_single, "two": time.time() - t},
    }


def networks(params: np.lib.npyio.NpzFile) -> dict:
    """params.npz leaves grouped by network ("actor/...", "critic/...")."""
    out: dict = {}
    for k in params.files:
        out.setdefault(k.split("/")[0], []).append(k)
    return out


def test_two_processes_match_the_single_process_run(runs):
    a, b = pd.read_csv(runs["single"] / "metrics.csv"), pd.read_csv(runs["two"] / "metrics.csv")
    assert len(a) == len(b) == EPISODES * ROBOTS
    for col in ("episode", "seed", "robot", "world", "goals", "reached_goal", "collisions", "fed_events", "fed_bytes"):
        pd.testing.assert_series_equal(a[col], b[col], check_exact=True)
    for col in ("reward", "critic_loss", "actor_loss", "q", "epsilon"):
        x, y = a[col].to_numpy(float), b[col].to_numpy(float)
        assert np.max(np.abs(x - y)) <= RTOL * np.max(np.abs(x)), col
    pa, pb = np.load(runs["single"] / "params.npz"), np.load(runs["two"] / "params.npz")
    assert sorted(pa.files) == sorted(pb.files)
    for name, keys in networks(pa).items():
        diff = max(np.max(np.abs(pa[k].astype(np.float64) - pb[k])) for k in keys)
        scale = max(np.max(np.abs(pa[k])) for k in keys)
        assert pa[keys[0]].shape[:2] == (1, ROBOTS) and diff <= RTOL * scale, (name, diff / scale)
    s = json.loads((runs["two"] / "summary.json").read_text())
    assert (s["devices"], s["processes"], s["shard"]) == (2, 2, "clients")
    assert s["aggregation_events"] == EPISODES and s["fed_bytes_total"] == EPISODES * s["bytes_per_fed_round"] > 0


def test_only_process_0_writes_and_prints(runs):
    out0, out1 = runs["outputs"]
    assert "wrote" in out0.stdout and "2 processes" in out0.stdout
    # (gloo's C++ side prints one "[Gloo] Rank i is connected ..." line per process to stdout)
    assert [x for x in out1.stdout.splitlines() if x.strip() and not x.startswith("[Gloo]")] == []
    files = {p.name for p in runs["two"].iterdir()}
    assert {"config.yaml", "metrics.csv", "summary.json", "params.npz", "learning_curves.png", "checkpoints"} <= files
    assert not [p for p in runs["two"].rglob("*tmp*")]  # no temporaries left by either process
    # orbax: process 0 saved alone (its manager works without the others): no file of process 1
    ck = runs["two"] / "checkpoints"
    assert sorted(int(p.name) for p in ck.iterdir() if p.name.isdigit()) == [2, EPISODES]
    assert [p for p in ck.rglob("*") if "process_1" in str(p)] == []


def test_both_processes_restore_and_the_resumed_run_is_the_same(runs, env):
    two, again = runs["two"], runs["folder"] / "resumed"
    shutil.copytree(two, again)
    shutil.rmtree(again / "checkpoints" / str(EPISODES))  # as if killed after episode 2's checkpoint
    run_two(env, "--resume", again)
    assert (again / "metrics.csv").read_bytes() == (two / "metrics.csv").read_bytes()
    pa, pb = np.load(two / "params.npz"), np.load(again / "params.npz")
    for k in pa.files:
        assert pa[k].tobytes() == pb[k].tobytes(), k
    assert json.loads((again / "summary.json").read_text())["resumed_from_episode"] == 2


# ----------------------------------------------------------------------------- flags and env vars


def test_distributed_config_from_flags_or_environment():
    from fedjax_nav.training.parallel import DistributedConfig, ShardingError, distributed_config

    env = {"JAX_COORDINATOR_ADDRESS": "10.0.0.1:1234", "JAX_NUM_PROCESSES": "4", "JAX_PROCESS_ID": "3"}
    assert distributed_config(environ=env) == DistributedConfig("10.0.0.1:1234", 4, 3)
    assert distributed_config("h:1", 2, 0, environ=env) == DistributedConfig("h:1", 2, 0)  # flags first
    with pytest.raises(ShardingError, match="--process-id / JAX_PROCESS_ID"):
        distributed_config("h:1", 2, environ={})
    with pytest.raises(ShardingError, match="process id 2 with 2 processes"):
        distributed_config("h:1", 2, 2, environ={})
    with pytest.raises(ShardingError, match="HOST:PORT"):
        distributed_config("localhost", 2, 0, environ={})
    with pytest.raises(ShardingError, match="integers"):
        distributed_config(environ=dict(env, JAX_NUM_PROCESSES="two"))
