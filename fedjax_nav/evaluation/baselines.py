"""A scripted baseline to evaluate beside the learned policies (docs/planning.md, "A scripted
follower"): no network, no training; it drives the run's observation as a classical controller.

    policy = follower(num_beams, plan)       policy(params, obs) -> action, the env's units
    run = follower_run(cfg, out)             a RunAgents whose one agent is the follower

The follower turns towards the observation's target (the plan's waypoint with `env.plan`, else
the goal) at `TURN_GAIN` x its bearing (clipped to omega_max) and drives forwards at
v_max x (1 - |bearing| / `TURN_IN_PLACE`) (none beyond that angle: it turns on the spot). It
reads no range: with the plan it measures what the waypoint alone is worth, the path's geometry
included (a collision is the plan's way passing too near a wall, or the protocol's noise); without
the plan it is the straight line to the goal.

`evaluation.suite.evaluate_suite(follower_run(cfg, out), suite)` runs it through the learned
policies' protocol (same rooms, goals, noise, keys), so its tables compare row by row.
"""

from __future__ import annotations

import functools
import math
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from fedjax_nav.env import plan as gp
from fedjax_nav.evaluation.run_data import RunAgents

TURN_GAIN = 2.0  # omega / omega_max per radian of bearing (saturates past 0.5 rad)
TURN_IN_PLACE = math.pi / 4  # rad: no forward speed at or beyond this bearing


@functools.lru_cache(maxsize=8)
def follower(num_beams: int, plan: bool):
    """policy(params, obs) -> (v / v_max, omega / omega_max): towards the observation's target
    (its bearing found by name in `plan.layout`); `params` is not read. One function object per
    observation layout, so that evaluations share one compiled program."""
    target = "waypoint_bearing" if plan else "goal_bearing"
    at = num_beams + gp.layout(plan).index(target)

    def policy(params, obs):
        bearing = obs[at]
        v = jnp.clip(1.0 - jnp.abs(bearing) / TURN_IN_PLACE, 0.0, 1.0)
        return jnp.stack([v, jnp.clip(TURN_GAIN * bearing, -1.0, 1.0)])

    return policy


def follower_run(cfg, out: str | Path) -> RunAgents:
    """The follower as a run of `cfg` (its env: rooms, plan, robot model; `evaluate_suite` takes
    the protocol from it): one agent, seed `cfg.run.seed`, kept under `out`."""
    policy = follower(int(cfg.env.num_beams), bool(cfg.env.plan))
    return RunAgents(
        run_dir=Path(out),
        cfg=cfg,
        actor_params={"none": jnp.zeros((1,), jnp.float32)},  # the agent axis [A = 1]; not read
        agent_seed=np.array([cfg.run.seed]),
        agent_net=np.array([0]),
        n_nets=1,
        num_robots=1,
        policy=policy,
    )
