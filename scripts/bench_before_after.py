"""Trainer throughput of two checkouts of fedjax_nav, compared in one run (the shared machine's
load drifts: alternating is what makes the comparison fair).

    git worktree add /tmp/before <commit>
    python scripts/bench_before_after.py --before /tmp/before --after . --repeat 3 [--episodes 5]
    python scripts/bench_before_after.py --before /tmp/before --after . --in-process --repeat 12

Default: each measurement is a fresh process importing that checkout (PYTHONPATH), timing
`bench_train(seeds=(1,), episodes=E)`: one thesis-scale FLDDPG seed, a steady chunk of E episodes
after compilation. `--in-process`: the before checkout's package is copied under the name
`fedjax_nav_before` (its imports rewritten), both trainers are compiled in one process and their
chunks alternate, so both see the same threads, allocator and load (twice: the build order
swapped in the second process, `--repeat` split between them);
fresh processes differed by several percent from run to run here (docs/benchmarks.md, "The
redesign's speed"). Prints one line per run and the median ratio after/before.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import statistics
import subprocess
import sys
import tempfile

CODE = """
import json, os, sys
if os.path.isdir("fedjax_nav/experiments"):
    from fedjax_nav.experiments import bench
else:  # checkouts before the redesign
    from fedjax_nav import bench
assert os.path.abspath(bench.__file__).startswith(os.getcwd()), bench.__file__  # this checkout, not another
row = bench.bench_train(seeds=(1,), episodes={episodes}, overrides={overrides!r})[0]
print("RESULT " + json.dumps(row))
"""

IN_PROCESS = """
import json, sys, time
sys.path[:0] = [{before_root!r}, {after!r}]
import jax, jax.numpy as jnp

def build(pkg):
    config = __import__(pkg + ".config", fromlist=["load_config"])
    trainer = __import__(pkg + ".training.trainer", fromlist=["Trainer"])
    try:
        hparams = __import__(pkg + ".training.hparams", fromlist=["hparams_from_config"])
    except ImportError:  # before the redesign
        hparams = trainer
    cfg = config.load_config({config!r}, ["run.chunk_episodes={episodes}", "run.checkpoint_every=0", *{overrides!r}])
    hp = hparams.hparams_from_config(cfg)
    tr = trainer.Trainer(cfg)
    st = tr.init_seeds(jnp.arange(1), hp)
    f = tr.compiled_chunk()
    st, m = f(st, hp, jnp.int32(0))
    jax.block_until_ready(m)
    return [f, st, hp, {episodes}]

runs = {{name: build(pkg) for name, pkg in {order!r}}}
for i in range({repeat}):
    for name in (("after", "before") if i % 2 else ("before", "after")):
        f, st, hp, ep = runs[name]
        t = time.perf_counter()
        st, m = f(st, hp, jnp.int32(ep))
        jax.block_until_ready(m)
        runs[name] = [f, st, hp, ep + {episodes}]
        row = {{"run": i + 1, "name": name, "episode_s": (time.perf_counter() - t) / {episodes}}}
        print("RESULT " + json.dumps(row), flush=True)
"""


def measure(checkout: str, episodes: int, overrides: list[str]) -> dict:
    env = {**os.environ, "PYTHONPATH": os.path.abspath(checkout), "JAX_PLATFORMS": "cpu"}
    r = subprocess.run(
        [sys.executable, "-c", CODE.format(episodes=episodes, overrides=overrides)],
        cwd=checkout,
        env=env,
        capture_output=True,
        text=True,
        timeout=1800,
    )
    if r.returncode:
        raise SystemExit(f"{checkout}: failed\n{r.stderr[-2000:]}")
    return json.loads(next(x for x in r.stdout.splitlines() if x.startswith("RESULT "))[7:])


def renamed_copy(checkout: str, root: str) -> None:
    """The checkout's package as `fedjax_nav_before` under root, every import of it rewritten."""
    dst = os.path.join(root, "fedjax_nav_before")
    shutil.copytree(os.path.join(checkout, "fedjax_nav"), dst, ignore=shutil.ignore_patterns("__pycache__"))
    for d, _, files in os.walk(dst):
        for f in files:
            if f.endswith(".py"):
                p = os.path.join(d, f)
                with open(p) as fh:
                    text = fh.read()
                with open(p, "w") as fh:
                    fh.write(re.sub(r"\bfedjax_nav\b", "fedjax_nav_before", text))


def in_process(args) -> dict[str, list[float]]:
    """Two processes, the build order swapped between them: the program compiled (and allocated)
    first ran 1-2% faster here, whichever it was."""
    times = {"before": [], "after": []}
    pkgs = {"before": "fedjax_nav_before", "after": "fedjax_nav"}
    with tempfile.TemporaryDirectory() as root:
        renamed_copy(args.before, root)
        after = os.path.abspath(args.after)
        config = os.path.join(after, "configs/thesis/flddpg.yaml")
        env = {**os.environ, "JAX_PLATFORMS": "cpu"}
        env.pop("PYTHONPATH", None)
        for first in ("before", "after"):
            order = [(n, pkgs[n]) for n in (first, "after" if first == "before" else "before")]
            code = IN_PROCESS.format(
                before_root=root,
                after=after,
                config=config,
                episodes=args.episodes,
                overrides=args.set,
                repeat=max(1, args.repeat // 2),
                order=order,
            )
            p = subprocess.Popen([sys.executable, "-c", code], cwd=root, env=env, stdout=subprocess.PIPE, text=True)
            for line in p.stdout:
                if line.startswith("RESULT "):
                    row = json.loads(line[7:])
                    times[row["name"]].append(row["episode_s"])
                    print(
                        f"{first} built first, run {row['run']} {row['name']:6s}: {row['episode_s']:.3f} s per episode",
                        flush=True,
                    )
            if p.wait():
                raise SystemExit(f"in-process comparison failed (exit {p.returncode})")
    return times


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--before", required=True)
    ap.add_argument("--after", required=True)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--episodes", type=int, default=5, help="a divisor of 125 (the chunk of the thesis preset)")
    ap.add_argument("--set", action="append", default=[], help="config override for both")
    ap.add_argument("--in-process", action="store_true", help="both trainers in one process, chunks alternated")
    args = ap.parse_args()
    if args.in_process:
        times = in_process(args)
    else:
        times = {"before": [], "after": []}
        for i in range(args.repeat):
            for name in ("before", "after"):
                row = measure(getattr(args, name), args.episodes, args.set)
                times[name].append(row["episode_s"])
                print(
                    f"run {i + 1} {name:6s}: {row['episode_s']:.3f} s per episode, "
                    f"{row['agent_updates_per_s']:,.0f} agent-updates/s, compile {row['compile_s']:.1f} s",
                    flush=True,
                )
    b, a = statistics.median(times["before"]), statistics.median(times["after"])
    print(f"median episode: before {b:.3f} s, after {a:.3f} s; after/before = {a / b:.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
