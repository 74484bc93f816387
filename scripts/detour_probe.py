"""Why detours fail (docs/clutter.md, "Why detours fail"): a run's failed detour episodes of a kept
suite evaluation, replayed in the rooms with the most of them and read where they went wrong
(fedjax_nav.evaluation.detours): turned back, stood still, the straight way blocked, crashes the
beams did not see, and the learned value along the way (V at the start, at the closest approach,
over the last 100 steps, at the end; --no-value leaves it out). Prints the summary per family and
outcome; --csv keeps every episode's row, --figure draws the rooms (every agent's attempt to each
goal, a colour per goal).

    fedjax-nav evaluate RUN --suite dense-heldout
    python scripts/detour_probe.py RUN --suite dense-heldout --rooms 12 --csv results/x.csv --figure docs/img/x.png
"""

from __future__ import annotations

import argparse
import sys


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("run", help="a training run directory with a kept suite evaluation")
    ap.add_argument("--suite", default="dense-heldout")
    ap.add_argument("--rooms", type=int, default=12, help="rooms replayed, those with the most failed detours")
    ap.add_argument("--folder", default=None, help="the kept evaluation (default RUN/eval/<suite>/)")
    ap.add_argument("--csv", default=None, help="write every replayed episode's row here")
    ap.add_argument("--figure", default=None, help="draw the replayed rooms here (PNG)")
    ap.add_argument("--no-value", action="store_true", help="leave out the learned value's columns")
    a = ap.parse_args(argv)

    from fedjax_nav.evaluation import detours, figures
    from fedjax_nav.evaluation.limits import EvalError
    from fedjax_nav.experiments.thesis_report import md_table

    try:
        table, replayed = detours.read(a.run, a.suite, a.rooms, folder=a.folder, value=not a.no_value)
    except EvalError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    if a.csv:
        table.to_csv(a.csv, index=False)
    if a.figure:
        figures.room_trajectories(replayed, a.figure, chosen="with the most failed detours")
    print(f"python scripts/detour_probe.py {a.run} --suite {a.suite} --rooms {a.rooms}")
    print(md_table(detours.summary(table).round(3)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
