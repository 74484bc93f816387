"""Where a training chunk's time goes: an XLA CPU profile of one steady chunk, summed by thunk
and, with `--parts`, by part of the program.

    python scripts/profile_chunk.py [--config thesis/flddpg] [--episodes 5] [--set K=V ...] [--top 30]
    python scripts/profile_chunk.py --config learners/ppo --episodes 1 --parts \
        --set env.envs_per_robot=256 --set method=snddpg        # PPO: docs/benchmarks.md

Compiles the config's chunk (one seed), runs it once, then traces the next chunk with
`jax.profiler` and prints, for every thunk name (numbered instances merged, e.g. all `dot.N`),
its total time and call count over the XLA worker threads, and the threads' busy time against
the wall time. Two checkouts are compared by running it in each (docs/benchmarks.md, "The
redesign's speed").

`--parts` attributes every thunk to a part by the shape it writes (read from the compiled HLO):
a shape holding the rows of one update's minibatch, of a whole rollout, or of one step's
environments names its part; a sort is the minibatch permutation; matmuls (`dot`, `ynn_fusion`)
writing none of those rows are the weight gradients (a sum over the minibatch's rows). A row count
equal to a layer's width (256 environments per robot and 256-wide layers) would be ambiguous:
profile such a config with another count. For PPO it
also times the minibatch gradient alone (`jax.grad` of the loss on one minibatch, the learner's own
function) times the update's epochs x minibatches x networks: what the update costs with nothing
else, the floor a faster program of the same algorithm can approach.
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

MATMULS = ("dot", "ynn_fusion", "xnn_fusion")


def thunk_times(d: str):
    """{thunk instance: ns} over the XLA CPU worker threads of the trace in `d`, and the threads."""
    from jax.profiler import ProfileData

    data = ProfileData.from_file(glob.glob(f"{d}/**/*.xplane.pb", recursive=True)[0])
    total, count, threads = collections.Counter(), collections.Counter(), set()
    for plane in data.planes:
        for line in plane.lines:
            if not line.name.startswith("tf_XLAEigen"):  # the XLA CPU worker threads
                continue
            threads.add(line.name)
            for ev in line.events:
                total[ev.name] += ev.duration_ns
                count[ev.name] += 1
    return total, count, threads


def output_shapes(hlo: str) -> dict[str, str]:
    """{instruction name: the shape it writes} of a compiled module's text."""
    line = re.compile(r"^\s*(?:ROOT )?%?([\w.\-]+) = (\([^=]*?\)|\S+) ", re.M)
    return {m.group(1): m.group(2) for m in line.finditer(hlo)}


