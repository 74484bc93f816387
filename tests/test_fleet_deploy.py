"""The Deployment Engine on one machine (docs/fleet.md): a SuperLink and one SuperNode process per
robot on 127.0.0.1 with TLS and SuperNode authentication; a SuperNode whose key is not registered
is refused; the deployed run ends where the in-program run ends."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_fleet import TINY

from fedjax_nav import rundir
from fedjax_nav.config import load_config
from fedjax_nav.training.hparams import hparams_from_config
from fedjax_nav.training.trainer import Trainer

pytest.importorskip("flwr")
from fedjax_nav.fleet.deploy import Deployment, deploy, main, make_node_key  # noqa: E402


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
