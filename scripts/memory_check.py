"""The memory estimate against the measured peak (docs/reliability.md, "Memory for many
environments"): for every learner and number of environments per robot, a fresh process trains
two episodes of 256 steps (learners/<name>.yaml, procedural rooms, 1 seed) and reports its peak RSS
growth over the RSS before `train` (`resource.getrusage`), beside `training.resources.memory_estimate`.

    python scripts/memory_check.py                              # 5 learners x 64, 1024, 8192 (~40 min on 2 cores)
    python scripts/memory_check.py --learners ppo --envs 64     # one case
    python scripts/memory_check.py --one learners/ppo 64        # (the child process)

Writes results/memory_check.csv (learner, envs, measured and estimated bytes, their ratio, the
estimate's parts); exits 1 when a ratio is below 1 or above 1.5.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
from pathlib import Path

CONFIGS = {
    "ddpg": "learners/ddpg",
    "td3": "learners/td3",
    "sac": "learners/sac",
    "ppo": "learners/ppo",
    "ppo-gru": "learners/ppo-gru",
}
SETS = ["env.episode_length=256", "run.episodes=2", "run.chunk_episodes=2", "run.eval_every=0", "run.seeds=1"]
# GRU-PPO's update at 8,192 environments in 4 minibatches needs ~15 GB (estimate): on a 22 GB
# machine it is measured in 32 minibatches of 256 environments
EXTRA = {("ppo-gru", 8192): ("ppo.minibatches=32",)}


def one(config: str, envs: int, extra=()) -> dict:
    """In this process: train the case and return its measured peak growth and the estimate."""
    from fedjax_nav.config import load_config
    from fedjax_nav.training.resources import memory_estimate
    from fedjax_nav.training.run import train
    from fedjax_nav.training.trainer import Trainer

    cfg = load_config(config, [f"env.envs_per_robot={envs}", *SETS, *extra])
    est = memory_estimate(Trainer(cfg))
    before = int(Path("/proc/self/statm").read_text().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    with tempfile.TemporaryDirectory() as d:
        train(cfg, Path(d) / "run", progress=False)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    return {"measured": peak - before, "estimate": est["total"], "parts": est}


def measure(config: str, envs: int, extra=()) -> dict:
    """`one` in a fresh process (the peak RSS is the process's)."""
    argv = [sys.executable, __file__, "--one", config, str(envs), *extra]
    out = subprocess.run(argv, capture_output=True, text=True, check=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--learners", nargs="+", default=list(CONFIGS))
    ap.add_argument("--envs", nargs="+", type=int, default=[64, 1024, 8192])
    ap.add_argument("--csv", default="results/memory_check.csv")
    ap.add_argument("--one", nargs="+", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.one:
        print(json.dumps(one(a.one[0], int(a.one[1]), a.one[2:])))
        return 0
    import pandas as pd

    rows, bad = [], 0
    for envs in a.envs:
        for name in a.learners:
            extra = EXTRA.get((name, envs), ())
            r = measure(CONFIGS[name], envs, extra)
            ratio = r["estimate"] / r["measured"]
            bad += not 1.0 <= ratio <= 1.5
            rows.append(
                {
                    "learner": name,
                    "extra": " ".join(extra),
                    "envs_per_robot": envs,
                    "measured_bytes": r["measured"],
                    "estimate_bytes": r["estimate"],
                    "ratio": round(ratio, 3),
                    **{f"est_{k}": v for k, v in r["parts"].items() if k != "total"},
                }
            )
            gib = r["measured"] / 2**30, r["estimate"] / 2**30
            print(f"{name:8s} {envs:5d} envs: measured {gib[0]:.2f} GiB, estimate {gib[1]:.2f} GiB, ratio {ratio:.2f}")
            if a.csv:  # after every case: a long check stopped early keeps what it measured
                pd.DataFrame(rows).to_csv(a.csv, index=False)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
