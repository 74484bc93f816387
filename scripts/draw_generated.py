"""Draw procedural rooms for docs/generator.md (PNGs under docs/img/generated/).

    python scripts/draw_generated.py [--out docs/img/generated] [--rooms 4] [--families forest,maze]
    python scripts/draw_generated.py --time 4096     # time generating 4096 rooms per family, jitted

For each family: `<family>.png`, rooms of room seeds 0 .. rooms-1 with the family's default spec
(the same rooms as ``fedjax-nav worlds generate --family F --seed S``), drawn with
`fedjax_nav.env.render.draw_world`; a dense family's rooms also show their clear network (dashed
green). Plus `reserved.png`: two rooms with their reserved network (the paths kept clear of
obstacles, see the solvability argument in docs/generator.md), `density.png`: one room of each
dense family at densities 0.25, 0.5 and 1, and `density_indoor.png`: the same for the indoor
families (office, corridors).
"""

from __future__ import annotations

import argparse
import functools
import os
import sys
import types
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from matplotlib.figure import Figure

from fedjax_nav.env import render
from fedjax_nav.worlds import procedural, rooms, suites

gen = types.SimpleNamespace(**{**vars(rooms), **vars(procedural), **vars(suites)})
ROOT = Path(__file__).resolve().parents[1]


def room(batch, i):
    return jax.tree.map(lambda leaf: jnp.asarray(np.asarray(leaf)[i]), batch)


# What the title of a dense family's room counts (info key, word).
DENSE_COUNTS = {
    "forest": (("trees", "trunks"),),
    "warehouse": (("racks", "racks"), ("pallets", "pallets")),
    "maze": (("cells", "cells"), ("maze_walls", "wall sides")),
    "cave": (("occupied", "rock cells"), ("outline_runs", "edges")),
    "office": (("rooms", "rooms"), ("obstacles", "obstacles")),
    "corridors": (("branches", "branches"), ("side_rooms", "rooms")),
}


def counts(family: str, spec, info, i: int) -> str:
    if family in DENSE_COUNTS:
        return ", ".join(f"{int(info[k][i])} {word}" for k, word in DENSE_COUNTS[family])
    return ", ".join(f"{int(info[k][i])} {k}" for k in ("walls", "boxes", "cylinders") if spec.uses(k))


def draw_network(ax, info, i: int) -> None:
    res, on = np.asarray(info["reserved"])[i], np.asarray(info["reserved_on"])[i]
    for x1, y1, x2, y2 in res[on]:
        ax.plot([x1, x2], [y1, y2], color="#2ca02c", lw=0.8, ls="--", zorder=3)


def draw_family(family: str, n: int, out: Path, dpi: int) -> Path:
    spec = gen.make_spec(family)
    seeds = np.arange(n)
    world, info = gen.generate_batch_with_info(jax.vmap(gen.room_key)(jnp.asarray(seeds)), spec)
    fig = Figure(figsize=(3.3 * n, 3.6), layout="constrained")
    for i, s in enumerate(seeds):
        w = room(world, i)
        W, H = np.asarray(w.size)
        ax = fig.add_subplot(1, n, i + 1)
        render.draw_world(ax, w, title=f"{family}, seed {s}\n{W:.1f} x {H:.1f} m; {counts(family, spec, info, i)}")
        if family in gen.DENSE_FAMILIES + gen.INDOOR_FAMILIES:
            draw_network(ax, info, i)
    path = out / f"{family}.png"
    fig.savefig(path, dpi=dpi)
    return path


def draw_density(out: Path, dpi: int, seed: int = 1, densities=(0.25, 0.5, 1.0), fams=None, name="density") -> Path:
    """One room of each of `fams` (rows; default the dense families) at each density (columns)."""
    fams = fams or gen.DENSE_FAMILIES
    fig = Figure(figsize=(3.3 * len(densities), 3.4 * len(fams)), layout="constrained")
    for r, family in enumerate(fams):
        spec = gen.make_spec(family)
        f = jax.jit(lambda k, d, spec=spec: gen.generate_with_info(k, spec, d))
        for j, d in enumerate(densities):
            w, info = f(gen.room_key(seed), d)
            info = {k: np.asarray(v)[None] for k, v in info.items()}
            ax = fig.add_subplot(len(fams), len(densities), r * len(densities) + j + 1)
            render.draw_world(ax, w, title=f"{family}, seed {seed}, density {d:g}\n{counts(family, spec, info, 0)}")
    path = out / f"{name}.png"
    fig.savefig(path, dpi=dpi)
    return path


