"""Throughput of a procedural-rooms training run against the fixed-room trainer, back to back
(docs/generalization.md): both programs compiled first, then timed chunks alternating
fixed, procedural, fixed, procedural, ... so that both see the same machine load.

    python scripts/bench_rooms.py [--config generalization/flddpg] [--rounds 3] [--episodes 5]
"""

from __future__ import annotations

import argparse
import time

import jax
import jax.numpy as jnp
import numpy as np

from fedjax_nav.config import load_config
from fedjax_nav.training.hparams import hparams_from_config
from fedjax_nav.training.trainer import Trainer


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--method", default="flddpg")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--episodes", type=int, default=5, help="episodes per timed chunk")
    ap.add_argument("--eval-every", type=int, default=0)
    args = ap.parse_args()
    extra = [
        f"run.chunk_episodes={args.episodes}",
        f"run.episodes={args.episodes}",
        "run.checkpoint_every=0",
        f"run.eval_every={args.eval_every}",
    ]
    setups = {}
    for name in ("thesis", "procedural"):
        cfg = load_config(f"generalization/{args.method}-{name}", extra)
        tr = Trainer(cfg)
        hp = hparams_from_config(cfg)
        t0 = time.time()
        st = tr.init_seeds(jnp.arange(1), hp)
        fn = tr.compiled_chunk()
        st, m = fn(st, hp, jnp.int32(0))
        jax.block_until_ready(m)
        setups[name] = [tr, hp, st, fn, time.time() - t0]
        print(f"{name}: init + compile + first chunk {setups[name][4]:.1f} s", flush=True)
    times = {k: [] for k in setups}
    for r in range(args.rounds):
        for name, s in setups.items():
            tr, hp, st, fn, _ = s
            t0 = time.time()
            st, m = fn(st, hp, jnp.int32((r + 1) * args.episodes))
            jax.block_until_ready(m)
            times[name].append(time.time() - t0)
            s[2] = st
            print(f"round {r} {name}: {times[name][-1]:.2f} s", flush=True)
    steps = args.episodes * setups["thesis"][0].T * setups["thesis"][0].num_robots
    for name, ts in times.items():
        ts = np.asarray(ts)
        print(
            f"{name}: {steps / ts.mean():,.0f} agent-steps/s (mean of {len(ts)} chunks of {args.episodes} episodes, "
            f"{ts.mean():.2f} +- {ts.std():.2f} s per chunk)"
        )
    print(f"procedural / fixed time per chunk: {np.mean(times['procedural']) / np.mean(times['thesis']):.3f}")


if __name__ == "__main__":
    main()
