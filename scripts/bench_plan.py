"""What the global plan costs (docs/planning.md): env agent-steps/s with `env.plan` off and on,
and the cost of a reset (the distance field) in one process, over procedural rooms.

    python scripts/bench_plan.py [--batch 1280] [--steps 200] [--family mixture] [--cells 64]

Each program is timed as `fedjax-nav bench env` times it (best of 3 calls after a compiling one):
a reset of every environment, then `steps` random-action steps in learn mode from those states.
"""

from __future__ import annotations

import argparse
import os
import time

import jax
import jax.numpy as jnp
import numpy as np

from fedjax_nav.env import NavEnv, make_params
from fedjax_nav.env import plan as gp
from fedjax_nav.experiments.bench import _time, machine, procedural_rooms


def _programs(env: NavEnv, steps: int):
    def reset(keys, params):
        return jax.vmap(env.reset)(keys, params)

    def roll(keys, state, params):
        def body(carry, k):
            state, acc = carry
            a = jax.random.uniform(k[0], (keys.shape[0], 2), minval=jnp.array([0.0, -1.0]), maxval=1.0)
            obs, state, r, *_ = jax.vmap(env.step)(jax.random.split(k[0], keys.shape[0]), state, a, params)
            return (state, acc + jnp.sum(obs) + jnp.sum(r)), None

        ks = jax.random.split(keys[0], steps)[:, None]
        return jax.lax.scan(body, (state, 0.0), ks)[0][1]

    return jax.jit(reset), jax.jit(roll)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--batch", type=int, default=1280)
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--family", default="mixture")
    ap.add_argument("--cells", type=int, default=64)
    a = ap.parse_args()
    rooms = procedural_rooms(a.family, 64)
    idx = jnp.arange(a.batch) % 64
    params = make_params(jax.tree.map(lambda x: x[idx], rooms))
    keys = jax.random.split(jax.random.key(0), a.batch)
    print(f"machine: {machine()}; load average before: {os.getloadavg()}")
    print(f"batch {a.batch} environments, {a.family} rooms (64 of the training stream), {a.steps} steps per call")
    rows = {}
    for on in (False, True):
        env = NavEnv(plan=on, plan_cells=a.cells)
        reset, roll = _programs(env, a.steps)
        t0 = time.perf_counter()
        jax.block_until_ready(reset(keys, params))
        t_reset = _time(reset, keys, params)
        _, state = reset(keys, params)
        t_roll = _time(roll, keys, state, params)
        rows[on] = (t_reset, t_roll)
        label = f"plan on ({a.cells} cells)" if on else "plan off"
        print(
            f"{label:22s} reset {t_reset * 1e3:8.1f} ms ({t_reset / a.batch * 1e6:7.1f} us per env); "
            f"steps {a.batch * a.steps / t_roll:12,.0f} agent-steps/s (compile+first {time.perf_counter() - t0:.0f} s)"
        )
    (r0, s0), (r1, s1) = rows[False], rows[True]
    episode = (r1 + s1 * 1024 / a.steps) / (r0 + s0 * 1024 / a.steps)
    print(f"step time x{s1 / s0:.2f}; a 1024-step episode (its reset and steps) x{episode:.2f}")
    # passes of the field's relaxation over these rooms (one per room, goal 0)
    f = jax.jit(
        jax.vmap(
            lambda w: gp.distance_field(
                gp.free_cells(w, 0.25, a.cells),
                gp.goal_cells(gp.free_cells(w, 0.25, a.cells), w.size, w.goals[0], 0.5),
                gp.grid(w.size, a.cells)[0],
            )[1]
        )
    )
    passes = np.asarray(f(rooms))
    print(f"field passes (up + down sweeps) per room: mean {passes.mean():.1f}, max {passes.max()}")
    print(f"load average after: {os.getloadavg()}")


if __name__ == "__main__":
    main()
