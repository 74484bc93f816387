"""Throughput benchmarks: `fedjax-nav bench env|train|all` (also `python scripts/bench.py`).

env:   env-only agent-steps/s (random actions, one jitted lax.scan) at batch 1, 64, 1024, 4096
       over the thesis's training rooms (24 beams, every obstacle).
train: one thesis-scale FLDDPG episode (5 robots, 1024 steps, 205 updates per robot), timed after
       compilation: agent-steps/s, agent-updates/s, achieved GFLOP/s of the DDPG updates against
       the fp32 matmul ceiling measured in the same run, and the extrapolated wall time of the
       whole 125-episode run; also 1 vs several seeds in one program (per-seed throughput), and
       1, 5 and 40 clients (robots) with one seed; compilation timed separately. Then the other
       learners with many environments per robot (`env.envs_per_robot`): feed-forward PPO with
       5 robots x 256 environments in procedural rooms, SAC and TD3 with 5 x 64, and the env alone
       at PPO's batch (1280) in the thesis rooms and in procedural rooms, and brax's own PPO at
       that batch. Their gradient steps per second count PPO's epochs x minibatches and the
       off-policy `gradient_steps` per update event; FLOP/s are the matmuls of every update and
       every action, counted on the learner's own jaxprs (experiments/flops.py).
sweep: a grid of 4 tau values at thesis scale, one by one against one vmapped program (the
       per-run cost of `fedjax-nav sweep`).

Results print as a table; `--record FILE` appends them, with machine, versions and command, to a
markdown file (docs/benchmarks.md).
"""

from __future__ import annotations

import functools
import os
import platform
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np


def _time(fn, *args, repeat: int = 3) -> float:
    """Best wall time of `repeat` calls after one warm-up (which compiles)."""
    jax.block_until_ready(fn(*args))
    best = np.inf
    for _ in range(repeat):
        t = time.perf_counter()
        jax.block_until_ready(fn(*args))
        best = min(best, time.perf_counter() - t)
    return best


def matmul_ceiling(n: int = 2048, repeat: int = 5) -> float:
    """Achieved fp32 GFLOP/s of an n^3 matmul: the machine's practical ceiling right now."""
    a = jax.random.normal(jax.random.key(0), (n, n), jnp.float32)
    b = jax.random.normal(jax.random.key(1), (n, n), jnp.float32)
    f = jax.jit(jnp.matmul)
    return 2 * n**3 / _time(f, a, b, repeat=repeat) / 1e9


def procedural_rooms(family: str = "mixture", n: int = 64):
    """`n` training-stream rooms of a family (stacked World), as `env.rooms: procedural` draws them."""
    from fedjax_nav.worlds import procedural, suites
    from fedjax_nav.worlds.rooms import RoomSpec

    keys = jax.vmap(suites.train_room_key)(jnp.arange(n))
    return procedural.generate_batch(keys, RoomSpec(family=family))


