"""Our PPO or SAC against brax's `ppo.train` / `sac.train`, alternated in one process
(docs/benchmarks.md, "where PPO's time goes", "SAC against brax's sac.train"): the shared VM's load
drifts between runs, so each brax measurement (its steady rate: two epoch lengths differenced,
experiments/bench_learners.py) sits between two of ours.

    python scripts/bench_vs_brax.py --method snddpg      # central PPO: one network over 1,280 environments
    python scripts/bench_vs_brax.py --method flddpg      # the federated PPO fleet, 5 x 256
    python scripts/bench_vs_brax.py --learner sac --method iddpg   # SAC, one robot: one network x 64 environments
    python scripts/bench_vs_brax.py --learner sac --method flddpg  # the federated SAC fleet, 5 x 64
"""

from __future__ import annotations

import argparse
import statistics
import time

import jax
import jax.numpy as jnp

from fedjax_nav.experiments.bench import _train_config, warm_chunk
from fedjax_nav.experiments.bench_learners import SAC_AS_BRAX, bench_brax_ppo, bench_brax_sac, ppo_config


def config(learner: str, method: str):
    """PPO: the `bench train` PPO row with `method`; SAC: brax's SAC setting (SAC_AS_BRAX) in the
    thesis rooms, one robot with iddpg, else the fleet of 5 robots."""
    if learner == "ppo":
        return ppo_config(method)
    one = ("env.worlds=[train-0]",) if method == "iddpg" else ()
    over = ["run.chunk_episodes=1", "run.checkpoint_every=0", *SAC_AS_BRAX, *one, f"method={method}"]
    return _train_config(over, "sac")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--learner", default="ppo", choices=("ppo", "sac"))
    ap.add_argument("--method", default="snddpg")
    ap.add_argument("--rounds", type=int, default=2)
    args = ap.parse_args()
    tr, hp, chunk, states = warm_chunk(config(args.learner, args.method))
    ours, brax, episode = [], [], 1

    def our_episode():
        nonlocal states, episode
        t = time.perf_counter()
        states, m = chunk(states, hp, jnp.int32(episode))
        jax.block_until_ready(m)
        episode += 1
        ours.append(tr.num_envs * tr.T / (time.perf_counter() - t))

    def brax_rate() -> float:
        if args.learner == "ppo":
            return bench_brax_ppo(num_envs=tr.num_envs)[0]["agent_steps_per_s"]
        return bench_brax_sac(num_envs=tr.envs_per_robot)[0]["agent_steps_per_s"]

    our_episode()
    for _ in range(args.rounds):
        brax.append(brax_rate())
        our_episode()
    print(
        f"ours ({args.learner} {args.method}, {tr.num_robots} x {tr.envs_per_robot}): "
        f"{[round(x) for x in ours]} agent-steps/s"
    )
    print(f"brax {args.learner}.train steady: {[round(x) for x in brax]} agent-steps/s")
    print(f"ours / brax (medians): {statistics.median(ours) / statistics.median(brax):.2f}x")


if __name__ == "__main__":
    main()
