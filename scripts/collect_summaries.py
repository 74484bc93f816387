"""Collect the summary.json of every run under a folder into one small CSV (committed under results/)."""

import json
import sys
from pathlib import Path

import pandas as pd

root, out = Path(sys.argv[1]), Path(sys.argv[2])
rows = []
for p in sorted(root.glob("*/summary.json")):
    s = json.loads(p.read_text())
    rows.append(
        {
            "run": p.parent.name,
            "method": s["method"],
            "seeds": s["seeds"],
            "episodes": s["episodes_done"],
            "success_last25_mean": round(s["success_last"], 4),
            "success_last25_std": round(s["success_last_std"], 4),
            "success_last25_per_seed": " ".join(f"{x:.3f}" for x in s["success_last_per_seed"]),
            "reward_last25_mean": round(s["reward_last"], 4),
            "reward_last25_std": round(s["reward_last_std"], 4),
            "aggregation_events": s["aggregation_events"],
            "n_comm": s["communication"]["n_comm"],
            "wall_s": round(s["wall_s"], 1),
        }
    )
out.parent.mkdir(parents=True, exist_ok=True)
pd.DataFrame(rows).to_csv(out, index=False)
print(pd.DataFrame(rows).to_string(index=False))
print("wrote", out)