def bench_env(batches=(1, 64, 1024, 4096), steps: int = 200, worlds_=None, family: str | None = None) -> list[dict]:
    """Env-only agent-steps/s over the named worlds (the thesis's training rooms by default), or
    over 64 procedural rooms of `family`."""
    from fedjax_nav import worlds
    from fedjax_nav.env import NavEnv, make_params

    if family is None:
        names = worlds_ or worlds.THESIS_TRAIN
        world, n, label = worlds.load_many(names), len(names), "thesis rooms" if worlds_ is None else "worlds"
    else:
        world, n, label = procedural_rooms(family), 64, f"procedural {family} rooms"
    env = NavEnv()

    def rollout(key, params):
        k0, k1 = jax.random.split(key)
        actions = jax.random.uniform(k1, (steps, 2), minval=jnp.array([0.0, -1.0]), maxval=1.0)
        _, state = env.reset(k0, params)

        def body(carry, xs):
            state, acc = carry
            k, a = xs
            obs, state, r, term, trunc, _ = env.step(k, state, a, params)
            return (state, acc + jnp.sum(obs) + r), None  # consume obs: no dead-code elimination

        (state, acc), _ = jax.lax.scan(body, (state, 0.0), (jax.random.split(k0, steps), actions))
        return acc

    rows = []
    ndev = jax.local_device_count()
    for b in batches:
        idx = jnp.arange(b) % n
        params = make_params(jax.tree.map(lambda x, idx=idx: x[idx], world))
        keys = jax.random.split(jax.random.key(0), b)
        f = jax.jit(jax.vmap(rollout))
        t = _time(f, keys, params)
        rows.append(
            {
                "bench": "env",
                "batch": b,
                "devices": 1,
                "steps": steps,
                "rooms": label,
                "agent_steps_per_s": b * steps / t,
            }
        )
        if ndev > 1 and b % ndev == 0 and b >= 64:
            # The same program with the batch split over one CPU device per core (shard_map).
            from jax.sharding import NamedSharding
            from jax.sharding import PartitionSpec as P

            mesh = jax.make_mesh((ndev,), ("batch",), axis_types=(jax.sharding.AxisType.Explicit,))
            put = lambda x, mesh=mesh: jax.device_put(x, NamedSharding(mesh, P("batch")))  # noqa: E731
            g = jax.jit(
                jax.shard_map(
                    jax.vmap(rollout),
                    mesh=mesh,
                    in_specs=(P("batch"), P("batch")),
                    out_specs=P("batch"),
                    check_vma=False,
                )
            )
            t = _time(g, put(keys), jax.tree.map(put, params))
            rows.append(
                {
                    "bench": "env",
                    "batch": b,
                    "devices": ndev,
                    "steps": steps,
                    "rooms": label,
                    "agent_steps_per_s": b * steps / t,
                }
            )
    return rows


def _train_config(overrides, learner: str = "ddpg"):
    """The thesis FLDDPG preset with `overrides` and `learner` (validated as a whole)."""
    from fedjax_nav.config import apply_overrides, from_dict, read_yaml

    data = read_yaml("configs/thesis/flddpg.yaml" if os.path.exists("configs/thesis/flddpg.yaml") else "thesis/flddpg")
    return from_dict({**apply_overrides(data, list(overrides)), "learner": learner})


def update_events(cfg, episodes: int) -> int:
    """Update events of one network in `episodes` episodes (PPO: one per rollout; off-policy: one
    every ddpg.train_every steps)."""
    from fedjax_nav.config import ON_POLICY_LEARNERS

    every = cfg.ppo.rollout if cfg.learner in ON_POLICY_LEARNERS else cfg.ddpg.train_every
    return cfg.env.episode_length // every * episodes


def gradient_steps(cfg, nets: int, episodes: int) -> int:
    """Gradient steps of every network in `episodes` episodes (update events x steps per event)."""
    from fedjax_nav.config import ON_POLICY_LEARNERS

    per_event = cfg.ppo.epochs * cfg.ppo.minibatches if cfg.learner in ON_POLICY_LEARNERS else cfg.ddpg.gradient_steps
    return nets * update_events(cfg, episodes) * per_event


