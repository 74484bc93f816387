"""Where a training chunk's time goes: an XLA CPU profile of one steady chunk, summed by thunk.

    python scripts/profile_chunk.py [--config thesis/flddpg] [--episodes 5] [--set K=V ...] [--top 30]

Compiles the config's chunk (one seed), runs it once, then traces the next chunk with
`jax.profiler` and prints, for every thunk name (numbered instances merged, e.g. all `dot.N`),
its total time and call count over the XLA worker threads, and the threads' busy time against
the wall time. Two checkouts are compared by running it in each (docs/benchmarks.md, "The
redesign's speed").
"""

from __future__ import annotations

import argparse
import collections
import glob
import re
import tempfile
import time

import jax
import jax.numpy as jnp


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--config", default="thesis/flddpg")
    ap.add_argument("--episodes", type=int, default=5, help="a divisor of run.episodes")
    ap.add_argument("--set", action="append", default=[])
    ap.add_argument("--top", type=int, default=30)
    args = ap.parse_args()
    from jax.profiler import ProfileData

    from fedjax_nav.config import load_config
    from fedjax_nav.training.hparams import hparams_from_config
    from fedjax_nav.training.trainer import Trainer

    cfg = load_config(args.config, [f"run.chunk_episodes={args.episodes}", "run.checkpoint_every=0", *args.set])
    hp = hparams_from_config(cfg)
    tr = Trainer(cfg)
    states = tr.init_seeds(jnp.arange(1), hp)
    f = tr.compiled_chunk()
    states, m = f(states, hp, jnp.int32(0))
    jax.block_until_ready(m)
    with tempfile.TemporaryDirectory() as d:
        jax.profiler.start_trace(d)
        t = time.perf_counter()
        states, m = f(states, hp, jnp.int32(args.episodes))
        jax.block_until_ready(m)
        wall = time.perf_counter() - t
        jax.profiler.stop_trace()
        data = ProfileData.from_file(glob.glob(f"{d}/**/*.xplane.pb", recursive=True)[0])
        total, count, threads = collections.Counter(), collections.Counter(), set()
        for plane in data.planes:
            for line in plane.lines:
                if not line.name.startswith("tf_XLAEigen"):  # the XLA CPU worker threads
                    continue
                threads.add(line.name)
                for ev in line.events:
                    name = re.sub(r"\.\d+$", "", ev.name)
                    total[name] += ev.duration_ns
                    count[name] += 1
    busy = total.pop("ThunkExecutor::Execute", 0) / 1e9
    calls = count.pop("ThunkExecutor::Execute", 0)
    print(f"{args.episodes} episode(s): wall {wall:.2f} s (under the profiler); {len(threads)} worker thread(s)")
    share = busy / max(wall * len(threads), 1e-9)
    print(f"thunk-executor calls {calls:,}, busy {busy:.2f} s = {share:.0%} of threads x wall")
    print(f"{'thunk':44s} {'ms':>9s} {'calls':>8s}")
    for name, ns in total.most_common(args.top):
        print(f"{name[:44]:44s} {ns / 1e6:9.1f} {count[name]:8d}")


if __name__ == "__main__":
    main()
