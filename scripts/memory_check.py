"""The memory estimate against the measured peak (docs/reliability.md, "Memory for many
environments"): for every learner and number of environments per robot, a fresh process trains
two episodes of 256 steps (learners/<name>.yaml, procedural rooms, 1 seed) and reports its peak RSS
growth over the RSS before `train` (VmHWM, /proc/self/status), beside `training.resources.memory_estimate`.

    python scripts/memory_check.py                              # 5 learners x 64, 1024, 8192 (~40 min on 2 cores)
    python scripts/memory_check.py --learners ppo --envs 64     # one case
    python scripts/memory_check.py --one learners/ppo 64        # (the child process)
    python scripts/memory_check.py --reestimate                 # the table's measured peaks against today's estimate

Writes results/memory_check.csv (learner, envs, measured and estimated bytes, their ratio, the
estimate's parts); exits 1 when a ratio is below 1 or above 1.5.
"""

from __future__ import annotations

import argparse
import json
import os
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
# GRU-PPO at 8,192 environments: measured in 32 minibatches of 256 environments, as the table has
# always been (it peaks at 14.5 GiB; XLA's temporaries of the update are the same in 4 minibatches)
EXTRA = {("ppo-gru", 8192): ("ppo.minibatches=32",)}


def peak_rss() -> int:
    """This process's peak RSS in bytes: VmHWM, the high-water mark of its own address space.
    Not `getrusage`'s ru_maxrss: Linux carries that across exec, so a child spawned by a big
    process (a pytest worker) reports its parent's peak."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) * 1024
    raise RuntimeError("/proc/self/status has no VmHWM line: the peak RSS is measured on Linux only")


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
    return {"measured": peak_rss() - before, "estimate": est["total"], "parts": est}


def estimate(config: str, envs: int, extra=()) -> dict:
    from fedjax_nav.config import load_config
    from fedjax_nav.training.resources import memory_estimate
    from fedjax_nav.training.trainer import Trainer

    return memory_estimate(Trainer(load_config(config, [f"env.envs_per_robot={envs}", *SETS, *extra])))


def reestimate(csv: str) -> int:
    """The table's measured peaks (the runs do not depend on the estimate) against the estimate of
    this code: after a change of the estimate's parts, without training again."""
    import pandas as pd

    df = pd.read_csv(csv, keep_default_na=False)
    for i, r in df.iterrows():
        est = estimate(CONFIGS[r["learner"]], int(r["envs_per_robot"]), str(r["extra"]).split())
        df.loc[i, "estimate_bytes"] = est["total"]
        df.loc[i, "ratio"] = round(est["total"] / r["measured_bytes"], 3)
        for k, v in est.items():
            if k != "total":
                df.loc[i, f"est_{k}"] = v
    df.to_csv(csv, index=False)
    print(
        df[["learner", "envs_per_robot", "extra", "measured_bytes", "estimate_bytes", "ratio"]].to_string(index=False)
    )
    return int(((df["ratio"] < 1) | (df["ratio"] > 1.5)).any())


def measure(config: str, envs: int, extra=()) -> dict:
    """`one` in a fresh process (the peak RSS is the process's), compiling as a first run does:
    without a persistent compilation cache (a cached program skips the compiler's share, which
    the estimate counts: a test suite's cache made a 1.62 GiB run peak at 1.07 GiB)."""
    argv = [sys.executable, __file__, "--one", config, str(envs), *extra]
    env = {k: v for k, v in os.environ.items() if not k.startswith(("JAX_COMPILATION_CACHE", "JAX_PERSISTENT_CACHE"))}
    done = subprocess.run(argv, capture_output=True, text=True, env=env)
    if done.returncode:
        raise RuntimeError(f"{' '.join(argv[1:])} exited {done.returncode}: {done.stderr.strip()[-2000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--learners", nargs="+", default=list(CONFIGS))
    ap.add_argument("--envs", nargs="+", type=int, default=[64, 1024, 8192])
    ap.add_argument("--csv", default="results/memory_check.csv")
    ap.add_argument("--one", nargs="+", help=argparse.SUPPRESS)
    ap.add_argument("--reestimate", action="store_true", help="keep the CSV's measured peaks, recompute the estimate")
    a = ap.parse_args()
    if a.one:
        print(json.dumps(one(a.one[0], int(a.one[1]), a.one[2:])))
        return 0
    import pandas as pd

    if a.reestimate:
        return reestimate(a.csv)
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
