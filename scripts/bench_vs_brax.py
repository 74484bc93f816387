"""Our PPO against brax's `ppo.train`, alternated in one process (docs/benchmarks.md, "where PPO's
time goes"): the shared VM's load drifts between runs, so each brax measurement (its steady rate:
two epoch lengths differenced, experiments/bench_learners.py) sits between two of ours.

    python scripts/bench_vs_brax.py --method snddpg      # central: one network over 1,280 environments
    python scripts/bench_vs_brax.py --method flddpg      # the federated fleet, 5 x 256
"""

from __future__ import annotations

import argparse
import statistics
import time

import jax
import jax.numpy as jnp

from fedjax_nav.experiments.bench import warm_chunk
from fedjax_nav.experiments.bench_learners import bench_brax_ppo, ppo_config


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--method", default="snddpg")
    ap.add_argument("--rounds", type=int, default=2)
    args = ap.parse_args()
    tr, hp, chunk, states = warm_chunk(ppo_config(args.method))
    ours, brax, episode = [], [], 1

    def our_episode():
        nonlocal states, episode
        t = time.perf_counter()
        states, m = chunk(states, hp, jnp.int32(episode))
        jax.block_until_ready(m)
        episode += 1
        ours.append(tr.num_envs * tr.T / (time.perf_counter() - t))

    our_episode()
    for _ in range(args.rounds):
        brax.append(bench_brax_ppo(num_envs=tr.num_envs)[0]["agent_steps_per_s"])
        our_episode()
    print(f"ours ({args.method}, {tr.num_robots} x {tr.envs_per_robot}): {[round(x) for x in ours]} agent-steps/s")
    print(f"brax ppo.train steady ({tr.num_envs} environments): {[round(x) for x in brax]} agent-steps/s")
    print(f"ours / brax (medians): {statistics.median(ours) / statistics.median(brax):.2f}x")


if __name__ == "__main__":
    main()
