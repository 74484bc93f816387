"""The scripted follower (fedjax_nav.evaluation.baselines) on a suite, through the learned
policies' protocol (docs/planning.md, "A scripted follower"): what the plan's waypoint alone is
worth, with no network. The env (rooms, plan, robot model) is a run's or a config's, with --set
overrides; the evaluation is written as `fedjax-nav evaluate --suite` writes it (suite.json,
suite_families.csv, suite_episodes.csv), so scripts/suite_table.py sets it beside the runs'.

    python scripts/follower_suite.py runs/x/points/<id> --suite dense-heldout --attempts 1 --out runs/x/follower-dense
    python scripts/follower_suite.py configs/learners/ppo.yaml --set env.plan=true --suite heldout --out runs/x/f
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("source", help="a run directory (its config.yaml) or a config file")
    ap.add_argument("--set", action="append", default=[], help="config overrides, as `fedjax-nav train --set`")
    ap.add_argument("--suite", default="dense-heldout")
    ap.add_argument("--attempts", type=int, default=1)
    ap.add_argument("--out", required=True, help="the evaluation's folder (refused when it holds one)")
    a = ap.parse_args(argv)

    from fedjax_nav.config import ConfigError, load_config
    from fedjax_nav.evaluation.baselines import follower_run
    from fedjax_nav.evaluation.limits import EvalError
    from fedjax_nav.evaluation.suite import SUITE_JSON, evaluate_suite, write_suite

    src = Path(a.source)
    out = Path(a.out)
    if (out / SUITE_JSON).exists():
        print(f"error: {out / SUITE_JSON} exists: choose another --out", file=sys.stderr)
        return 2
    try:
        cfg = load_config(src / "config.yaml" if src.is_dir() else src, a.set)
        res = evaluate_suite(follower_run(cfg, out), a.suite, attempts=a.attempts)
    except (ConfigError, EvalError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    fams = res["families"]
    print(fams[["family", "rooms", "success", "worst10", "collision", "timeout"]].to_string(index=False))
    print("wrote " + ", ".join(str(p) for p in write_suite(res, out)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