def bench_train(
    seeds=(1,),
    episodes: int = 1,
    ceiling: float | None = None,
    overrides=(),
    devices: int = 1,
    shard: str = "seeds",
    learner: str = "ddpg",
) -> list[dict]:
    """`devices` > 1: the seeds spread over that many devices (what `train --seeds N` does by
    default when N is a multiple of the cores), or with `shard="clients"` the robots (padded
    with masked clients to a multiple of `devices`: one thesis seed, 5 robots, as 3 + 3).
    agent-steps count every environment's steps (robots x env.envs_per_robot)."""
    from fedjax_nav.experiments.flops import learner_flops
    from fedjax_nav.training.hparams import hparams_from_config
    from fedjax_nav.training.trainer import Trainer

    rows = []
    for s in seeds:
        cfg = _train_config([f"run.chunk_episodes={episodes}", "run.checkpoint_every=0", *overrides], learner)
        hp = hparams_from_config(cfg)
        mesh = None
        if devices > 1:
            from fedjax_nav.training import parallel

            mesh = parallel.make_mesh(devices, shard, jax.local_devices())
        tr = Trainer(cfg, pad=parallel.client_padding(mesh, cfg.num_robots) if mesh is not None else 0)
        states = tr.init_seeds(jnp.arange(s), hp, mesh=mesh)
        f = tr.compiled_chunk(mesh=mesh, states=states, hp=hp)
        t0 = time.perf_counter()
        states, m = f(states, hp, jnp.int32(0))
        jax.block_until_ready(m)
        compile_s = time.perf_counter() - t0
        t0 = time.perf_counter()
        states, m = f(states, hp, jnp.int32(episodes))
        jax.block_until_ready(m)
        dt = time.perf_counter() - t0
        T, N = cfg.env.episode_length, tr.n_real  # the padding clients' work is not counted
        agent_steps = s * N * cfg.env.envs_per_robot * T * episodes
        updates = s * gradient_steps(cfg, tr.n_real if tr.pad else tr.n_nets, episodes)
        # Matmul FLOPs counted on the learner's own jaxprs (experiments.flops): every update event
        # of every network, and the acting of every environment step.
        n_nets = tr.n_real if tr.pad else tr.n_nets
        per_event, per_act = learner_flops(tr.learner, tr.nets, tr.obs_size, tr.writes, hp)
        flops = s * n_nets * update_events(cfg, episodes) * per_event + agent_steps * per_act
        gflops = flops / dt / 1e9
        rows.append(
            {
                "bench": "train",
                "method": cfg.method,
                "learner": cfg.learner + ("-gru" if cfg.learner == "ppo" and cfg.ppo.recurrent == "gru" else ""),
                "envs_per_robot": cfg.env.envs_per_robot,
                "seeds": s,
                "robots": N,
                "rooms": cfg.env.rooms
                if cfg.env.rooms == "fixed"
                else f"{cfg.env.rooms} {list(cfg.env.room_families)}",
                "devices": devices,
                "shard": shard if devices > 1 else None,
                "padded_clients": tr.pad,
                "agent_steps_per_s": agent_steps / dt,
                "agent_updates_per_s": updates / dt,
                "gflops": gflops,
                "ceiling_gflops": ceiling,
                "fraction_of_ceiling": gflops / ceiling if ceiling and gflops is not None else None,
                "episode_s": dt / episodes,
                "run_estimate_s": dt / episodes * cfg.run.episodes,  # all seeds together
                "compile_s_incl_first_chunk": compile_s,
                "compile_s": max(compile_s - dt, 0.0),  # first call - a steady one
            }
        )
    return rows


# The other learners with many environments per robot (docs/learners.md): feed-forward PPO with
# 5 x 256 environments in procedural rooms (rollout 128 x 256 = 32768 rows per robot and update),
# SAC and TD3 with 5 x 64 (a buffer of 100k rows per robot, one gradient step per update event).
PROCEDURAL = ("env.rooms=procedural", "env.room_families=[mixture]")
LEARNER_ROWS = (
    ("ppo", ("env.envs_per_robot=256", *PROCEDURAL)),
    ("ppo", ("env.envs_per_robot=256", "ppo.recurrent=gru", *PROCEDURAL)),
    ("sac", ("env.envs_per_robot=64", "ddpg.buffer_size=100000", *PROCEDURAL)),
    ("td3", ("env.envs_per_robot=64", "ddpg.buffer_size=100000", *PROCEDURAL)),
)


