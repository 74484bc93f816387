"""Training throughput in dense procedural rooms against sparse ones, same run (docs/dense_rooms.md,
"Training in dense rooms with many environments per robot"): the `bench train` PPO row (5 robots x
256 environments, a fresh room per environment per episode) with each family in turn, one 1024-step
episode timed after a compiling one, and each row's ratio to the first (the sparse 'mixture').

    python scripts/bench_dense_training.py                                  # mixture, forest, warehouse, maze, cave
    python scripts/bench_dense_training.py --families mixture cave --learner td3 --envs 64
"""

from __future__ import annotations

import argparse
import sys

from fedjax_nav.experiments.bench import bench_train, machine


def rows(families, learner: str = "ppo", envs: int = 256) -> list[dict]:
    out = []
    for fam in families:
        extra = (f"env.envs_per_robot={envs}", "env.rooms=procedural", f"env.room_families=[{fam}]")
        (r,) = bench_train(seeds=(1,), overrides=extra, learner=learner)
        out.append(r | {"family": fam})
    return out


def table(rs: list[dict]) -> str:
    base = rs[0]["agent_steps_per_s"]
    head = f"| family | agent-steps/s | ratio to {rs[0]['family']} | episode s | compile s |"
    lines = [head, "|---|---|---|---|---|"]
    for r in rs:
        lines.append(
            f"| {r['family']} | {r['agent_steps_per_s']:,.0f} | {r['agent_steps_per_s'] / base:.2f} | "
            f"{r['episode_s']:.2f} | {r['compile_s']:.0f} |"
        )
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--families", nargs="+", default=["mixture", "forest", "warehouse", "maze", "cave"])
    ap.add_argument("--learner", default="ppo")
    ap.add_argument("--envs", type=int, default=256, help="environments per robot (5 robots)")
    a = ap.parse_args(argv)
    rs = rows(a.families, a.learner, a.envs)
    print(f"Machine: {machine()}; learner {a.learner}, 5 robots x {a.envs} environments\n")
    print(table(rs))
    return 0


if __name__ == "__main__":
    sys.exit(main())
