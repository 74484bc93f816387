"""Real fleets on Flower (docs/fleet.md): the package stays free of Flower; a robot's slice of the
program draws that robot's keys; the Flower simulation of a 2-robot FLDDPG run ends where the
in-program run ends (to float32 round-off) and leaves a normal run directory."""

import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from fedjax_nav import rundir
from fedjax_nav.config import load_config
from fedjax_nav.fleet.robot import FleetError, check
from fedjax_nav.training.hparams import hparams_from_config
from fedjax_nav.training.trainer import Trainer

TINY = [
    "env.episode_length=16",
    "offpolicy.batch_size=8",
    "offpolicy.buffer_size=64",
    "offpolicy.hidden=16",
    "offpolicy.random_steps=8",
    "offpolicy.train_every=2",
    "run.checkpoint_every=0",
    "env.worlds=[train-0,train-2]",
    "run.episodes=4",
    "fed.period=2",
]


def test_the_package_and_its_cli_import_no_flower():
    code = "import sys, fedjax_nav, fedjax_nav.cli, fedjax_nav.fleet.server; print('flwr' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


@pytest.mark.parametrize(
    "override, field",
    [
        ("method=seddpg", "method"),
        ("fed.period_unit=steps", "fed.period_unit"),
        ("run.seeds=2", "run.seeds"),
        ("env.shared_rooms=true", "env.shared_rooms"),
    ],
)
def test_what_the_fleet_does_not_run_is_refused_naming_the_field(override, field):
    with pytest.raises(FleetError, match=f"^{field}: "):
        check(load_config("thesis/flddpg", TINY + [override]))


def test_a_one_robot_slice_draws_that_robots_keys():
    """Robot 1 of a 2-robot IDDPG run, alone in its program (Trainer(fleet=(1, 2))), after one episode."""
    import dataclasses

    cfg = load_config("thesis/iddpg", TINY)
    whole, hp = Trainer(cfg), hparams_from_config(cfg)
    mine = dataclasses.replace(cfg, env=dataclasses.replace(cfg.env, worlds=(cfg.env.worlds[1],)))
    part = Trainer(mine, fleet=(1, 2))
    a, _ = jax.jit(whole.episode)(whole.init(jax.random.key(0), hp), hp, jnp.int32(0))
    b, _ = jax.jit(part.episode)(part.init(jax.random.key(0), hp), hp, jnp.int32(0))
    assert float(a.reward_sum[1]) == pytest.approx(float(b.reward_sum[0]), rel=1e-6)
    for x, y in zip(jax.tree.leaves(a.agents), jax.tree.leaves(b.agents)):
        np.testing.assert_allclose(np.asarray(x[1]), np.asarray(y[0]), rtol=1e-5, atol=1e-6)


# Federated PPO (FedAvg soft, tau 0.5, every 2 episodes) with 4 environments per robot, in fixed rooms.
PPO_TINY = [
    *("env.envs_per_robot=4", "ppo.rollout=8", "ppo.hidden=16", "run.eval_every=0", "run.seeds=1"),
    *("env.rooms=fixed", "env.worlds=[train-0,train-2]", "env.episode_length=16", "run.episodes=4"),
    *("run.checkpoint_every=0", "run.chunk_episodes=2"),
]


@pytest.mark.parametrize(
    "name, overrides, atol", [("thesis/flddpg", TINY, 1e-6), ("learners/ppo", PPO_TINY, 1e-5)], ids=["flddpg", "ppo"]
)
def test_the_flower_simulation_ends_where_the_program_ends(tmp_path, name, overrides, atol):
    """To float32 round-off: one robot per program sums in another order than two (measured: FLDDPG
    6e-8 at most, PPO 1.2e-6, Adam's step amplifying round-off of its first updates)."""
    pytest.importorskip("flwr")
    pytest.importorskip("ray")
    from fedjax_nav.fleet.apps import run_simulation

    cfg = load_config(name, overrides)
    tr, hp = Trainer(cfg), hparams_from_config(cfg)
    states = tr.init_seeds(jnp.asarray([cfg.run.seed]), hp)
    states, _ = tr.compiled_chunk(cfg.run.episodes)(states, hp, jnp.int32(0))
    want = rundir.flatten_params(jax.device_get(tr.learner.shared(states.agents)))

    summary = run_simulation(cfg, tmp_path / "run")
    assert summary["aggregation_events"] == 2 and summary["fleet"] == "flower"
    with np.load(tmp_path / "run" / rundir.PARAMS) as got:
        assert set(got.files) == set(want)
        for leaf, value in want.items():
            np.testing.assert_allclose(got[leaf], value, rtol=1e-5, atol=atol, err_msg=leaf)
    df = rundir.read_metrics(tmp_path / "run")
    assert len(df) == cfg.run.episodes * 2 and df["fed_events"].sum() == 2 * 2  # one per round, on each robot's row
    assert rundir.read_config(tmp_path / "run") == cfg