def bench_brax_ppo(num_envs: int = 1280, rollout: int = 128, minibatches: int = 4, epochs: int = 4, updates=(2, 6)):
    """brax's own `ppo.train` on this project's brax env (the thesis's training rooms, one per
    environment in turn), with the batch of the PPO row: `num_envs` environments, `rollout`-step
    unrolls, `epochs` x `minibatches`, the same 64x2 tanh networks. brax's `training/sps` of an
    epoch includes a fixed cost per epoch (about 6 s here, whatever the epoch's length), so it is
    run with two epoch lengths (`updates` training steps per epoch) and the steady rate is the
    difference of steps over the difference of epoch times; brax's own figure for the longer epoch
    is reported beside it."""
    from brax import envs as brax_envs
    from brax.training.agents.ppo import networks as ppo_networks
    from brax.training.agents.ppo import train as ppo
    from flax import linen

    from fedjax_nav import worlds
    from fedjax_nav.env import brax_env  # noqa: F401  (registers the env)

    env = brax_envs.get_environment(brax_env.ENV_NAME, worlds=list(worlds.THESIS_TRAIN))
    per_update = num_envs * rollout
    net = functools.partial(
        ppo_networks.make_ppo_networks,
        policy_hidden_layer_sizes=(64, 64),
        value_hidden_layer_sizes=(64, 64),
        activation=linen.tanh,
    )
    epoch_s, sps = [], []
    for u in updates:
        walls: list[float] = []

        def progress(step, metrics, walls=walls):
            if "training/walltime" in metrics:
                walls.append(float(metrics["training/walltime"]))
                sps.append(float(metrics["training/sps"]))

        ppo.train(
            env,
            num_timesteps=per_update * u * 2,  # two epochs of u training steps (num_evals - 1)
            num_evals=3,
            episode_length=1024,
            num_envs=num_envs,
            unroll_length=rollout,
            batch_size=num_envs // minibatches,
            num_minibatches=minibatches,
            num_updates_per_batch=epochs,
            normalize_observations=False,
            run_evals=False,
            num_resets_per_eval=0,
            network_factory=net,
            progress_fn=progress,
        )
        epoch_s.append(walls[-1] - walls[-2])  # the second epoch: compiled in the first
    steady = per_update * (updates[1] - updates[0]) / (epoch_s[1] - epoch_s[0])
    return [
        {
            "bench": "brax_ppo",
            "num_envs": num_envs,
            "rollout": rollout,
            "agent_steps_per_s": steady,
            "brax_sps": sps[-1],
            "epoch_fixed_s": epoch_s[0] - per_update * updates[0] / steady,
        }
    ]


def bench_learners(
    overrides=(), rows=LEARNER_ROWS, env_batch: int = 1280, ceiling: float | None = None, brax: bool = True
) -> list[dict]:
    """`bench train` rows of the learners beside DDPG, and at PPO's batch the env alone (in the
    thesis rooms and in the procedural rooms the learners train in) and brax's PPO."""
    out = []
    for learner, extra in rows:
        out += bench_train(seeds=(1,), overrides=(*extra, *overrides), learner=learner, ceiling=ceiling)
    if env_batch:
        out += bench_env(batches=(env_batch,), steps=200)
        out += bench_env(batches=(env_batch,), steps=200, family="mixture")
    if env_batch and brax:
        out += bench_brax_ppo(num_envs=env_batch, updates=(2, 6) if env_batch >= 1024 else (4, 12))
    return out


