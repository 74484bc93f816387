"""Copy the small tables of a reproduce report folder to results/ (committed), so that the numbers
survive a new machine: results/reproduction_<experiment>.csv (by_setting: last-25 success and reward
per setting, mean and std over seed runs, with the thesis's numbers), results/reproduction_eval.csv
and results/reproduction_table3.csv.

    python scripts/collect_reproduction.py runs/reproduce-thesis results
"""

import json
import shutil
import sys
from pathlib import Path

report, out = Path(sys.argv[1]), Path(sys.argv[2])
out.mkdir(parents=True, exist_ok=True)
info = json.loads((report / "reproduce.json").read_text())
written = []
for name in info["experiments"]:
    src = report / "experiments" / name / "by_setting.csv"
    if src.exists() and src.stat().st_size > 1:
        written.append(shutil.copyfile(src, out / f"reproduction_{name}.csv"))
for src, dst in (
    ("eval_summary.csv", "reproduction_eval.csv"),
    ("table3_communication.csv", "reproduction_table3.csv"),
):
    if (report / src).exists() and (report / src).stat().st_size > 1:
        written.append(shutil.copyfile(report / src, out / dst))
print("wrote", ", ".join(str(p) for p in written))
