"""`fedjax-nav bench shared`: env-only agent-steps/s with K robots per shared room against the
same robots alone in separate rooms, in one run (docs/shared_rooms.md, "Speed").

Both sides step the same K x N robots in the same N procedural rooms (mixture) with uniform
random actions: separate, each robot alone in its copy of room j (`vmap(env.step)`); shared, the
K robots of room j together (`shared.fleet_step`: every robot also casts its lidar at the K - 1
others and checks its distance to them). `cost_per_robot` is separate / shared agent-steps/s: what
a robot's step costs more when it shares its room.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from fedjax_nav.experiments.bench import _time, procedural_rooms


def _rollout(env, step_all, steps: int):
    """(keys [B], params [B]) -> f32[]: every robot drives `steps` uniform random actions from a
    reset, the observations and rewards summed (nothing is dead code)."""

    def run(keys, params):
        _, states = jax.vmap(env.reset)(keys, params)

        def body(carry, k):
            states, acc = carry
            ks = jax.random.split(k, keys.shape[0])
            a = jax.vmap(lambda q: jax.random.uniform(q, (2,), minval=jnp.array([0.0, -1.0]), maxval=1.0))(ks)
            obs, states, r, *_ = step_all(ks, states, a, params)
            return (states, acc + jnp.sum(obs) + jnp.sum(r)), None

        (_, acc), _ = jax.lax.scan(body, (states, 0.0), jax.random.split(keys[0], steps))
        return acc

    return run


def bench_shared(ks=(1, 4, 8, 16), rooms: int = 64, steps: int = 200) -> list[dict]:
    from fedjax_nav.env import NavEnv, make_params, shared

    env = NavEnv()
    world = procedural_rooms("mixture", rooms)
    rows = []
    for k in ks:
        fleet = jax.vmap(lambda w, key, k=k: shared.place_fleet(w, key, k))(
            world, jax.random.split(jax.random.key(0), rooms)
        )
        # robot-major rows [k * rooms]: environment j of robot i is room j (as the trainer lays them out)
        placed = jax.tree.map(lambda x: x.swapaxes(0, 1).reshape(-1, *x.shape[2:]), fleet)
        params = make_params(placed)
        keys = jax.random.split(jax.random.key(1), k * rooms)
        alone = jax.jit(_rollout(env, jax.vmap(env.step), steps))
        together = jax.jit(_rollout(env, shared.fleet_step(env, jnp.ones(k, bool), rooms), steps))
        t_alone, t_shared = _time(alone, keys, params), _time(together, keys, params)
        n = k * rooms * steps
        rows.append(
            {
                "bench": "shared",
                "robots_per_room": k,
                "rooms": rooms,
                "steps": steps,
                "separate_steps_per_s": n / t_alone,
                "shared_steps_per_s": n / t_shared,
                "cost_per_robot": t_shared / t_alone,
            }
        )
    return rows
