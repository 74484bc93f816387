"""Throughput benchmarks: `fedjax-nav bench env|train|all` (also `python scripts/bench.py`).

env:   env-only agent-steps/s (random actions, one jitted lax.scan) at batch 1, 64, 1024, 4096
       over the thesis's training rooms (24 beams, every obstacle).
train: one thesis-scale FLDDPG episode (5 robots, 1024 steps, 205 updates per robot), timed after
       compilation: agent-steps/s, agent-updates/s, achieved GFLOP/s of its updates and actions
       against the fp32 matmul ceiling measured in the same run, and the extrapolated wall time of
       the whole 125-episode run; also 1 vs several seeds in one program (per-seed throughput),
       and 1, 5 and 40 clients (robots) with one seed; compilation timed separately. Then
       (experiments/bench_learners.py) the other learners with many environments per robot
       (`env.envs_per_robot`): feed-forward and recurrent PPO with 5 robots x 256 environments
       in procedural rooms, central PPO (one network, `method=snddpg`) over the same 1280
       environments in the thesis rooms (brax's setting), SAC and TD3 with 5 x 64, the env alone
       at PPO's batch (1280) in the thesis rooms and in procedural rooms, and brax's own PPO at
       that batch, with each PPO row's ratio to brax's steady rate. Their gradient
       steps per second count PPO's epochs x minibatches and the off-policy `gradient_steps` per
       update event; FLOP/s are the matmuls of every update and every action, counted on the
       learner's own jaxprs (experiments/flops.py).
sweep: a grid of 4 tau values at thesis scale, one by one against one vmapped program (the
       per-run cost of `fedjax-nav sweep`; experiments/bench_sweep.py).

Results print as a table (experiments/bench_run.py runs the rows); `--record FILE` appends them,
with machine, versions and command, to a markdown file (docs/benchmarks.md).
"""

from __future__ import annotations

import math
import os
import platform
import time

import jax
import jax.numpy as jnp
import numpy as np

from fedjax_nav.config import Config


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


def random_rollout(env, steps: int):
    """`rollout(key, params) -> f32[]`: one robot driving `steps` uniform random actions (linear
    in [0, 1], angular in [-1, 1]) from a reset, summing its observations and rewards so that
    nothing is dead code: what every env benchmark times (vmapped and jitted by the caller)."""

    def rollout(key, params):
        k0, k1 = jax.random.split(key)
        actions = jax.random.uniform(k1, (steps, 2), minval=jnp.array([0.0, -1.0]), maxval=1.0)
        _, state = env.reset(k0, params)

        def body(carry, xs):
            state, acc = carry
            k, a = xs
            obs, state, r, *_ = env.step(k, state, a, params)
            return (state, acc + jnp.sum(obs) + r), None  # consume obs: no dead-code elimination

        (state, acc), _ = jax.lax.scan(body, (state, 0.0), (jax.random.split(k0, steps), actions))
        return acc

    return rollout


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
    rollout = random_rollout(env, steps)

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


def warm_chunk(cfg):
    """(Trainer, hp, its compiled chunk, states after the chunk's first, compiling call) of `cfg`
    for one seed: what the profiling scripts time from (scripts/profile_chunk.py, bench_*.py)."""
    from fedjax_nav.training.hparams import hparams_from_config
    from fedjax_nav.training.trainer import Trainer

    hp = hparams_from_config(cfg)
    tr = Trainer(cfg)
    chunk = tr.compiled_chunk()
    states, m = chunk(tr.init_seeds(jnp.arange(1), hp), hp, jnp.int32(0))
    jax.block_until_ready(m)
    return tr, hp, chunk, states


THESIS_LEARNER = Config().learner  # the default: its rows are labelled without it, as before


def _learner_label(cfg) -> str:
    """The learner's name, with its recurrent field's value where it has a memory ("ppo-gru")."""
    from fedjax_nav.config import get
    from fedjax_nav.learner_table import get as learner_row

    row = learner_row(cfg.learner)
    memory = get(cfg, row.recurrent) if row.recurrent else "none"
    return cfg.learner + ("" if memory == "none" else f"-{memory}")


def update_events(cfg, episodes: int) -> int:
    """Update events of one network in `episodes` episodes (PPO: one per rollout; off-policy: one
    every offpolicy.train_every steps)."""
    from fedjax_nav.config import get
    from fedjax_nav.learner_table import get as learner_row

    every = get(cfg, learner_row(cfg.learner).update_every)
    return cfg.env.episode_length // every * episodes


def gradient_steps(cfg, nets: int, episodes: int) -> int:
    """Gradient steps of every network in `episodes` episodes (update events x steps per event)."""
    from fedjax_nav.config import get
    from fedjax_nav.learner_table import get as learner_row

    per_event = math.prod(get(cfg, name) for name in learner_row(cfg.learner).steps_per_update)
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
                "learner": _learner_label(cfg),
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
        elif r["bench"] == "brax_sac":
            lines.append(
                f"| brax sac.train | {r['num_envs']} environments, one gradient step of {r['batch']} rows per "
                f"environment step, thesis rooms | {r['agent_steps_per_s']:,.0f} agent-steps/s steady (epochs of two "
                f"lengths differenced; brax's own training/sps {r['brax_sps']:,.0f}) |"
            )
        elif r["bench"] == "shared":
            lines.append(
                f"| env, shared rooms | {r['robots_per_room']} robots per room x {r['rooms']} procedural "
                f"mixture rooms, random actions | {r['shared_steps_per_s']:,.0f} agent-steps/s together, "
                f"{r['separate_steps_per_s']:,.0f} alone: a robot's step costs {r['cost_per_robot']:.2f}x |"
            )
        elif r["bench"] == "ratio":
            lines.append(f"| ratio, same run | {r['what']} | {r['value']:.2f}x |")
        elif r["bench"] == "ceiling":
            lines.append(f"| matmul 2048^3 fp32 | ceiling | {r['gflops']:.1f} GFLOP/s |")
        else:
            learner, per = r.get("learner", THESIS_LEARNER), r.get("envs_per_robot", 1)
            flops = (
                f"{r['gflops']:.1f} GFLOP/s = {100 * (r['fraction_of_ceiling'] or 0):.0f}% of ceiling; "
                if r.get("gflops") is not None
                else ""
            )
            lines.append(
                f"| train {r['method']}{f' ({learner})' if learner != THESIS_LEARNER else ''} | "
                f"{r['seeds']} seed(s) x {r['robots']} robots"
                f"{f' x {per} environments' if per > 1 else ''}"
                f"{f', seeds over {d} devices' if (d := r.get('devices', 1)) > 1 else ''}"
                f"{f', {rooms} rooms, new every episode' if (rooms := r.get('rooms', 'fixed')) != 'fixed' else ''} | "
                f"{r['agent_steps_per_s']:,.0f} agent-steps/s, {r['agent_updates_per_s']:,.0f} "
                f"{'agent-updates/s' if learner == THESIS_LEARNER else 'gradient steps/s'}, {flops}"
                f"episode {r['episode_s']:.2f} s, 125-episode run (all its seeds) ~{r['run_estimate_s']:.0f} s; "
                f"compile ~{r['compile_s']:.1f} s (first call minus a steady one) |"
            )
    return "\n".join(lines)