def bench_sweep(points: int = 4, episodes: int = 2, overrides=(), repeat: int = 2) -> list[dict]:
    """A grid of `points` tau values x 1 seed of the thesis FLDDPG preset: the runs one by one (one
    compiled program, batch 1, tau a traced scalar) against one vmapped batch of `points` rows (what
    `fedjax-nav sweep` runs). Both timed after compilation, alternately `repeat` times (best of
    each); the ratio is per run."""
    from fedjax_nav.config import load_config
    from fedjax_nav.training.hparams import hparams_from_config, stack_hparams
    from fedjax_nav.training.trainer import Trainer

    cfg = load_config(
        "configs/thesis/flddpg.yaml" if os.path.exists("configs/thesis/flddpg.yaml") else None,
        [
            f"run.chunk_episodes={episodes}",
            f"run.episodes={episodes}",
            f"fed.period={min(2, episodes)}",
            "run.checkpoint_every=0",
            *overrides,
        ],
    )
    tr = Trainer(cfg)
    base = hparams_from_config(cfg)
    taus = np.linspace(0.0, 1.0, points).astype(np.float32)
    hps = [base | {"fed.tau": jnp.float32(t)} for t in taus]
    f = tr.compiled_chunk()

    def run(seeds, hp):
        states = tr.init_seeds(jnp.asarray(seeds, jnp.int32), hp)
        jax.block_until_ready(states)
        t = time.perf_counter()
        _, m = f(states, hp, jnp.int32(0))
        jax.block_until_ready(m)
        return time.perf_counter() - t

    grid_hp = stack_hparams(hps)
    n_dev = jax.local_device_count()
    sharded = None
    if n_dev > 1 and points % n_dev == 0:  # what `fedjax-nav sweep` does by default: rows over devices
        from fedjax_nav.training import parallel

        mesh = parallel.make_mesh(n_dev, "seeds", jax.local_devices())
        st = tr.init_seeds(jnp.zeros(points, jnp.int32), grid_hp, mesh=mesh)
        f_mesh = tr.compiled_chunk(mesh=mesh, states=st, hp=grid_hp)

        def sharded():
            states = tr.init_seeds(jnp.zeros(points, jnp.int32), grid_hp, mesh=mesh)
            jax.block_until_ready(states)
            t = time.perf_counter()
            _, m = f_mesh(states, grid_hp, jnp.int32(0))
            jax.block_until_ready(m)
            return time.perf_counter() - t

    t0 = time.perf_counter()
    run([0], hps[0])  # compile batch 1
    run([0] * points, grid_hp)  # compile batch `points`
    if sharded:
        sharded()
    compile_s = time.perf_counter() - t0
    one, grid, grid_dev = np.inf, np.inf, np.inf
    for _ in range(repeat):  # alternate, keep the best of each: the load drifts on a shared machine
        one = min(one, sum(run([0], h) for h in hps))
        grid = min(grid, run([0] * points, grid_hp))
        if sharded:
            grid_dev = min(grid_dev, sharded())
    T, N = cfg.env.episode_length, tr.num_robots
    row = {
        "bench": "sweep",
        "points": points,
        "episodes": episodes,
        "robots": N,
        "steps": T,
        "one_by_one_s": one,
        "sweep_s": grid,
        "per_run_one_by_one_s": one / points,
        "per_run_sweep_s": grid / points,
        "sweep_speedup": one / grid,
        "compile_s": compile_s,
        "repeat": repeat,
        "devices": n_dev if sharded else 1,
    }
    if sharded:
        row.update({"sweep_devices_s": grid_dev, "sweep_devices_speedup": one / grid_dev})
    return [row]


