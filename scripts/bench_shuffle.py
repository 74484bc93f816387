"""PPO's minibatch permutation, jax's against agents/shuffle.py's, in one process (docs/benchmarks.md,
"where PPO's time goes"): the update alone and whole episodes, the two programs alternated, and
their numbers compared (they must be equal: the same permutation).

    python scripts/bench_shuffle.py --method snddpg     # central: one network over 5 x 256 environments
    python scripts/bench_shuffle.py --method flddpg     # the federated fleet
"""

from __future__ import annotations

import argparse
import statistics
import time

import jax
import jax.numpy as jnp

from fedjax_nav.agents import ppo, shuffle
from fedjax_nav.experiments.bench import warm_chunk
from fedjax_nav.experiments.bench_learners import ppo_config
from fedjax_nav.training.hparams import hparams_from_config

PERMUTATIONS = {"shuffle": shuffle.permutation, "jax": jax.random.permutation}


def build(cfg, perm):
    """(jitted update on a random rollout, its inputs, compiled chunk, its state after episode 0,
    rewards, agent-steps per episode), traced with `perm` as PPO's permutation."""
    ppo.shuffle.permutation = perm
    try:
        tr, hp, chunk, states = warm_chunk(cfg)
        agents, bufs = (jax.tree.map(lambda x: x[0], t) for t in (states.agents, states.buffers))
        noise = lambda x: jax.random.normal(jax.random.key(1), x.shape, x.dtype) if x.dtype == jnp.float32 else x
        update = jax.jit(lambda a, b, k: tr._update(a, b, k, jnp.int32(127), hp))
        args = (agents, jax.tree.map(noise, bufs), jax.random.key(0))
        jax.block_until_ready(update(*args))
        return [update, args, chunk, states, [], tr.num_envs * tr.T]
    finally:
        ppo.shuffle.permutation = shuffle.permutation


def timed(fn, *args) -> float:
    t = time.perf_counter()
    jax.block_until_ready(fn(*args))
    return time.perf_counter() - t


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--method", default="snddpg")
    ap.add_argument("--updates", type=int, default=6)
    ap.add_argument("--episodes", type=int, default=2)
    args = ap.parse_args()
    cfg = ppo_config(args.method)
    hp = hparams_from_config(cfg)
    runs = {name: build(cfg, perm) for name, perm in PERMUTATIONS.items()}
    upd, eps = {n: [] for n in runs}, {n: [] for n in runs}
    for i in range(args.updates):
        for n in list(runs)[:: 1 if i % 2 else -1]:
            upd[n].append(timed(runs[n][0], *runs[n][1]))
    for e in range(args.episodes):
        for n in list(runs)[:: 1 if e % 2 else -1]:
            r = runs[n]
            t = time.perf_counter()
            r[3], m = r[2](r[3], hp, jnp.int32(e + 1))
            jax.block_until_ready(m)
            eps[n].append(time.perf_counter() - t)
            r[4].append(float(m["reward"].sum()))
    for n, r in runs.items():
        print(
            f"{args.method} {n:8s} update {1e3 * statistics.median(upd[n]):6.0f} ms (median of {args.updates}); "
            f"episodes {[round(t, 2) for t in eps[n]]} s: {r[5] / statistics.median(eps[n]):,.0f} agent-steps/s; "
            f"rewards {r[4]}"
        )
    same = runs["shuffle"][4] == runs["jax"][4]
    ratio = statistics.median(eps["shuffle"]) / statistics.median(eps["jax"])
    print(
        f"shuffle / jax: update {statistics.median(upd['shuffle']) / statistics.median(upd['jax']):.2f}x, "
        f"episode {ratio:.2f}x; the same rewards: {same}"
    )


if __name__ == "__main__":
    main()
