"""The env step's cost in the procedural families, dense against sparse, at a training-like batch.

    python scripts/bench_dense_families.py [--families mixture,forest,warehouse,maze,cave,office,corridors]
        [--robots 5 --envs 64 --steps 200 --repeats 9] [--record docs/dense_rooms.md]

--robots x --envs environments, each in its own room of the family's default spec
(`generate_batch` over `train_room_key(0 .. n-1)`, padded to the family's `padded_shape`, the
per-pose layout of a training run): random actions through `NavEnv.step` (move, 24-beam cast,
clearance, reward, reset on a collision) in one jitted `lax.scan` of --steps steps, vmapped over
the environments, as `fedjax-nav bench env` does; and the geometry alone (one cast + one
`nearest_distance` per environment, scripts/bench_dense.py's "step"); and drawing the rooms
themselves (`generate_batch` of the --robots x --envs keys: rooms generated per second). Families
are timed in one process, alternated, median of --repeats (wall and CPU time: the machine may be
shared); ratios are against the first family listed (default: every family, `mixture` first).
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

os.environ.setdefault("JAX_PLATFORMS", "cpu")
sys.path.insert(0, str(Path(__file__).resolve().parent))

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
from bench_dense import (  # noqa: E402
    MAX_RANGE,
    NUM_BEAMS,
    compile_seconds,
    report_end,
    report_head,
    rows_of,
    step_geometry,
    throughput,
)

from fedjax_nav.env import NavEnv, make_params  # noqa: E402
from fedjax_nav.experiments.bench import random_rollout  # noqa: E402
from fedjax_nav.worlds import procedural, rooms, suites  # noqa: E402


def family_cases(family: str, n: int, steps: int):
    """((env rollout, args), (geometry, args), (generator, args), rows) over n rooms of `family`."""
    spec = rooms.make_spec(family)
    room_keys = jax.vmap(suites.train_room_key)(jnp.arange(n))
    world = procedural.generate_batch(room_keys, spec)
    env, params = NavEnv(num_beams=NUM_BEAMS, max_range=MAX_RANGE), make_params(world)

    rollout = random_rollout(env, steps)

    keys = jax.random.split(jax.random.key(0), n)
    poses = jnp.concatenate([world.starts[:, 0, :2], jnp.zeros((n, 1))], -1)
    geo = jax.jit(jax.vmap(step_geometry))
    env_case = (jax.jit(jax.vmap(rollout)), (keys, params))
    gen_case = (procedural.generate_batch, (room_keys, spec))  # compiled above
    return env_case, (geo, (world.segments, poses, world.circles)), gen_case, rows_of(world)


def bench(families, robots: int, envs: int, steps: int, repeats: int) -> list[str]:
    n = robots * envs
    cases, rows, comp = {}, {}, {}
    for fam in families:
        env_case, geo_case, gen_case, rows[fam] = family_cases(fam, n, steps)
        comp[fam] = compile_seconds(*env_case)
        cases[(fam, "env")], cases[(fam, "geometry")], cases[(fam, "generate")] = env_case, geo_case, gen_case
    t, cpu = throughput(cases, repeats)
    ref = families[0]
    lines = [
        f"{robots} robots x {envs} environments = {n} rooms (one each), {steps} random-action env steps per call; "
        f"geometry: one cast + clearance per room; generated: `generate_batch` of the {n} rooms; median of "
        f"{repeats} alternated repeats.",
        "",
        f"| family | rows (M + C) | env compile s | env agent-steps/s | vs {ref} | per CPU-s | vs {ref} "
        f"| geometry steps/s | vs {ref} | rooms generated/s | vs {ref} |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for fam in families:
        (m, c), e, g, r = rows[fam], (fam, "env"), (fam, "geometry"), (fam, "generate")
        lines.append(
            f"| {fam} | {m + c} ({m} + {c}) | {comp[fam]:.2f} | {n * steps / t[e]:,.0f} "
            f"| {t[(ref, 'env')] / t[e]:.2f}x | {n * steps / cpu[e]:,.0f} | {cpu[(ref, 'env')] / cpu[e]:.2f}x "
            f"| {n / t[g]:,.0f} | {t[(ref, 'geometry')] / t[g]:.2f}x "
            f"| {n / t[r]:,.0f} | {t[(ref, 'generate')] / t[r]:.2f}x |"
        )
        print(lines[-1], flush=True)
    return lines


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    default = ("mixture",) + rooms.DENSE_FAMILIES + rooms.INDOOR_FAMILIES
    ap.add_argument("--families", default=",".join(default), help="comma-separated families (first: the reference)")
    ap.add_argument("--robots", type=int, default=5)
    ap.add_argument("--envs", type=int, default=64, help="environments per robot")
    ap.add_argument("--steps", type=int, default=200, help="env steps per timed call")
    ap.add_argument("--repeats", type=int, default=9)
    ap.add_argument("--record", metavar="FILE", help="append the table to FILE (markdown)")
    a = ap.parse_args(argv)
    families = a.families.split(",")
    bad = [f for f in families if f not in rooms.FAMILIES]
    if bad:
        ap.error(f"--families: {bad[0]!r} is not a family ({', '.join(rooms.FAMILIES)})")
    out = report_head("bench_dense_families.py", argv) + bench(families, a.robots, a.envs, a.steps, a.repeats)
    report_end(out, "bench_dense_families.py", a.record)


if __name__ == "__main__":
    main()
