"""The robustness experiment's report (docs/robustness.md): evaluate every finished point of the
sweep on the thesis arena, write the tables, the acceptance verdict and the figures into the
sweep's folder, and copy the small tables to results/ and the figures to docs/img/robustness/.

    fedjax-nav sweep robustness --out runs/sweeps/robustness     # train (resumable)
    python scripts/robustness_report.py runs/sweeps/robustness   # report on what has finished
"""

import argparse

from fedjax_nav.config.sweepfile import load_sweep
from fedjax_nav.configs import SWEEP_DIR
from fedjax_nav.experiments.robustness import report

ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
ap.add_argument("out", help="the sweep's output folder (its points/ are read)")
ap.add_argument("--sweep", default=str(SWEEP_DIR / "robustness.yaml"), help="the sweep file (default robustness)")
ap.add_argument("--attempts", type=int, default=4, help="evaluation attempts per agent and goal (default 4)")
ap.add_argument("--no-eval", action="store_true", help="tables from learning metrics only")
ap.add_argument("--results", default="results", help="copy the tables here ('' = no copy)")
ap.add_argument("--figures", default="docs/img/robustness", help="copy the figures here ('' = no copy)")
a = ap.parse_args()
report(
    load_sweep(a.sweep),
    a.out,
    attempts=a.attempts,
    evaluate=not a.no_eval,
    copy_tables=a.results or None,
    copy_figures=a.figures or None,
)
