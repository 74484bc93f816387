"""The trainer sharded over devices (fedjax_nav.training.parallel) gives the single-device run's results.

This test process has one CPU device, so the multi-device cases run in one subprocess with 4
forced host devices (`--xla_force_host_platform_device_count=4`, `worker` below) that prints a
JSON report the tests read. Against the same program without a mesh, in that subprocess:
- the federated step of every aggregator (soft, PW, RW, GS; with and without the targets;
  tau = 0, 0.5, 1) with the clients on 2 and 4 devices and the seeds on 2;
- whole runs (2 seeds x 4 robots, 2 episodes of 32 steps in 2 compiled chunks): FLDDPG at
  tau = 0.5, 0, 1 (federated step every episode) and GSDDPG (global model carried, federated
  step every 6 steps), with the clients on 1, 2, 4 devices, the seeds on 2, and a 2 x 2 mesh of
  seeds x clients;
- 20 repeated runs on 4 devices dispatched without blocking between them (the deadlock pitfall
  of collectives on fake CPU devices), each bitwise equal to the first.

What "the same" means here (measured with jax 0.10.2 on XLA:CPU; numbers in docs/scaling.md):
- bitwise: a mesh of one device; every federated step with whole seeds per device;
- within RTOL = 1e-6 relative otherwise: every federated step (max |a - b| <= RTOL * max |a|
  per array) and, after whole runs, every metric array and every network (actor, critic,
  targets, Adam moments, GS's global model: max |a - b| over the network's leaves <= RTOL * its
  largest weight). Discrete outcomes (goals, collisions, federated events) are equal.
  Two causes, both measured: the federated mean over sharded clients is per-device partial sums
  plus an all-reduce (another summation order, 1 ulp), and XLA:CPU's partitioned executable
  differs in the last bit in the local DDPG updates even where the per-device HLO is the
  single-device program's (shard_map of the same function too). Those ulps then travel through
  training like any rounding difference: per array, a bias near zero reaches 5e-6 of its own
  size, and rewards (differences of positions) 1e-5, so the check is per network, and the runs
  are short.
"""

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

RTOL = 1e-6
ROBOTS = 4
SEEDS = 2
DEVICES = 4
EPISODES = 2  # in chunks of one: two compiled calls per run
PLACEMENTS = [("clients", 1), ("clients", 2), ("clients", 4), ("seeds", 2)]
GRID = ("seeds+clients", 4)  # a 2 x 2 mesh naming both axes (whole runs only)
TIMEOUT = 600  # s: a cold compilation cache on a loaded 2-core machine


def tiny_worlds(folder: Path) -> list[str]:
    """Four small rooms (one circle each): compile time grows with the obstacles."""
    folder.mkdir(parents=True, exist_ok=True)
    names = []
    for i in range(ROBOTS):
        spec = {
            "size": [3.0 + 0.5 * i, 3.0],
            "circles": [[0.5, 0.4 * i - 0.6, 0.3]],
            "starts": [[-1.0, -1.0, 0.3 * i]],
            "goals": [[1.0, 1.0]],
        }
        path = folder / f"room-{i}.json"
        path.write_text(json.dumps(spec))
        names.append(str(path))
    return names


def tiny_overrides(worlds: list[str]) -> list[str]:
    return [
        f"env.worlds=[{','.join(worlds)}]",
        "env.episode_length=32",
        "offpolicy.batch_size=8",
        "offpolicy.buffer_size=64",
        "offpolicy.hidden=16",
        "offpolicy.depth=2",
        f"run.seeds={SEEDS}",
        f"run.episodes={EPISODES}",
        "run.chunk_episodes=1",
        "run.checkpoint_every=0",
        "fed.period=1",
    ]


# ----------------------------------------------------------------------------- the worker


