"""Training speed on 1 vs several devices (docs/scaling.md): the same config, no mesh against a
mesh of N devices with the clients or the seeds sharded.

    python scripts/scaling.py --config configs/thesis/flddpg.yaml \
        --set "env.worlds=[train-0,train-2,train-3,train-4]" --seeds 2 --episodes 5 \
        --cases 1 2:clients 2:seeds --rounds 2

Each case runs in its own subprocess (on CPU, N forced host devices must be set before jax
starts); cases alternate for `--rounds` rounds, so that a shared machine's load falls on all of
them alike. Per case: compile + first episode, then the best and the median of the following
one-episode chunks (blocked one by one), as agent-steps/s (robots x seeds x steps / s).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time


def measure(config: str, overrides: list[str], devices: int, shard: str, episodes: int) -> dict:
    """Runs in the subprocess."""
    import jax
    import jax.numpy as jnp

    from fedjax_nav.config import load_config
    from fedjax_nav.training import parallel
    from fedjax_nav.training.hparams import hparams_from_config
    from fedjax_nav.training.trainer import Trainer

    cfg = load_config(
        config, overrides + ["run.chunk_episodes=1", "run.checkpoint_every=0", f"run.episodes={episodes}"]
    )
    tr, hp = Trainer(cfg), hparams_from_config(cfg)
    mesh = parallel.make_mesh(devices, shard) if devices > 1 else None
    t = time.perf_counter()
    states = tr.init_seeds(jnp.arange(cfg.run.seeds), hp, mesh=mesh)
    chunk = tr.compiled_chunk(mesh=mesh, states=states, hp=hp)
    times = []
    for e in range(episodes):
        states, m = chunk(states, hp, jnp.int32(e))
        jax.block_until_ready((states, m))
        times.append(time.perf_counter() - t)
        t = time.perf_counter()
    steps = cfg.num_robots * cfg.run.seeds * cfg.env.episode_length
    rest = times[1:]
    return {
        "case": f"{devices}:{shard}" if mesh else "1",
        "first_s": times[0],
        "best_s": min(rest),
        "median_s": statistics.median(rest),
        "best_steps_per_s": steps / min(rest),
        "median_steps_per_s": steps / statistics.median(rest),
        "backend": jax.default_backend(),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", required=True)
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--seeds", type=int, default=1)
    ap.add_argument("--episodes", type=int, default=5, help="per case; the first one includes compilation")
    ap.add_argument("--cases", nargs="+", default=["1", "2:clients"], help="N or N:clients|seeds")
    ap.add_argument("--rounds", type=int, default=1)
    ap.add_argument("--worker", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    overrides = args.set + [f"run.seeds={args.seeds}"]
    if args.worker:
        n, _, shard = args.worker.partition(":")
        print("RESULT " + json.dumps(measure(args.config, overrides, int(n), shard or "clients", args.episodes)))
        return 0
    rows = []
    for _ in range(args.rounds):
        for case in args.cases:
            n = int(case.partition(":")[0])
            env = dict(os.environ, XLA_FLAGS=f"--xla_force_host_platform_device_count={n}")
            cmd = [
                sys.executable,
                __file__,
                "--config",
                args.config,
                "--seeds",
                str(args.seeds),
                "--episodes",
                str(args.episodes),
                "--worker",
                case,
                *sum((["--set", s] for s in args.set), []),
            ]
            res = subprocess.run(cmd, env=env, capture_output=True, text=True)
            if res.returncode:
                print(res.stderr[-2000:], file=sys.stderr)
                return res.returncode
            row = json.loads([x for x in res.stdout.splitlines() if x.startswith("RESULT ")][-1][7:])
            row["load"] = os.getloadavg()[0]
            rows.append(row)
            print(
                f"| {row['case']} | {row['first_s']:.1f} | {row['best_s']:.2f} | {row['median_s']:.2f} | "
                f"{row['best_steps_per_s']:,.0f} | {row['median_steps_per_s']:,.0f} | {row['load']:.1f} |",
                flush=True,
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