def machine() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            cpu = next(line.split(":", 1)[1].strip() for line in f if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    py = platform.python_version()
    return f"{cpu}, {os.cpu_count()} cores, {jax.default_backend()}; jax {jax.__version__}, python {py}"


def format_rows(rows: list[dict]) -> str:
    lines = []
    for r in rows:
        if r["bench"] == "env":
            lines.append(
                f"| env | batch {r['batch']}, {r['devices']} device(s), {r.get('rooms', 'thesis rooms')}, "
                "random actions | "
                f"{r['agent_steps_per_s']:,.0f} agent-steps/s |"
            )
        elif r["bench"] == "sweep":
            lines.append(
                f"| sweep | {r['points']} tau values x 1 seed, {r['episodes']} x {r['steps']} steps, "
                f"{r['robots']} robots | "
                f"one by one {r['one_by_one_s']:.1f} s ({r['per_run_one_by_one_s']:.1f} s per run); one vmapped "
                f"program {r['sweep_s']:.1f} s ({r['per_run_sweep_s']:.1f} s per run): {r['sweep_speedup']:.2f}x; "
                f"compiling both {r['compile_s']:.0f} s |"
            )
            if r.get("sweep_devices_s"):
                lines.append(
                    f"| sweep, rows over {r['devices']} devices (the default) | the same grid | "
                    f"{r['sweep_devices_s']:.1f} s ({r['sweep_devices_s'] / r['points']:.1f} s per run): "
                    f"{r['sweep_devices_speedup']:.2f}x one by one |"
                )
        elif r["bench"] == "brax_ppo":
            lines.append(
                f"| brax ppo.train | {r['num_envs']} environments x {r['rollout']}-step unrolls, thesis rooms | "
                f"{r['agent_steps_per_s']:,.0f} agent-steps/s steady (epochs of two lengths differenced; "
                f"brax's own training/sps {r['brax_sps']:,.0f}, with a fixed {r['epoch_fixed_s']:.1f} s per epoch) |"
            )
        elif r["bench"] == "ceiling":
            lines.append(f"| matmul 2048^3 fp32 | ceiling | {r['gflops']:.1f} GFLOP/s |")
        else:
            learner, per = r.get("learner", "ddpg"), r.get("envs_per_robot", 1)
            flops = (
                f"{r['gflops']:.1f} GFLOP/s = {100 * (r['fraction_of_ceiling'] or 0):.0f}% of ceiling; "
                if r.get("gflops") is not None
                else ""
            )
            lines.append(
                f"| train {r['method']}{f' ({learner})' if learner != 'ddpg' else ''} | "
                f"{r['seeds']} seed(s) x {r['robots']} robots"
                f"{f' x {per} environments' if per > 1 else ''}"
                f"{f', seeds over {d} devices' if (d := r.get('devices', 1)) > 1 else ''}"
                f"{f', {rooms} rooms, new every episode' if (rooms := r.get('rooms', 'fixed')) != 'fixed' else ''} | "
                f"{r['agent_steps_per_s']:,.0f} agent-steps/s, {r['agent_updates_per_s']:,.0f} "
                f"{'agent-updates/s' if learner == 'ddpg' else 'gradient steps/s'}, {flops}"
                f"episode {r['episode_s']:.2f} s, 125-episode run (all its seeds) ~{r['run_estimate_s']:.0f} s; "
                f"compile ~{r['compile_s']:.1f} s (first call minus a steady one) |"
            )
    return "\n".join(lines)


def main(args) -> int:
    what = getattr(args, "what", "env")
    quick = getattr(args, "quick", False)
    rows: list[dict] = []
    if what in ("env", "all"):
        rows += bench_env(batches=(1, 64) if quick else (1, 64, 1024, 4096), steps=20 if quick else 200)
    if what in ("train", "all"):
        ceiling = matmul_ceiling(512 if quick else 2048)
        rows.append({"bench": "ceiling", "gflops": ceiling})
        over = ("env.episode_length=64", "ddpg.batch_size=64") if quick else ()
        rows += bench_train(seeds=(1,), ceiling=ceiling, overrides=over)
        if not quick:  # right after it: the same run drawing a fresh procedural room per robot and episode
            proc = ("env.rooms=procedural", "env.room_families=[mixture]")
            rows += bench_train(seeds=(1,), ceiling=ceiling, overrides=(*over, *proc))
            rows += bench_train(seeds=(8,), ceiling=ceiling, overrides=over)
        n_dev = jax.local_device_count()
        if n_dev > 1 and not quick:  # the default fast path of `train --seeds 8` on this machine
            rows += bench_train(seeds=(8,), ceiling=ceiling, overrides=over, devices=n_dev)
        # scaling with the number of clients: 1 and 40 robots (the thesis's rooms repeated), one seed
        for robots in (1,) if quick else (1, 40):
            rooms = ", ".join(f"train-{[0, 2, 3, 4, 5][i % 5]}" for i in range(robots))
            rows += bench_train(seeds=(1,), ceiling=ceiling, overrides=(*over, f"env.worlds=[{rooms}]"))
        small = (*over, "env.envs_per_robot=4", "ppo.rollout=32") if quick else ()
        rows += bench_learners(small, env_batch=64 if quick else 1280, ceiling=ceiling, brax=not quick)
        rows.append({"bench": "ceiling", "gflops": matmul_ceiling(512 if quick else 2048)})  # again: load drifts
    if what in ("sweep", "all"):
        over = ("env.episode_length=64", "ddpg.batch_size=64") if quick else ()
        rows += bench_sweep(points=2 if quick else 4, episodes=1 if quick else 2, overrides=over)
    table = format_rows(rows)
    print(table)
    record = getattr(args, "record", None)
    if record:
        cmd = "fedjax-nav bench " + " ".join(sys.argv[2:]) if sys.argv[0].endswith("fedjax-nav") else " ".join(sys.argv)
        with open(record, "a") as f:
            f.write(
                f"\n### {time.strftime('%Y-%m-%d %H:%M')} — `{cmd}`\n\nMachine: {machine()}\n\n"
                f"| what | setting | result |\n|---|---|---|\n{table}\n"
            )
        print(f"appended to {record}")
    return 0