def worker(folder: str) -> dict:  # pragma: no cover (runs in the subprocess)
    import jax
    import jax.numpy as jnp

    from fedjax_nav.config import load_config
    from fedjax_nav.training import federation, parallel
    from fedjax_nav.training.hparams import hp_axes, hparams_from_config
    from fedjax_nav.training.trainer import Trainer

    assert jax.device_count() == DEVICES, jax.devices()
    root = Path(__file__).resolve().parents[1] / "configs" / "thesis"
    worlds = tiny_worlds(Path(folder))

    def host(tree):
        unkey = lambda x: jax.random.key_data(x) if jax.dtypes.issubdtype(x.dtype, jax.dtypes.prng_key) else x  # noqa: E731
        flat = jax.tree_util.tree_flatten_with_path(jax.device_get(jax.tree.map(unkey, tree)))[0]
        return [(jax.tree_util.keystr(kp), np.asarray(x)) for kp, x in flat]

    def compare(ref, got) -> dict:
        ref, got = host(ref), host(got)
        assert len(ref) == len(got)
        rel, worst = 0.0, ""
        for (name, a), (_, b) in zip(ref, got):
            assert a.shape == b.shape and a.dtype == b.dtype, name
            if a.dtype.kind in "biu":  # counts, keys: exact
                r = 0.0 if np.array_equal(a, b) else np.inf
            else:
                r = float(np.max(np.abs(a.astype(np.float64) - b))) / (float(np.max(np.abs(a))) or 1.0)
            if r > rel:
                rel, worst = r, name
        return {
            "bitwise": all(np.array_equal(a, b) for (_, a), (_, b) in zip(ref, got)),
            "max_rel": rel,
            "worst": worst,
        }

    def networks(st):
        """Each network as one vector: actor, critic, their targets, Adam's moments, GS's global model."""
        a = st.agents
        return [
            a.actor,
            a.critic,
            a.actor_targ,
            a.critic_targ,
            a.actor_opt.mu,
            a.actor_opt.nu,
            a.critic_opt.mu,
            a.critic_opt.nu,
            st.agg_state,
        ]

    def network_rel(ref, got) -> float:
        """max |a - b| / max |a| over all leaves of one network (per array, a bias near zero would
        weigh the ulps of the larger weights it was computed from)."""
        ref, got = [x for _, x in host(ref)], [x for _, x in host(got)]
        if not ref:
            return 0.0
        diff = max(float(np.max(np.abs(a.astype(np.float64) - b))) for a, b in zip(ref, got))
        return diff / (max(float(np.max(np.abs(a))) for a in ref) or 1.0)

    def mesh_of(axis, n):
        if axis == GRID[0]:
            return jax.make_mesh(
                (2, n // 2),
                ("seeds", "clients"),
                axis_types=(jax.sharding.AxisType.Auto,) * 2,
                devices=jax.devices()[:n],
            )
        return parallel.make_mesh(n, axis)

    report = {"fed_step": {}, "train": {}, "seconds": {}}
    t0 = time.time()

    # --- the federated step of every aggregator, on states whose clients differ
    for method, targets in [
        ("flddpg", False),
        ("flddpg", True),
        ("pwddpg", False),
        ("rwddpg", False),
        ("gsddpg", False),
        ("gsddpg", True),
    ]:
        cfg = load_config(
            root / f"{method}.yaml", tiny_overrides(worlds) + [f"fed.include_targets={str(targets).lower()}"]
        )
        tr, hp = Trainer(cfg), hparams_from_config(cfg)
        st = tr.init_seeds(jnp.arange(SEEDS), hp)
        st = st.replace(
            reward_sum=jax.random.normal(jax.random.key(1), st.reward_sum.shape), reward_steps=jnp.full((SEEDS,), 20.0)
        )
        if method == "gsddpg":  # a global model away from the clients' mean
            st = st.replace(agg_state=jax.tree.map(lambda x: x + 0.1, st.agg_state))
        step = jax.vmap(lambda s, h, tr=tr: federation.federated_round(tr.round, s, h)[0], in_axes=(0, hp_axes(hp)))
        taus = (0.0, 0.5, 1.0) if method != "gsddpg" else (0.5,)  # GS has no tau (beta steps the global model)
        for tau in taus:
            h = hp | {"fed.tau": jnp.float32(tau)}
            ref = jax.jit(step)(st, h)
            for axis, n in PLACEMENTS[1:]:  # (a mesh of one device is checked on whole runs)
                mesh = mesh_of(axis, n)
                sh = parallel.state_shardings(st, mesh)
                f = jax.jit(step, in_shardings=(sh, parallel.seed_shardings(h, mesh)), out_shardings=sh)
                out = f(parallel.put(st, sh), h)
                assert (
                    out.agents.actor["params"]["Dense_0"]["kernel"].sharding
                    == sh.agents.actor["params"]["Dense_0"]["kernel"]
                )
                report["fed_step"][f"{method}{'+targets' if targets else ''} tau={tau} {axis}x{n}"] = compare(ref, out)

    report["seconds"]["fed_step"] = time.time() - t0
    t0 = time.time()

    # --- whole runs: two compiled chunks of one episode; one compilation per placement, reused
    # for every tau (a traced hyperparameter)
    copy = jax.jit(lambda t: jax.tree.map(jnp.copy, t))  # keeps the placement; the original is not donated

    def episodes(chunk, states, hp):
        ms = []
        for first in range(EPISODES):
            states, m = chunk(states, hp, jnp.int32(first))
            ms.append(m)
        return ms, states

    for method, extra, taus in [
        ("flddpg", [], (0.5, 0.0, 1.0)),
        ("gsddpg", ["fed.period_unit=steps", "fed.period=6"], (0.5,)),
    ]:
        cfg = load_config(root / f"{method}.yaml", tiny_overrides(worlds) + extra)
        tr, hp = Trainer(cfg), hparams_from_config(cfg)
        hps = [hp | {"fed.tau": jnp.float32(tau)} for tau in taus]
        init = tr.init_seeds(jnp.arange(SEEDS), hp)
        chunk = tr.compiled_chunk()
        refs = [episodes(chunk, copy(init), h) for h in hps]
        for axis, n in PLACEMENTS + [GRID]:
            mesh = mesh_of(axis, n)
            init = tr.init_seeds(jnp.arange(SEEDS), hp, mesh=mesh)
            chunk = tr.compiled_chunk(mesh=mesh, states=init, hp=hp)
            for tau, h, ref in zip(taus, hps, refs):
                got = episodes(chunk, copy(init), h)
                key = f"{method} tau={tau} {axis}x{n}"
                r = report["train"][key] = compare(ref, got)  # everything, buffers and env states too
                r["metrics"] = compare(ref[0], got[0])
                r["params"] = compare((ref[1].agents, ref[1].agg_state), (got[1].agents, got[1].agg_state))
                r["networks"] = max(network_rel(a, b) for a, b in zip(networks(ref[1]), networks(got[1])))
                r["discrete_equal"] = all(
                    np.array_equal(np.asarray(a[k]), np.asarray(b[k]))
                    for a, b in zip(ref[0], got[0])
                    for k in ("goals", "collisions", "fed_events")
                )
                r["fed_events"] = int(sum(np.asarray(m["fed_events"]).sum() for m in got[0]))

    report["seconds"]["train"] = time.time() - t0
    t0 = time.time()

    # --- 20 runs on 4 devices dispatched back to back (no blocking between them)
    mesh = mesh_of("clients", DEVICES)
    init = tr.init_seeds(jnp.arange(SEEDS), hp, mesh=mesh)  # GSDDPG, its global model on every device
    chunk = tr.compiled_chunk(mesh=mesh, states=init, hp=hp)
    first = episodes(chunk, copy(init), hp)
    outs = [episodes(chunk, copy(init), hp) for _ in range(20)]
    jax.block_until_ready(outs)
    report["repeat"] = {"runs": len(outs), "all_equal_first": all(compare(first, o)["bitwise"] for o in outs)}
    report["seconds"]["repeat"] = time.time() - t0
    return report


# ----------------------------------------------------------------------------- the tests


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    folder = tmp_path_factory.mktemp("sharding")
    # every compilation into conftest's persistent cache (its settings are in os.environ), the small
    # ones of the federated step too
    env = dict(os.environ, JAX_PLATFORMS="cpu", XLA_FLAGS=f"--xla_force_host_platform_device_count={DEVICES}")
    code = (
        "import json, sys; sys.path.insert(0, sys.argv[1]); import test_sharding as t; "
        "print('REPORT ' + json.dumps(t.worker(sys.argv[2])))"
    )
    res = subprocess.run(
        [sys.executable, "-c", code, str(Path(__file__).parent), str(folder)],
        env=env,
        capture_output=True,
        text=True,
        timeout=TIMEOUT,
    )
    assert res.returncode == 0, res.stderr[-4000:]
    line = [x for x in res.stdout.splitlines() if x.startswith("REPORT ")]
    assert line, res.stdout[-2000:] + res.stderr[-2000:]
    return json.loads(line[-1][len("REPORT ") :])


def test_every_aggregator_across_devices(report):
    fed = report["fed_step"]
    kinds = {"flddpg", "flddpg+targets", "pwddpg", "rwddpg", "gsddpg", "gsddpg+targets"}
    assert {k.split()[0] for k in fed} == kinds
    assert {k.split()[1] for k in fed if k.startswith("flddpg ")} == {"tau=0.0", "tau=0.5", "tau=1.0"}
    for key, r in fed.items():
        assert r["max_rel"] <= RTOL, (key, r)
        if key.endswith("clientsx1") or key.endswith("seedsx2"):
            assert r["bitwise"], (key, r)  # one device, or whole seeds per device: the same sums


def test_training_on_1_2_4_devices_matches_one_device(report):
    train = report["train"]
    assert {k.rsplit(" ", 1)[1] for k in train} == {f"{a}x{n}" for a, n in PLACEMENTS + [GRID]}
    for key, r in train.items():
        assert r["metrics"]["max_rel"] <= RTOL, (key, r)  # every metric array
        assert r["networks"] <= RTOL, (key, r)  # every network, target, Adam moment, global model
        assert r["discrete_equal"], key
        assert r["fed_events"] > 0, key  # the federated step ran (every episode, or every 6 steps)
        if key.endswith("clientsx1"):
            assert r["bitwise"], (key, r)


def test_no_deadlock_in_20_repeated_runs(report):
    assert report["repeat"] == {"runs": 20, "all_equal_first": True}


# ----------------------------------------------------------------------------- in this process


def test_placement_errors_name_the_numbers():
    import jax

    from fedjax_nav.training import parallel

    mesh = parallel.make_mesh(1)
    parallel.check_placement(mesh, 3, 5, False, False)  # one device: anything goes
    with pytest.raises(parallel.ShardingError, match="2 devices asked for, 1 available"):
        parallel.make_mesh(2)
    with pytest.raises(parallel.ShardingError, match="'robots'"):
        parallel.make_mesh(1, "robots")

    class FakeMesh:  # check_placement reads only axis names and sizes
        def __init__(self, **shape):
            self.axis_names, self.shape = tuple(shape), shape

    with pytest.raises(parallel.ShardingError, match="5 clients .* over 2 devices"):
        parallel.check_placement(FakeMesh(clients=2), 1, 5, False, False)
    with pytest.raises(parallel.ShardingError, match="3 seeds do not divide over 2 devices"):
        parallel.check_placement(FakeMesh(seeds=2), 3, 4, False, False)
    with pytest.raises(parallel.ShardingError, match="one network.*--shard seeds"):
        parallel.check_placement(FakeMesh(clients=2), 2, 4, True, True)
    with pytest.raises(parallel.ShardingError, match="one replay buffer"):
        parallel.check_placement(FakeMesh(clients=2), 2, 4, False, True)
    parallel.check_placement(FakeMesh(seeds=2), 2, 5, True, True)  # SNDDPG: seeds shard
    assert jax.device_count() == 1


def test_state_shardings_by_field(tmp_path):
    import jax
    import jax.numpy as jnp
    from jax.sharding import PartitionSpec as P

    from fedjax_nav.config import load_config
    from fedjax_nav.training import parallel
    from fedjax_nav.training.hparams import hparams_from_config
    from fedjax_nav.training.trainer import Trainer

    root = Path(__file__).resolve().parents[1] / "configs" / "thesis"
    cfg = load_config(root / "gsddpg.yaml", tiny_overrides(tiny_worlds(tmp_path)))
    tr, hp = Trainer(cfg), hparams_from_config(cfg)
    template = jax.eval_shape(lambda: tr.init_seeds(jnp.arange(SEEDS), hp))
    sh = parallel.state_shardings(template, parallel.make_mesh(1, "clients"))
    spec = lambda t: {x.spec for x in jax.tree.leaves(t)}  # noqa: E731
    for name in parallel.CLIENT_FIELDS:
        if getattr(template, name) is None:  # `world`: only procedural-room runs carry their rooms
            continue
        assert spec(getattr(sh, name)) == {P(None, "clients")}, name
    for name in ("explore", "agg_state", "reward_steps", "key"):
        assert spec(getattr(sh, name)) == {P(None)}, name
    sh = parallel.state_shardings(template, parallel.make_mesh(1, "seeds"))
    assert {x.spec for x in jax.tree.leaves(sh)} == {P("seeds")}


def test_cli_devices_errors_exit_2(tmp_path, capsys):
    from fedjax_nav import cli

    root = Path(__file__).resolve().parents[1] / "configs" / "thesis"
    # jax is already running with 1 device in this process: the flag cannot add more
    rc = cli.main(["train", "--config", str(root / "flddpg.yaml"), "--out", str(tmp_path / "r"), "--devices", "2"])
    assert rc == 2
    assert "2 devices asked for, 1 available" in capsys.readouterr().err
    rc = cli.main(["train", "--config", str(root / "flddpg.yaml"), "--distributed", "--num-processes", "2"])
    assert rc == 2 and "--distributed needs --out" in capsys.readouterr().err


@pytest.mark.skipif((os.cpu_count() or 1) < 2, reason="the default spreads seeds over one device per core")
def test_train_with_seeds_a_multiple_of_the_cores_spreads_them_by_default(tmp_path):
    """`fedjax-nav train --seeds N` (N a multiple of the cores) runs the seeds over one forced CPU
    device per core without any flag; `--devices 1` keeps the one-device program."""
    cores = os.cpu_count()
    cfg = tmp_path / "tiny.yaml"
    cfg.write_text(
        # 2 robots in the smallest shipped room: each subprocess compiles its own program, and the
        # compile time grows with the robots' rooms (the default thesis rooms have up to 60 obstacles)
        "method: flddpg\nenv: {episode_length: 8, worlds: [train-0, train-0]}\n"
        "offpolicy: {hidden: 8, batch_size: 4, buffer_size: 16}\n"
        "fed: {period: 1}\nrun: {episodes: 1, chunk_episodes: 1, checkpoint_every: 0}\n"
    )
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    env["JAX_PLATFORMS"] = "cpu"
    exe = [sys.executable, "-m", "fedjax_nav.cli", "train", "--config", str(cfg), "--seeds", str(cores), "--quiet"]
    for extra, devices in (([], cores), (["--devices", "1"], None)):
        out = tmp_path / f"run{len(extra)}"
        r = subprocess.run(exe + ["--out", str(out)] + extra, env=env, capture_output=True, text=True, timeout=TIMEOUT)
        assert r.returncode == 0, r.stderr[-3000:]
        s = json.loads((out / "summary.json").read_text())
        assert s.get("devices") == devices and (devices is None or s["shard"] == "seeds"), s
