"""What the traffic rules do (docs/shared_rooms.md, "Keeping right", "Giving way"): success and
robot-robot collisions against K robots per room for each fleet of a `scripts/shared_report.py
--csv` table, each fleet without a rule (solid) and under each rule its label's ending names
(RULES: ", keeping right" dashed; ", trained keeping right" dotted; ", keeping right and giving
way" dash-dotted), the bars the 95% interval over the training seeds.

    python scripts/draw_keep_right.py results/plan_keep_right.csv --out docs/img/shared_rooms/keep_right.png
    python scripts/draw_keep_right.py results/plan_give_way.csv --out docs/img/shared_rooms/give_way.png \
        --fleet "central, 3.0e7" --fleet "central, 1.0e8" --fleet "federated, 1.0e7"
"""

from __future__ import annotations

import argparse
import sys

# label ending -> (style, line): the one that ends a label names its rule (no ending is another's); none: "without"
RULES = {
    ", keeping right": ("with", "--"),
    ", trained keeping right": ("trained", ":"),
    ", keeping right and giving way": ("giving way", "-."),
}
LINES = {"without": "-"} | {style: line for style, line in RULES.values()}


def series(df) -> dict:
    """{fleet: {style: rows over K}} from the table's 'all' rows: style "without", or that of the
    RULES ending its label (the fleet: the label without it)."""
    rows = df[df.family == "all"].sort_values("robots_per_room")
    out: dict = {}
    for label, g in rows.groupby("label", sort=False):
        end = next((e for e in RULES if label.endswith(e)), "")
        style = RULES[end][0] if end else "without"
        out.setdefault(label[: len(label) - len(end)], {})[style] = g
    return out


def draw(df, out: str, fleets=None) -> str:
    from matplotlib.figure import Figure

    fig = Figure(figsize=(11, 4.2), layout="constrained")
    ax_s, ax_r = fig.subplots(1, 2)
    names = {style: end for end, (style, _) in RULES.items()} | {"without": ""}
    drawn = {f: parts for f, parts in series(df).items() if not fleets or f in fleets}
    for n, (fleet, parts) in enumerate(drawn.items()):
        for style, g in sorted(parts.items(), key=lambda p: list(LINES).index(p[0])):  # legend: without first
            k = g.robots_per_room.to_numpy()
            err = [g.success - g.ci_seeds_low, g.ci_seeds_high - g.success]
            ax_s.errorbar(k, g.success, yerr=err, ls=LINES[style], color=f"C{n}", marker="o", ms=3, capsize=2)
            ax_r.plot(
                k, g.robot_collision, ls=LINES[style], color=f"C{n}", marker="o", ms=3, label=fleet + names[style]
            )
    for ax, what in ((ax_s, "success"), (ax_r, "robot-robot collisions per robot-episode")):
        ax.set_xscale("log", base=2)
        ax.set_xticks([1, 2, 4, 8], ["1", "2", "4", "8"])
        ax.set_xlabel("robots per room (K)")
        ax.set_ylabel(what)
        ax.grid(alpha=0.3)
    ax_s.axhline(0.92, color="k", lw=0.8, ls="-.")
    ax_s.text(5.0, 0.93, "goal at K = 4: 0.92", fontsize=8)
    ax_r.legend(fontsize=7, loc="upper left")
    styles = {style for parts in drawn.values() for style in parts}
    key = ", ".join(f"{end[2:]} ({LINES[style]})" for end, (style, _) in RULES.items() if style in styles)
    fig.suptitle(f"held-out mixture rooms, 2 seeds: without a rule (-), {key}")
    fig.savefig(out, dpi=100)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("csv", help="a table written by scripts/shared_report.py --csv")
    ap.add_argument("--out", required=True, help="the PNG")
    ap.add_argument("--fleet", action="append", default=[], help="draw only this fleet (its label without a rule)")
    a = ap.parse_args(argv)
    import pandas as pd

    df = pd.read_csv(a.csv)
    missing = {"label", "robots_per_room", "family", "success", "ci_seeds_low", "ci_seeds_high"} - set(df)
    if missing:
        print(f"error: {a.csv}: not a shared_report.py table (no column {sorted(missing)[0]!r})", file=sys.stderr)
        return 2
    unknown = sorted(set(a.fleet) - set(series(df)))
    if unknown:
        print(f"error: --fleet {unknown[0]!r}: no such fleet in {a.csv} (it has {sorted(series(df))})", file=sys.stderr)
        return 2
    print("wrote", draw(df, a.out, a.fleet))
    return 0


if __name__ == "__main__":
    sys.exit(main())
