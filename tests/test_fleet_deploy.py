"""The Deployment Engine on one machine (docs/fleet.md): a SuperLink and one SuperNode process per
robot on 127.0.0.1 with TLS and SuperNode authentication; a SuperNode whose key is not registered
is refused; the deployed run ends where the in-program run ends."""

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_fleet import TINY

from fedjax_nav import rundir
from fedjax_nav.config import load_config, save_config
from fedjax_nav.training.hparams import hparams_from_config
from fedjax_nav.training.trainer import Trainer

pytest.importorskip("flwr")
from fedjax_nav.fleet.deploy import Deployment, deploy, free_port, main, make_node_key, strays  # noqa: E402


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="reads Linux's /proc")
def test_a_flower_app_process_orphaned_by_a_kill_is_found_by_its_port():
    """A ServerApp outlived its killed SuperLink (its own session): `strays` finds Flower app
    processes by the deployment's ports, which `Deployment.stop` then kills; no other process."""
    port, other = free_port(), free_port()
    code = "import time; time.sleep(60)"
    argv = f"exec -a flwr-serverapp {sys.executable} -c '{code}' --runtime-api-address 127.0.0.1:{port}"
    proc = subprocess.Popen(["bash", "-c", argv])
    try:
        deadline = time.monotonic() + 10
        while proc.pid not in strays([port]) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert strays([port]) == [proc.pid] and strays([other]) == []
    finally:
        proc.kill()
        proc.wait()


def test_a_supernode_whose_key_is_not_registered_is_refused(tmp_path):
    d = Deployment(tmp_path / "deploy")
    try:
        d.start_superlink()
        known, _ = make_node_key(d.work / "keys", "known")
        d.register(make_node_key(d.work / "keys", "other")[1])  # a registered key, not the stranger's
        stranger, _ = make_node_key(d.work / "keys", "stranger")
        assert d.start_supernode(0, stranger, retries=1).wait(timeout=120) != 0
        nodes = d.flwr("supernode", "list", "fleet", "--format", "json").stdout
    finally:
        d.stop()
    assert "Failed to activate SuperNode" in (d.work / "supernode-0.log").read_text()
    assert "No SuperNode found with the given public key" in (d.work / "superlink.log").read_text()
    assert '"status": "online"' not in nodes and "https://127.0.0.1" in (d.work / "superlink.log").read_text()


def test_an_existing_run_is_never_overwritten(tmp_path, capsys):
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / rundir.SUMMARY).write_text("{}")
    assert main(["thesis/flddpg", *TINY, "--out", str(tmp_path / "run")]) == 2
    assert "holds a run already" in capsys.readouterr().err
    assert not (tmp_path / "run.deploy").exists()


def test_the_deployment_ends_where_the_program_ends(tmp_path):
    cfg = load_config("thesis/flddpg", TINY)
    tr, hp = Trainer(cfg), hparams_from_config(cfg)
    states = tr.init_seeds(jnp.asarray([cfg.run.seed]), hp)
    states, _ = tr.compiled_chunk(cfg.run.episodes)(states, hp, jnp.int32(0))
    want = rundir.flatten_params(jax.device_get(tr.learner.shared(states.agents)))

    summary = deploy(cfg, tmp_path / "run", timeout=900)  # TLS and SuperNode authentication on
    assert summary["aggregation_events"] == 2 and summary["fleet"] == "flower"
    with np.load(tmp_path / "run" / rundir.PARAMS) as got:
        assert set(got.files) == set(want)
        for name, value in want.items():
            np.testing.assert_allclose(got[name], value, rtol=1e-5, atol=1e-6, err_msg=name)
    assert rundir.read_config(tmp_path / "run") == cfg
    logs = tmp_path / "run.deploy"
    assert "https://127.0.0.1" in (logs / "superlink.log").read_text()
    assert all("Failed" not in (logs / f"supernode-{i}.log").read_text() for i in range(2))


def _in_program(cfg) -> dict:
    tr, hp = Trainer(cfg), hparams_from_config(cfg)
    states = tr.init_seeds(jnp.asarray([cfg.run.seed]), hp)
    states, _ = tr.compiled_chunk(cfg.run.episodes)(states, hp, jnp.int32(0))
    return rundir.flatten_params(jax.device_get(tr.learner.shared(states.agents)))


