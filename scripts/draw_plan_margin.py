"""What the plan's margin does (docs/planning.md, "The margin, and a scripted follower"): the
path down the plan's field between the room's start row and goal farthest apart (by the plain
path) with the plain field (margin 0) and with the margin, over generated maze, office and forest rooms, on the
env's own grid.

    python scripts/draw_plan_margin.py --out docs/img/plan_margin.png
"""

from __future__ import annotations

import argparse
import sys


def descent(field, cost, size, cells: int, xy) -> list:
    """The cells' centres along the path down `field` from the point `xy` (as `plan.waypoint` walks
    it, with no lookahead and no sight rule): [(x, y), ...] to the goal's cells."""
    import numpy as np

    from fedjax_nav.env import plan

    f, c = np.asarray(field), np.asarray(cost)
    res, xs, ys = (np.asarray(a) for a in plan.grid(size, cells))
    y, x = (int(i) for i in plan.cell_of(xy, size, cells))
    out = [(xs[x], ys[y])]
    while np.isfinite(f[y, x]) and f[y, x] > 0:
        nb = [(y + dy, x + dx, s) for dy, dx, s in zip(plan._DY, plan._DX, plan._STEP)]
        nb = [(v, w, s) for v, w, s in nb if 0 <= v < cells and 0 <= w < cells]
        y, x, _ = min(nb, key=lambda n: f[n[0], n[1]] + n[2] * float(res) * c[y, x])
        out.append((xs[x], ys[y]))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True)
    ap.add_argument("--margin", type=float, default=0.3)
    ap.add_argument("--cells", type=int, default=128)
    a = ap.parse_args(argv)

    import jax
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from fedjax_nav.env import plan
    from fedjax_nav.env.render import draw_world
    from fedjax_nav.worlds.procedural import generate
    from fedjax_nav.worlds.rooms import make_spec

    def plain(world, g, cells):
        return plan.goal_field(world, world.goals[g], 0.25, 0.5, cells, 0.0)

    rooms = [("maze", 3), ("office", 5), ("forest", 7)]
    fig, axes = plt.subplots(1, len(rooms), figsize=(5.5 * len(rooms), 5.5))
    for ax, (family, seed) in zip(axes, rooms):
        world = generate(jax.random.key(seed), make_spec(family))
        draw_world(ax, world, title=f"{family} (seed {seed})", labels=False)
        pairs = [(i, g) for i in range(int(world.num_starts)) for g in range(int(world.num_goals))]
        fields = {g: plain(world, g, a.cells) for g in range(int(world.num_goals))}

        lengths = {p: len(descent(*fields[p[1]], world.size, a.cells, world.starts[p[0], :2])) for p in pairs}
        start, far = max(pairs, key=lengths.__getitem__)
        for m, color in ((0.0, "tab:red"), (a.margin, "tab:blue")):
            field, cost = plan.goal_field(world, world.goals[far], 0.25, 0.5, a.cells, m)
            pts = descent(field, cost, world.size, a.cells, world.starts[start, :2])
            ax.plot(*zip(*pts), color=color, lw=2, label=f"margin {m:g} m")
        ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    fig.savefig(a.out, dpi=90)
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
