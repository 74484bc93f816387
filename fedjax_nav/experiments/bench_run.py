"""`fedjax-nav bench env|train|sweep|shared|all` (also `python scripts/bench.py`): the rows of
`experiments/bench.py` and `experiments/bench_learners.py` in one run, printed as a table and, with
`--record FILE`, appended to a markdown file with the machine, versions and command."""

from __future__ import annotations

import sys
import time

import jax

from fedjax_nav.experiments.bench import bench_env, bench_train, format_rows, machine, matmul_ceiling
from fedjax_nav.experiments.bench_learners import bench_learners
from fedjax_nav.experiments.bench_shared import bench_shared
from fedjax_nav.experiments.bench_sweep import bench_sweep


def main(args) -> int:
    what = getattr(args, "what", "env")
    quick = getattr(args, "quick", False)
    rows: list[dict] = []
    if what in ("env", "all"):
        rows += bench_env(batches=(1, 64) if quick else (1, 64, 1024, 4096), steps=20 if quick else 200)
    if what in ("train", "all"):
        ceiling = matmul_ceiling(512 if quick else 2048)
        rows.append({"bench": "ceiling", "gflops": ceiling})
        over = ("env.episode_length=64", "offpolicy.batch_size=64") if quick else ()
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
    if what in ("shared", "all"):
        rows += bench_shared(
            ks=(1, 4) if quick else (1, 4, 8, 16), rooms=8 if quick else 64, steps=20 if quick else 200
        )
    if what in ("sweep", "all"):
        over = ("env.episode_length=64", "offpolicy.batch_size=64") if quick else ()
        rows += bench_sweep(points=2 if quick else 4, episodes=1 if quick else 2, overrides=over)
    table = format_rows(rows)
    print(table)
    record = getattr(args, "record", None)
    if record:
        cli = sys.argv[0].endswith(("fedjax-nav", "__main__.py"))  # the console script or python -m fedjax_nav.cli
        cmd = "fedjax-nav bench " + " ".join(sys.argv[2:]) if cli else " ".join(sys.argv)
        with open(record, "a") as f:
            f.write(
                f"\n### {time.strftime('%Y-%m-%d %H:%M')} — `{cmd}`\n\nMachine: {machine()}\n\n"
                f"| what | setting | result |\n|---|---|---|\n{table}\n"
            )
        print(f"appended to {record}")
    return 0
