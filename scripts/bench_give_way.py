"""What giving way costs (docs/shared_rooms.md, "Speed"): env-only agent-steps/s of the shared-room
step as it was before the rules (`vmap(NavEnv.move)`, gather, settle) against `shared.fleet_step`
now (each robot's command checked against the others before the move, `fleet_move`), with
`env.give_way` off, on, and on with `env.give_way_door` (traced: the same program), in one run,
as `fedjax-nav bench shared` steps them (random actions, K x rooms robots in procedural mixture rooms).

    python scripts/bench_give_way.py --ks 4,8 --rooms 64 --steps 200 --repeats 3
"""

from __future__ import annotations

import argparse
import sys

# (env.give_way, env.give_way_door): off, giving way, giving way and waiting at doors
RULES = ((0.0, 0.0), (0.05, 0.0), (0.05, 1.6))


def rows(ks, rooms: int, steps: int, repeats: int) -> list[dict]:
    import jax
    import jax.numpy as jnp

    from fedjax_nav.env import NavEnv, make_params, shared
    from fedjax_nav.experiments.bench import _time, procedural_rooms
    from fedjax_nav.experiments.bench_shared import _rollout

    env, out = NavEnv(), []
    world = procedural_rooms("mixture", rooms)
    for k in ks:
        fleet = jax.vmap(lambda w, key, k=k: shared.place_fleet(w, key, k))(
            world, jax.random.split(jax.random.key(0), rooms)
        )
        placed = jax.tree.map(lambda x: x.swapaxes(0, 1).reshape(-1, *x.shape[2:]), fleet)
        present = jnp.ones(k, bool)

        def before(keys, states, actions, params, present=present):  # the step before giving way existed
            moved = jax.vmap(env.move)(keys, states, actions, params)
            around = shared.fleet_others(moved.pose, jax.vmap(env.radius)(params), present, rooms)
            return jax.vmap(env.settle)(keys, states, moved, params, around)

        keys = jax.random.split(jax.random.key(1), k * rooms)
        old = jax.jit(_rollout(env, before, steps))
        new = jax.jit(_rollout(env, shared.fleet_step(env, present, rooms), steps))
        for gap, door in RULES:
            params = make_params(placed, give_way=gap, give_way_door=door)
            for r in range(repeats):
                t_old, t_new = _time(old, keys, params), _time(new, keys, params)
                n = k * rooms * steps
                out.append(dict(robots_per_room=k, give_way=gap, give_way_door=door, repeat=r))
                out[-1] |= dict(before_steps_per_s=n / t_old)
                out[-1] |= dict(now_steps_per_s=n / t_new, cost=t_new / t_old)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--ks", default="4,8", help="robots per room, e.g. 4,8")
    ap.add_argument("--rooms", type=int, default=64)
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--repeats", type=int, default=3)
    a = ap.parse_args(argv)
    try:
        ks = [int(k) for k in a.ks.split(",")]
    except ValueError:
        print(f"error: --ks {a.ks!r}: robots per room as integers, e.g. 4,8", file=sys.stderr)
        return 2
    import pandas as pd

    df = pd.DataFrame(rows(ks, a.rooms, a.steps, a.repeats))
    print(df.to_string(index=False, float_format=lambda x: f"{x:,.3f}"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
