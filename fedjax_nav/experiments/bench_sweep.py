"""`fedjax-nav bench sweep`: a grid of tau values at thesis scale, trained one by one against one
vmapped program (and over every local device): the per-run cost of `fedjax-nav sweep`
(docs/benchmarks.md)."""

from __future__ import annotations

import os
import time

import jax
import jax.numpy as jnp
import numpy as np


def _sweep_config(episodes: int, overrides=()):
    """The thesis FLDDPG preset of `bench_sweep`: `episodes` episodes in one chunk, federated every
    2 episodes (or every one), no checkpoints, then `overrides`."""
    from fedjax_nav.config import load_config

    return load_config(
        "configs/thesis/flddpg.yaml" if os.path.exists("configs/thesis/flddpg.yaml") else None,
        [
            f"run.chunk_episodes={episodes}",
            f"run.episodes={episodes}",
            f"fed.period={min(2, episodes)}",
            "run.checkpoint_every=0",
            *overrides,
        ],
    )


def bench_sweep(points: int = 4, episodes: int = 2, overrides=(), repeat: int = 2) -> list[dict]:
    """A grid of `points` tau values x 1 seed of the thesis FLDDPG preset: the runs one by one (one
    compiled program, batch 1, tau a traced scalar) against one vmapped batch of `points` rows (what
    `fedjax-nav sweep` runs). Both timed after compilation, alternately `repeat` times (best of
    each); the ratio is per run."""
    from fedjax_nav.training.hparams import hparams_from_config, stack_hparams
    from fedjax_nav.training.trainer import Trainer

    cfg = _sweep_config(episodes, overrides)
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