def _rounds_done(out, at_least: int, timeout: float = 600.0) -> int:
    start = time.monotonic()
    while time.monotonic() - start < timeout:
        try:
            with np.load(out / rundir.FLEET_STATE) as z:
                if (done := int(z["done"])) >= at_least:
                    return done
        except (FileNotFoundError, OSError, KeyError, ValueError):
            pass
        time.sleep(0.1)
    raise TimeoutError(f"{out}: round {at_least} not done in {timeout} s")


def _processes_of(folder) -> list[str]:
    """The command lines of live processes naming `folder`, or Flower app processes talking to a
    port of a deployment under it (its ports.json): a deployment's leftovers."""
    ports = [p for f in Path(folder).rglob("ports.json") for p in json.loads(f.read_text())]
    found = []
    for proc in Path("/proc").iterdir():
        try:
            line = (proc / "cmdline").read_bytes().replace(b"\0", b" ").decode()
        except OSError:
            continue
        if proc.name.isdigit() and "pytest" not in line:
            if str(folder) in line or any(f"127.0.0.1:{p} " in line + " " for p in ports):
                found.append(line)
    return found


def test_a_killed_server_resumes_and_ends_where_the_program_ends(tmp_path):
    args = [*TINY, "run.episodes=6"]  # 3 rounds
    cfg, out = load_config("thesis/flddpg", args), tmp_path / "run"
    cmd = [sys.executable, "-m", "fedjax_nav.fleet.deploy", "thesis/flddpg", *args, "--out", str(out)]
    driver = subprocess.Popen(cmd, start_new_session=True, stderr=subprocess.PIPE, text=True)
    _rounds_done(out, 1)
    os.killpg(json.loads((tmp_path / "run.deploy" / "pids.json").read_text())["superlink"], signal.SIGKILL)
    assert driver.wait(timeout=300) == 2 and "go on with --resume" in driver.stderr.read()
    assert rundir.read_json(out / rundir.SUMMARY)["rounds_done"] in (1, 2)  # the directory stands after a kill

    summary = deploy(cfg, out, resume=True, timeout=900)
    assert summary["rounds_done"] == 3 and summary["aggregation_events"] == 3
    with np.load(out / rundir.PARAMS) as got:
        for name, value in _in_program(cfg).items():
            np.testing.assert_allclose(got[name], value, rtol=1e-5, atol=1e-6, err_msg=name)
    df = rundir.read_metrics(out)
    assert len(df) == 6 * 2 and df["fed_events"].sum() == 3 * 2 and df["reward"].notna().all()
    assert _processes_of(tmp_path) == []  # nothing of either deployment outlives it


def test_a_killed_robot_is_left_out_of_its_rounds_and_rejoins(tmp_path):
    cfg, out = load_config("thesis/flddpg", [*TINY, "run.episodes=8"]), tmp_path / "run"  # 4 rounds
    save_config(cfg, tmp_path / "run.yaml")
    d, runs = Deployment(tmp_path / "deploy"), []
    try:
        d.start_superlink()
        keys = [make_node_key(d.work / "keys", f"robot-{i}") for i in range(2)]
        for i, (private, public) in enumerate(keys):
            d.register(public)
            d.start_supernode(i, private)
        flwr_run = threading.Thread(target=lambda: runs.append(d.run(tmp_path / "run.yaml", out, 900, 120.0)))
        flwr_run.start()
        _rounds_done(out, 1)
        os.killpg(d.pids["supernode-1"], signal.SIGKILL)  # robot 1 dies before it answers round 2
        _rounds_done(out, 2)
        d.restart_supernode(1, keys[1][0])  # and comes back with its key and its disk
        flwr_run.join(timeout=900)
    finally:
        d.stop()
    assert rundir.read_json(out / rundir.SUMMARY)["rounds_done"] == 4
    df = rundir.read_metrics(out)
    clients = df[df["fed_events"] > 0].groupby("episode")["fed_clients"].max().tolist()  # one per round
    # round 2 closed with robot 0 alone, robot 1 took part again by the last round
    assert clients[:2] == [2, 1] and clients[-1] == 2 and set(clients) == {1, 2}
    robot1 = df[df["robot"] == 1].groupby(df["episode"] // 2)["reward"]  # by round
    assert robot1.apply(lambda r: r.isna().all()).tolist() == [c == 1 for c in clients]
    assert df[df["robot"] == 0]["reward"].notna().all()
    assert _processes_of(tmp_path) == []
