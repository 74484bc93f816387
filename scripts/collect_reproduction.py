"""Copy the small tables of a reproduce report folder to results/ (committed), so that the numbers
survive a new machine: results/reproduction_<experiment>.csv (by_setting: last-25 success and reward
per setting, mean and std over seed runs, with the thesis's numbers),
results/reproduction_<experiment>_per_seed.csv (the same two numbers for every seed run),
results/reproduction_eval.csv and results/reproduction_table3.csv.

    python scripts/collect_reproduction.py runs/reproduce-thesis results
"""

import shutil
import sys
from pathlib import Path

import pandas as pd

LAST = 25  # episodes: the thesis's "last 25 episodes"


def per_seed(results: Path) -> pd.DataFrame:
    """Per setting and seed: success (robots that reached the goal, per episode) and reward per
    step, averaged over the last LAST episodes: the numbers the by_setting means are taken over."""
    df = pd.read_csv(results)
    keys = [c for c in df.columns[: df.columns.get_loc("episode")] if c not in ("point", "method")]
    last = df[df.episode >= df.episode.max() + 1 - LAST]
    ep = last.groupby(["label", *[k for k in keys if k != "label"], "seed", "episode"], dropna=False)
    ep = ep.agg(success=("reached_goal", "mean"), reward=("reward", "mean")).reset_index()
    out = ep.groupby(["label", "seed"], dropna=False)[["success", "reward"]].mean().reset_index()
    return out.round(4)


report, out = Path(sys.argv[1]), Path(sys.argv[2])
out.mkdir(parents=True, exist_ok=True)
written = []
# every experiment in the folder, not only those of its last `reproduce` call (reproduce.json)
for name in sorted(p.name for p in (report / "experiments").iterdir() if p.is_dir()):
    src = report / "experiments" / name / "by_setting.csv"
    if src.exists() and src.stat().st_size > 1:
        written.append(shutil.copyfile(src, out / f"reproduction_{name}.csv"))
        results = report / "experiments" / name / "results.csv"
        if results.exists():
            dst = out / f"reproduction_{name}_per_seed.csv"
            per_seed(results).to_csv(dst, index=False)
            written.append(dst)
for src, dst in (
    ("eval_summary.csv", "reproduction_eval.csv"),
    ("table3_communication.csv", "reproduction_table3.csv"),
):
    if (report / src).exists() and (report / src).stat().st_size > 1:
        written.append(shutil.copyfile(report / src, out / dst))
print("wrote", ", ".join(str(p) for p in written))