def _sends(server, scale=1.0, seed=0):
    """Each robot's send as it would arrive: the model the server holds for it, perturbed."""
    rng = np.random.default_rng(seed)
    key = np.asarray(jax.random.key_data(jax.random.key(0)))
    out = {}
    for i, held in enumerate(server.held):
        shared = {k: (v + rng.normal(0, 0.01, v.shape)).astype(v.dtype) for k, v in held.items()}
        out[i] = shared | {"reward": np.array([0.5], np.float32), "key": key}
    out[2] = {k: v * scale if k.startswith("shared") else v for k, v in out[2].items()}
    return out


def _largest(server, robots=(0, 1)) -> float:
    return max(float(np.abs(server.held[i][k]).max()) for i in robots for k in server.held[i])


@pytest.mark.parametrize("rule", ["mean", "median"])
def test_the_server_refuses_nan_and_misshapen_sends_and_a_robust_rule_outvotes_a_scaled_one(rule):
    from fedjax_nav.fleet.server import Server

    cfg = load_config("thesis/flddpg", [*TINY, "env.worlds=[train-0,train-2,train-3]", f"fed.aggregator={rule}"])
    server = Server(cfg)
    honest = _largest(server)

    sends = _sends(server)
    name = next(iter(sends[2]))
    sends[2][name] = np.full_like(sends[2][name], np.nan)
    sends[1][name] = sends[1][name][..., :-1]
    refused = server.aggregate(sends)
    assert set(refused) == {1, 2} and "not finite" in refused[2] and "the run's is" in refused[1]
    assert int(server.stats["clients"]) == 1 and np.isfinite(_largest(server, (0, 1, 2)))

    refused = server.aggregate(_sends(server, scale=100.0, seed=1))  # robot 2 scales its update
    assert refused == {} and int(server.stats["clients"]) == 3
    if rule == "median":  # outvoted: the honest robots stay where honest models are
        assert _largest(server) < 2 * honest
    else:  # the plain mean is pulled away (what the robust rules are for)
        assert _largest(server) > 10 * honest


def test_a_byzantine_robot_sends_the_programs_attack_and_the_median_outvotes_it():
    from fedjax_nav.fleet.robot import Robot
    from fedjax_nav.fleet.server import Server

    cfg = load_config("thesis/flddpg", [*TINY, "env.worlds=[train-0,train-2,train-3]", "fed.aggregator=median"])
    server, liar = Server(cfg), Robot(cfg, 2)
    honest, initial = _largest(server), dict(server.held[2])  # robot 2's initial model, as the robot has it
    sends = _sends(server)
    truthful = sends[2]
    sends[2] = liar.attacked(truthful, "scale", None)  # node config byzantine=scale, no answer taken yet
    for name, ref in initial.items():  # the program's "scale": reference + (-10) (own - reference)
        np.testing.assert_allclose(sends[2][name], ref - 10.0 * (truthful[name] - ref), rtol=1e-5, atol=1e-6)
    noisy = liar.attacked(truthful, "noise", None)
    assert all(np.isfinite(noisy[k]).all() and not np.allclose(noisy[k], truthful[k]) for k in initial)
    with pytest.raises(FleetError, match="^byzantine: 'stale' is no attack a robot sends"):
        liar.attacked(truthful, "stale", None)
    assert server.aggregate(sends) == {} and _largest(server) < 2 * honest  # outvoted