def row_parts(tr) -> dict[int, str]:
    """{row count: part} of the program of Trainer `tr` (the rows of one step, and of a PPO
    update's rollout and minibatch)."""
    from fedjax_nav.config import get

    parts = {tr.num_envs: "rollout: env step, acting, storing (every environment)"}
    parts.setdefault(tr.envs_per_robot, parts[tr.num_envs])
    if tr.learner.on_policy:
        rollout = get(tr.cfg, "ppo.rollout") * tr.writes
        parts[rollout] = "update: value pass and GAE over the rollout"
        parts[rollout // get(tr.cfg, "ppo.minibatches")] = "update: minibatch"
    else:
        parts[get(tr.cfg, "offpolicy.batch_size")] = "update: minibatch"
    return parts


def part_of(name: str, shape: str, parts: dict[int, str]) -> str:
    kind = re.sub(r"\.\d+$", "", name)
    if kind.startswith("sort"):
        return "update: minibatch permutation (sort)"
    dims = {int(x) for x in re.findall(r"\d+", re.sub(r"\{[^}]*\}", "", shape))}
    matmul = kind in MATMULS
    for rows, part in parts.items():
        if rows in dims:
            if part == "update: minibatch":
                return part + (" matmuls (forward, backward)" if matmul else ", elementwise (loss, tanh, gather)")
            return part
    return "update: weight gradients (matmuls summing the rows)" if matmul else "other (scalars, Adam, small ops)"


def minibatch_floor(tr, hp, repeat: int = 5) -> float:
    """Seconds of one PPO update's minibatch gradients alone: jax.grad of the learner's loss on
    one minibatch (random rows), best of `repeat`, times epochs x minibatches x networks."""
    from fedjax_nav.agents import ppo
    from fedjax_nav.config import get

    nets = tr.nets.ppo
    rows = get(tr.cfg, "ppo.rollout") * tr.writes // nets.minibatches
    state = tr.learner.init(tr.nets, jax.random.key(0), tr.obs_size, hp)
    k = jax.random.split(jax.random.key(1), 6)
    mb = {
        "obs": jax.random.normal(k[0], (rows, tr.obs_size)),
        "raw_action": jax.random.normal(k[1], (rows, nets.action_size)),
        "log_prob": jax.random.normal(k[2], (rows,)),
        "adv": jax.random.normal(k[3], (rows,)),
        "return": jax.random.normal(k[4], (rows,)),
        "value": jax.random.normal(k[5], (rows,)),
    }
    params = (ppo.weights(state.actor), state.log_std, state.value)
    grad = jax.jit(lambda p, b, key: jax.grad(ppo._minibatch_loss, has_aux=True)(p, nets, b, key, hp))
    jax.block_until_ready(grad(params, mb, k[0]))
    best = float("inf")
    for _ in range(repeat):
        t = time.perf_counter()
        jax.block_until_ready(grad(params, mb, k[0]))
        best = min(best, time.perf_counter() - t)
    return best * nets.epochs * nets.minibatches * tr.n_nets


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--config", default="thesis/flddpg")
    ap.add_argument("--episodes", type=int, default=5, help="a divisor of run.episodes")
    ap.add_argument("--set", action="append", default=[])
    ap.add_argument("--top", type=int, default=30)
    ap.add_argument("--parts", action="store_true", help="attribute the time to parts of the program")
    args = ap.parse_args()

    from fedjax_nav.config import get, load_config
    from fedjax_nav.experiments.bench import warm_chunk

    cfg = load_config(args.config, [f"run.chunk_episodes={args.episodes}", "run.checkpoint_every=0", *args.set])
    tr, hp, f, states = warm_chunk(cfg)
    t = time.perf_counter()
    states, m = f(states, hp, jnp.int32(args.episodes))
    jax.block_until_ready(m)
    steady = time.perf_counter() - t
    with tempfile.TemporaryDirectory() as d:
        jax.profiler.start_trace(d)
        t = time.perf_counter()
        states, m = f(states, hp, jnp.int32(2 * args.episodes))
        jax.block_until_ready(m)
        wall = time.perf_counter() - t
        jax.profiler.stop_trace()
        total, count, threads = thunk_times(d)
    busy = total.pop("ThunkExecutor::Execute", 0) / 1e9
    calls = count.pop("ThunkExecutor::Execute", 0)
    steps = tr.num_envs * tr.T * args.episodes
    print(f"{args.episodes} episode(s): {steady:.2f} s steady ({steps / steady:,.0f} agent-steps/s)")
    share = busy / max(wall * len(threads), 1e-9)
    print(
        f"traced {wall:.2f} s; {len(threads)} worker thread(s), thunk-executor calls {calls:,}, "
        f"busy {busy:.2f} s = {share:.0%} of threads x wall"
    )
    if args.parts:
        shapes = output_shapes(f.lower(states, hp, jnp.int32(0)).compile().as_text())
        parts, by_part = row_parts(tr), collections.Counter()
        for name, ns in total.items():
            by_part[part_of(name, shapes.get(name, ""), parts)] += ns
        ops = sum(by_part.values())
        print("\n| part | thread-s per episode | share of op time |\n|---|---|---|")
        for part, ns in by_part.most_common():
            print(f"| {part} | {ns / 1e9 / args.episodes:.2f} | {ns / ops:.0%} |")
        if tr.learner.on_policy:
            floor = minibatch_floor(tr, hp) * (tr.T // get(cfg, "ppo.rollout")) * args.episodes
            print(
                f"\nminibatch gradients alone: {floor / args.episodes:.2f} s per episode "
                f"= {steps / floor:,.0f} agent-steps/s if nothing else ran (the chunk: {steps / steady:,.0f})"
            )
        return
    merged, merged_count = collections.Counter(), collections.Counter()
    for name, ns in total.items():
        merged[re.sub(r"\.\d+$", "", name)] += ns
        merged_count[re.sub(r"\.\d+$", "", name)] += count[name]
    print(f"{'thunk':44s} {'ms':>9s} {'calls':>8s}")
    for name, ns in merged.most_common(args.top):
        print(f"{name[:44]:44s} {ns / 1e6:9.1f} {merged_count[name]:8d}")


if __name__ == "__main__":
    main()
