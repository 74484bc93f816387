"""Env throughput of the robot models, measured alternately in one run (docs/robot.md, docs/benchmarks.md).

    python scripts/bench_robot.py [--batch 4096] [--steps 100] [--rounds 3]

Agent-steps/s of `NavEnv.step` (random actions, one jitted lax.scan, vmapped over the batch, the
thesis's five training rooms) with the env settings the trainer builds for each model: the ideal
robot (noise off, 24 exact beams), the full TurtleBot3 Burger model (noise on, a 360-sample scan
pooled to 24 beams, 3 physics substeps, a 1-step command delay, acceleration limits, ...) and the
same model on 24 exact beams (`robot.scan_samples=0`: what the dense scan costs). Each model is
compiled first; then the models are timed in turn, `--rounds` times; the best of each is printed.
"""

from __future__ import annotations

import argparse
import platform
import time

import jax
import jax.numpy as jnp


def program(robot, steps: int, batch: int):
    from fedjax_nav import worlds
    from fedjax_nav.env import NavEnv, make_params
    from fedjax_nav.experiments.bench import random_rollout

    names = worlds.THESIS_TRAIN
    world = worlds.load_many(names)
    env = NavEnv(**robot.env_settings())
    traced = {
        k: getattr(robot, k)
        for k in (
            "accel_lin",
            "accel_ang",
            "delay_steps",
            "range_noise",
            "range_resolution",
            "range_min",
            "dropout",
            "footprint",
            "lidar_offset",
        )
    }
    idx = jnp.arange(batch) % len(names)
    params = make_params(jax.tree.map(lambda x: x[idx], world), **traced)

    rollout = random_rollout(env, steps)

    f = jax.jit(jax.vmap(rollout))
    keys = jax.random.split(jax.random.key(0), batch)
    return lambda: jax.block_until_ready(f(keys, params))


def main(argv=None):
    import dataclasses

    from fedjax_nav.robots import RobotConfig

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--batch", type=int, default=4096)
    ap.add_argument("--steps", type=int, default=100)
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args(argv)
    tb3 = RobotConfig(model="turtlebot3_burger")
    models = {
        "ideal": RobotConfig(),
        "turtlebot3_burger": tb3,
        "turtlebot3_burger, scan_samples=0": dataclasses.replace(tb3, scan_samples=0),
    }
    fns = {}
    for name, robot in models.items():
        t = time.perf_counter()
        fns[name] = program(robot, args.steps, args.batch)
        fns[name]()  # compile + first run
        print(f"{name}: compiled and ran once in {time.perf_counter() - t:.1f} s", flush=True)
    best = {name: float("inf") for name in fns}
    for _ in range(args.rounds):
        for name, fn in fns.items():
            t = time.perf_counter()
            fn()
            best[name] = min(best[name], time.perf_counter() - t)
    print(
        f"\nbatch {args.batch}, {args.steps} steps, best of {args.rounds} alternating rounds; "
        f"{platform.processor() or platform.machine()}, {jax.devices()[0].platform}, jax {jax.__version__}"
    )
    print("| robot model | agent-steps/s | relative to ideal |\n|---|---|---|")
    for name, t in best.items():
        rate = args.batch * args.steps / t
        print(f"| {name} | {rate:,.0f} | {best['ideal'] / t:.3f} |")


if __name__ == "__main__":
    main()
