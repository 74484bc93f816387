"""The fleet's cost (docs/fleet.md, "Cost"): for R robots, the wall time of a federated round on
Flower's simulation engine against the same round in one compiled program, and the bytes a round
puts on the wire against the in-program accounting (summary.json's bytes_per_fed_round).

    python scripts/bench_fleet.py --robots 5,50 --rounds 4

Each robot's config is the thesis FLDDPG (its networks, so its bytes) with short episodes; the
Flower run's rounds are read from its fleet_rounds.csv (the first round, where every robot
compiles, is left out of the medians), the in-program round is one compiled chunk of fed.period
episodes of the whole fleet, timed after its compiling call.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

# Robots' programs from JAX's persistent compilation cache, as the Deployment Engine's are
# (fleet/deploy.py): a robot that lands on another Ray actor than last round loads its program.
os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", os.path.expanduser("~/.cache/fedjax_nav_jax"))

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from fedjax_nav import rundir, worlds  # noqa: E402
from fedjax_nav.config import load_config  # noqa: E402
from fedjax_nav.training.hparams import hparams_from_config  # noqa: E402
from fedjax_nav.training.trainer import Trainer  # noqa: E402

SHORT = [
    "env.episode_length=128",
    "offpolicy.batch_size=64",
    "offpolicy.random_steps=64",
    "offpolicy.train_every=4",
    "run.checkpoint_every=0",
    "fed.period=2",
]


def config(robots: int, rounds: int):
    names = [worlds.THESIS_TRAIN[i % len(worlds.THESIS_TRAIN)] for i in range(robots)]
    return load_config("thesis/flddpg", [*SHORT, f"env.worlds=[{','.join(names)}]", f"run.episodes={2 * rounds}"])


def in_program_round_s(cfg, rounds: int) -> float:
    """Median wall time of one round (fed.period episodes and the exchange) of the whole fleet."""
    tr, hp = Trainer(cfg), hparams_from_config(cfg)
    states = tr.init_seeds(jnp.asarray([cfg.run.seed]), hp)
    chunk = tr.compiled_chunk(cfg.fed.period)
    states, _ = jax.block_until_ready(chunk(states, hp, jnp.int32(0)))  # compiles
    times = []
    for r in range(1, rounds):
        start = time.perf_counter()
        states, _ = jax.block_until_ready(chunk(states, hp, jnp.int32(r * cfg.fed.period)))
        times.append(time.perf_counter() - start)
    return float(np.median(times))


def flower_rounds(cfg, folder: Path) -> tuple[pd.DataFrame, dict]:
    from fedjax_nav.fleet.apps import run_simulation

    start = time.perf_counter()
    summary = run_simulation(cfg, folder / "run")
    summary["total_s"] = time.perf_counter() - start
    return pd.read_csv(folder / "run" / rundir.FLEET_ROUNDS), summary


def row(robots: int, rounds: int) -> dict:
    cfg = config(robots, rounds)
    program = in_program_round_s(cfg, rounds)
    with tempfile.TemporaryDirectory() as tmp:
        df, summary = flower_rounds(cfg, Path(tmp))
    steady = df.iloc[1:]
    wall, train = float(steady["wall_s"].median()), float(steady["robot_train_s_max"].median())
    wire = float((steady["bytes_to_robots"] + steady["bytes_params_from_robots"]).median())
    return {
        "robots": robots,
        "in-program round s": program,
        "Flower round s": wall,
        "slowest robot's training s": train,
        "Flower / in-program": wall / program,
        "params bytes on the wire / round": wire,
        "metrics bytes / round": float(steady["bytes_metrics_from_robots"].median()),
        "in-program accounting bytes / round": summary["bytes_per_fed_round"],
        "whole Flower run s": summary["total_s"],
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--robots", default="5,50", help="comma-separated robot counts")
    ap.add_argument("--rounds", type=int, default=4)
    a = ap.parse_args(argv)
    rows = [row(int(r), a.rounds) for r in a.robots.split(",")]
    table = pd.DataFrame(rows)
    print(f"python scripts/bench_fleet.py --robots {a.robots} --rounds {a.rounds}  ({time.strftime('%Y-%m-%d %H:%M')})")
    cells = lambda values: "| " + " | ".join(f"{v:.3g}" if isinstance(v, float) else str(v) for v in values) + " |"
    print(cells(table.columns) + "\n" + cells(["---"] * table.shape[1]))
    print("\n".join(cells(r) for r in table.itertuples(index=False)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
