"""The generalization experiment's report (docs/generalization.md): evaluate every finished point
of the sweep on the thesis arena and the held-out suite, write the tables, the goal check and
the figures into the sweep's folder, and copy the small tables to results/ and the figures to
docs/img/generalization/.

    fedjax-nav sweep generalization --out runs/sweeps/generalization      # train (resumable)
    python scripts/generalization_report.py runs/sweeps/generalization    # report on what has finished
    python scripts/generalization_report.py runs/sweeps/generalization --sweep generalization_levers

After the report it prints the tail of the held-out suite per point (docs/generalization.md, "Tail
metrics"): over all rooms the success, the worst 10 % of rooms, the collision and time-out rates and
the median path-length ratio (columns of <name>.csv; points evaluated before the tail: "-"); then,
with the `stats` extra (rliable), each point's mean, interquartile mean (IQM) and probability of
improvement over the other methods (<name>_iqm.csv; docs/generalization.md).
"""

import argparse
import sys
from pathlib import Path

import pandas as pd

from fedjax_nav.analysis.generalization import ROBUST_NOTE, robust_readable
from fedjax_nav.config.sweepfile import load_sweep
from fedjax_nav.configs import SWEEP_DIR
from fedjax_nav.experiments.generalization import report, report_name
from fedjax_nav.rundir import RunDirError

ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
ap.add_argument("out", help="the sweep's output folder (its points/ are read)")
ap.add_argument(
    "--sweep",
    default=str(SWEEP_DIR / "generalization.yaml"),
    help="the sweep file or shipped name; its name prefixes the report's files",
)
ap.add_argument(
    "--suite",
    default="heldout",
    help="held-out suite (default heldout: 50 rooms per family x 4 goals); another suite's tables are "
    "named after it (<sweep>_dense-heldout.csv) beside the heldout ones",
)
ap.add_argument("--suite-attempts", type=int, default=1, help="attempts per agent, room and goal (default 1)")
ap.add_argument("--attempts", type=int, default=4, help="arena attempts per agent and goal (default 4)")
ap.add_argument("--no-eval", action="store_true", help="tables from what is already evaluated")
ap.add_argument("--results", default="results", help="copy the tables here ('' = no copy)")
ap.add_argument("--figures", default="docs/img/generalization", help="copy the figures here ('' = no copy)")
a = ap.parse_args()
sweep = load_sweep(a.sweep)
try:
    report(
        sweep,
        a.out,
        suite=a.suite,
        suite_attempts=a.suite_attempts,
        arena_attempts=a.attempts,
        evaluate=not a.no_eval,
        copy_tables=a.results or None,
        copy_figures=a.figures or None,
    )
except RunDirError as e:
    print(f"error: {e}", file=sys.stderr)
    sys.exit(2)

table = Path(a.out) / f"{report_name(sweep.name, a.suite)}.csv"
TAIL = {
    "all": "success",
    "all_worst10": "worst 10%",
    "all_collision": "collision",
    "all_timeout": "time-out",
    "all_path_ratio_median": "path ratio",
}
t = pd.read_csv(table) if table.exists() and table.stat().st_size > 1 else pd.DataFrame()
if len(t):
    names = ["label"] if "label" in t and t.duplicated(["method", "rooms", "episodes"]).any() else []
    shown = t.reindex(columns=[*names, "method", "rooms", "episodes", *TAIL]).rename(columns=TAIL)
    print(f"held-out suite {a.suite}, all rooms (the tail):")
    print(shown.to_string(index=False, float_format=lambda x: f"{x:.3f}", na_rep="-"))

iqm = Path(a.out) / f"{report_name(sweep.name, a.suite)}_iqm.csv"
if iqm.exists() and iqm.stat().st_size > 1:
    print(f"\nheld-out suite {a.suite}: {ROBUST_NOTE}")
    print(robust_readable(pd.read_csv(iqm)).to_string(index=False))
