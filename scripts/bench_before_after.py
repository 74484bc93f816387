"""Trainer throughput of two checkouts of fedjax_nav, alternated in one run (the shared machine's
load drifts: alternating pairs is what makes the comparison fair).

    git worktree add /tmp/before <commit>
    python scripts/bench_before_after.py --before /tmp/before --after . --repeat 3 [--episodes 5]

Each measurement is a fresh process importing that checkout (PYTHONPATH), timing
`bench_train(seeds=(1,), episodes=E)`: one thesis-scale FLDDPG seed, a steady chunk of E episodes
after compilation. Prints one line per run and the median ratio after/before.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys

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


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--before", required=True)
    ap.add_argument("--after", required=True)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--episodes", type=int, default=5, help="a divisor of 125 (the chunk of the thesis preset)")
    ap.add_argument("--set", action="append", default=[], help="config override for both")
    args = ap.parse_args()
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
