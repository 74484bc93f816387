"""A suite evaluation under changed env values (docs/planning.md, "The margin, and a scripted
follower"): a run's own agents with traced env values overridden (e.g. the plan's margin and
lookahead of a run trained without them; and the plan's grid, `env.plan_cells`), or, with
--follower, the scripted follower (fedjax_nav.evaluation.baselines) in the env of a run or a
config, through the learned policies' protocol. Written as `fedjax-nav evaluate --suite` writes
it (suite.json, suite_families.csv, suite_episodes.csv), so scripts/suite_table.py sets it beside
the runs'. With --robots-per-room K,..: K robots per room (docs/shared_rooms.md, "Evaluation"),
written as `fedjax-nav evaluate --robots-per-room` writes it (shared.json, shared_families.csv,
shared_episodes.csv, and the fleet's trajectories in the first room, shared_trajectories.png); with
--world in place of --suite, in that world, robot i from its start i to its goal i.

    python scripts/suite_with.py RUN --set env.plan_margin=0.3 --set env.plan_lookahead=0.5 --suite maze-50 --out x/m03
    python scripts/suite_with.py RUN --follower --suite dense-heldout --out runs/x/follower-dense
    python scripts/suite_with.py configs/learners/ppo.yaml --follower --set env.plan=true --suite heldout --out runs/x/f
    python scripts/suite_with.py RUN --set env.plan_margin=0.3 --robots-per-room 1,2,4,8 --suite dense-heldout --out x/k
    python scripts/suite_with.py RUN --set env.plan_margin=0.3 --max-steps 2048 --suite indoor-heldout --out x/t2048
    python scripts/suite_with.py RUN --set env.plan_keep_right=0.45 --robots-per-room 4 --world eval-crossing --out x/c
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("source", help="a run directory (its agents and config.yaml), or with --follower a config file")
    ap.add_argument("--follower", action="store_true", help="drive the scripted follower, not the run's agents")
    ap.add_argument("--set", action="append", default=[], help="config overrides, as `fedjax-nav train --set`")
    ap.add_argument("--suite", default="dense-heldout")
    ap.add_argument("--attempts", type=int, default=1)
    ap.add_argument("--out", required=True, help="the evaluation's folder (refused when it holds one)")
    ap.add_argument("--robots-per-room", default=None, help="K robots per room, e.g. 1,2,4,8 (default: one per room)")
    ap.add_argument("--max-steps", type=int, default=None, help="time-out T (default: the run's episode_length)")
    ap.add_argument("--world", default=None, help="with --robots-per-room: this world in place of --suite")
    a = ap.parse_args(argv)
    if a.world is not None and a.robots_per_room is None:
        print("error: --world: only with --robots-per-room (one robot per room runs a --suite)", file=sys.stderr)
        return 2
    suite = None if a.world is not None else a.suite

    from fedjax_nav.config import ConfigError, load_config
    from fedjax_nav.evaluation.baselines import follower_run
    from fedjax_nav.evaluation.limits import EvalError
    from fedjax_nav.evaluation.overrides import run_with
    from fedjax_nav.evaluation.shared_rooms import evaluate_shared, shared_figure, write_shared
    from fedjax_nav.evaluation.suite import SUITE_JSON, evaluate_suite, write_suite
    from fedjax_nav.rundir import SHARED_JSON

    src, out = Path(a.source), Path(a.out)
    for name in (SUITE_JSON, SHARED_JSON):
        if (out / name).exists():
            print(f"error: {out / name} exists: choose another --out", file=sys.stderr)
            return 2
    try:
        ks = [int(k) for k in a.robots_per_room.split(",")] if a.robots_per_room else None
    except ValueError:
        print(f"error: --robots-per-room: integers separated by commas, got {a.robots_per_room!r}", file=sys.stderr)
        return 2
    try:  # a run's agents: traced values only (evaluation.overrides); the follower: any config
        if a.follower:  # in the env of a run (its config.yaml) or of a config file
            run = follower_run(load_config(src / "config.yaml" if src.is_dir() else src, a.set), out)
        else:
            run = run_with(src, a.set)
        if ks is not None:
            res = evaluate_shared(run, suite, ks, attempts=a.attempts, max_steps=a.max_steps, world=a.world)
        else:
            res = evaluate_suite(run, suite, attempts=a.attempts, max_steps=a.max_steps)
    except (ConfigError, EvalError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    if ks is not None:
        cols = ["robots_per_room", "family", "success", "worst10", "collision", "robot_collision", "timeout"]
        print(res["families"][cols].to_string(index=False))
        write_shared(res, out)
        shared_figure(run, suite, max(ks), out, max_steps=a.max_steps, world=a.world, attempts=a.attempts)
        print(f"wrote {out}/")
        return 0
    fams = res["families"]
    print(fams[["family", "rooms", "success", "worst10", "collision", "timeout"]].to_string(index=False))
    print("wrote " + ", ".join(str(p) for p in write_suite(res, out)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
