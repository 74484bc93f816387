"""Steps/s of the vmap vector env (`NavVectorEnv`) against gymnasium's SyncVectorEnv of `NavGymEnv`s.

    JAX_PLATFORMS=cpu python scripts/bench_gym_vector.py [--num-envs 64] [--steps 200]

Both run the same task (world train-0, random placement, 1024-step episodes) with the same
uniform random actions drawn in advance, so collisions make the sub-envs reset (NEXT_STEP
autoreset) as in training. Each is timed over `--steps` vector steps after a warm-up that
compiles everything (the vmap env is timed over 5 passes, it is that much faster);
env-steps/s = num_envs * steps timed / seconds. Both are built in this one
process and timed back to back, so their ratio holds on a shared machine even when the load
drifts (the load average is printed).
"""

from __future__ import annotations

import argparse
import os
import time

import gymnasium
import numpy as np

import fedjax_nav.env.gym_env as gym_env

KWARGS = dict(world="train-0", placement="random", episode_length=1024)


def time_steps(envs, actions: np.ndarray, repeat: int = 1) -> float:
    """Seconds for `repeat` passes over the actions (len(actions) vector steps each, after a reset)."""
    envs.reset(seed=0)
    t0 = time.perf_counter()
    for _ in range(repeat):
        for a in actions:
            envs.step(a)
    return time.perf_counter() - t0


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--num-envs", type=int, default=64)
    p.add_argument("--steps", type=int, default=200)
    args = p.parse_args()
    n = args.num_envs
    rng = np.random.default_rng(0)
    actions = rng.uniform([0.0, -1.0], [1.0, 1.0], size=(args.steps, n, 2)).astype(np.float32)
    print(f"load average before: {os.getloadavg()[0]:.2f}, num_envs={n}, steps={args.steps}")
    results = {}
    for mode, repeat in (("vector_entry_point", 5), ("sync", 1)):
        t0 = time.perf_counter()
        envs = gymnasium.make_vec(gym_env.ENV_ID, num_envs=n, vectorization_mode=mode, **KWARGS)
        time_steps(envs, actions[:20])  # warm-up: compiles reset, step and the autoreset path
        build = time.perf_counter() - t0
        sec = time_steps(envs, actions, repeat)
        results[mode] = n * args.steps * repeat / sec
        print(f"{mode:>18}: {results[mode]:>10,.0f} env-steps/s ({sec:.2f} s; build + warm-up {build:.1f} s)")
        envs.close()
    ratio = results["vector_entry_point"] / results["sync"]
    print(f"ratio vmap / sync: {ratio:.1f}x; load average after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