def draw_reserved(out: Path, dpi: int) -> Path:
    fig = Figure(figsize=(7.0, 3.8), layout="constrained")
    for j, (family, seed) in enumerate((("mixture", 1), ("walls", 2))):
        spec = gen.RoomSpec(family=family)
        w, info = jax.jit(functools.partial(gen.generate_with_info, spec=spec))(gen.room_key(seed))
        ax = fig.add_subplot(1, 2, j + 1)
        render.draw_world(ax, w, title=f"{family}, seed {seed}: reserved network")
        res, on = np.asarray(info["reserved"]), np.asarray(info["reserved_on"])
        c = spec.clearance
        from matplotlib.patches import Circle, Polygon, Rectangle

        for x1, y1, x2, y2 in res[on]:
            ax.plot([x1, x2], [y1, y2], color="#2ca02c", lw=1.0, ls="--", zorder=3)
            # the band of half-width c around each path that obstacles keep out of
            d = np.array([x2 - x1, y2 - y1])
            n = np.array([-d[1], d[0]]) / max(np.linalg.norm(d), 1e-9) * c
            a, b = np.array([x1, y1]), np.array([x2, y2])
            ax.add_patch(
                Polygon([a + n, b + n, b - n, a - n], closed=True, fc="#2ca02c", ec="none", alpha=0.12, zorder=1)
            )
            for q in (a, b):
                ax.add_patch(Circle(q, c, fc="#2ca02c", ec="none", alpha=0.12, zorder=1))
        rooms, act = np.asarray(info["rooms"]), np.asarray(info["rooms_active"])
        for x0, y0, x1, y1 in rooms[act]:
            ax.add_patch(
                Rectangle(
                    (x0 + c, y0 + c),
                    x1 - x0 - 2 * c,
                    y1 - y0 - 2 * c,
                    fill=False,
                    ec="#9467bd",
                    lw=0.7,
                    ls=":",
                    zorder=1,
                )
            )
    path = out / "reserved.png"
    fig.savefig(path, dpi=dpi)
    return path


def time_generation(n: int, families, repeats: int = 5) -> None:
    """Print, per family: the first call of `generate_batch` on n keys (compile + run) and the
    median of `repeats` further calls."""
    import time

    keys = jax.vmap(gen.train_room_key)(jnp.arange(n))
    print(
        f"jax {jax.__version__}, backend {jax.default_backend()}, {os.cpu_count()} CPUs, "
        f"load average {os.getloadavg()[0]:.1f}"
    )
    for family in families:
        spec = gen.make_spec(family)
        t = time.perf_counter()
        jax.block_until_ready(gen.generate_batch(keys, spec))
        first = time.perf_counter() - t
        runs = []
        for _ in range(repeats):
            t = time.perf_counter()
            jax.block_until_ready(gen.generate_batch(keys, spec))
            runs.append(time.perf_counter() - t)
        med = sorted(runs)[len(runs) // 2]
        print(
            f"{family:9s} {n} rooms, shape {gen.padded_shape(spec)}: first call (compile + run) {first:5.1f} s; "
            f"then median {med * 1e3:6.0f} ms "
            f"({n / med:,.0f} rooms/s)"
        )


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(ROOT / "docs" / "img" / "generated"))
    ap.add_argument("--rooms", type=int, default=4)
    ap.add_argument("--dpi", type=int, default=render.DPI)
    ap.add_argument("--density-seed", type=int, default=3, help="the indoor families' room in density_indoor.png")
    ap.add_argument("--time", type=int, default=None, metavar="N", help="time generating N rooms instead of drawing")
    ap.add_argument("--families", default=",".join(gen.FAMILIES), help="comma-separated families (default: all)")
    args = ap.parse_args(argv)
    families = [f for f in args.families.split(",") if f]
    bad = [f for f in families if f not in gen.FAMILIES]
    if bad:
        ap.error(f"--families: {bad[0]!r} is not a family ({', '.join(gen.FAMILIES)})")
    if args.time:
        time_generation(args.time, families)
        return 0
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for family in families:
        print(draw_family(family, args.rooms, out, args.dpi))
    if set(gen.BASE_FAMILIES) <= set(families):
        print(draw_reserved(out, args.dpi))
    if set(gen.DENSE_FAMILIES) <= set(families):
        print(draw_density(out, args.dpi))
    if set(gen.INDOOR_FAMILIES) <= set(families):
        print(draw_density(out, args.dpi, seed=args.density_seed, fams=gen.INDOOR_FAMILIES, name="density_indoor"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
