"""Resource checks before a run allocates anything: the memory its run will take, by part
(docs/reliability.md, "Memory for many environments").

`jax.eval_shape` of the trainer's `init` gives the exact bytes of one seed's `TrainState` without
allocating it; each learner declares what one update holds beyond it (`Learner.update_bytes`:
its batches and its own networks' activations); the room generator what drawing the rooms holds
(`training.rooms.generation_bytes`); and compiling the program costs about COMPILER_BYTES.
`check_memory` refuses a run whose estimate exceeds the budget (`config.memory.over_budget`, the
rule evaluation refuses by too), with one line naming the config field behind the largest part,
taken from the learner's row (`storage_size`, `update_size`). The sweeps pack their batches by the
same estimate (`sweep.plan.point_bytes`).
"""

from __future__ import annotations

import jax

from fedjax_nav import learner_table
from fedjax_nav.agents.learners import activation_bytes  # noqa: F401  (re-exported: the replay update's part)
from fedjax_nav.config import ConfigError, get
from fedjax_nav.config.memory import nbytes, over_budget, size
from fedjax_nav.training.hparams import hparams_from_config
from fedjax_nav.training.rooms import generation_bytes
from fedjax_nav.training.trainer import Trainer

# peak memory of a chunk per row / bytes of one TrainState row (donated); sweeps plan with it too
STATE_BYTES_FACTOR = 3

# Host bytes per metrics row (episode x seed x robot): the arrays, the pandas frame and its CSV text.
METRICS_ROW_BYTES = 16 * 8 * 3
# What compiling a chunk program adds to the process's peak (XLA:CPU; it is not returned to the
# system after): the peak RSS growth of a run minus its other parts, 0.98-1.08 GB for DDPG, PPO and
# GRU-PPO at 64 environments per robot (learners/*.yaml; scripts/memory_check.py).
COMPILER_BYTES = 1_200 * 2**20
# Bytes per environment beyond its state: XLA's temporaries of one step (the lidar's per-beam work,
# 5.6 KB at 5 x 16,384 environments of the thesis rooms) and what the initial state's program and
# the host copies hold per environment, not taken apart: the peak RSS growth of SAC at 5 x 65,536
# environments of the thesis rooms beyond every other part was 15.9 KB per environment.
ENV_STEP_BYTES = 18_000


class ResourceError(ConfigError):
    """The run would need more memory than the budget; the message names the field (exit 2)."""


def memory_estimate(trainer: Trainer) -> dict[str, int]:
    """Bytes of a run of `trainer.cfg` by part (every seed): "buffers" (replay rows or rollouts),
    "networks" (actors, critics, targets, Adam states, the aggregator's models), "env" (env states,
    observations, counters, the rooms), "update" (one update of every network at once: the
    learner's `update_bytes`), "steps" (ENV_STEP_BYTES per environment), "rooms" (drawing the
    rooms: `training.rooms.generation_bytes`), "compiler" (compiling the program), "metrics" (host
    tables of every episode), "worlds", and "total": the state parts times STATE_BYTES_FACTOR (a
    chunk's peak: the donated state, its outputs, the checkpoint's host copy) plus the others.
    Measured against the peak RSS of real runs of every learner at 64, 1,024 and 8,192 environments
    per robot (scripts/memory_check.py, results/memory_check.csv; docs/reliability.md)."""
    cfg = trainer.cfg
    hp = hparams_from_config(cfg)
    shapes = jax.eval_shape(lambda k: trainer.init(k, hp), jax.random.key(0))
    S = cfg.run.seeds
    buffers = nbytes(shapes.buffers) * S
    networks = (nbytes(shapes.agents) + nbytes(shapes.agg_state)) * S
    env = nbytes(shapes) * S - buffers - networks
    update = trainer.learner.update_bytes(trainer.nets, trainer.obs_size, trainer.writes) * trainer.n_nets * S
    steps = ENV_STEP_BYTES * cfg.num_robots * cfg.env.envs_per_robot * S
    largest = max((len(idx) for _, idx in trainer.rooms.groups), default=0) if trainer.rooms.procedural else 0
    rooms = generation_bytes(largest) * S
    metrics = cfg.run.episodes * S * cfg.num_robots * METRICS_ROW_BYTES
    worlds = nbytes(trainer.world)
    total = STATE_BYTES_FACTOR * (buffers + networks + env) + update + steps + rooms + COMPILER_BYTES
    total += metrics + worlds
    return {
        "buffers": buffers,
        "networks": networks,
        "env": env,
        "update": update,
        "steps": steps,
        "rooms": rooms,
        "compiler": COMPILER_BYTES,
        "metrics": metrics,
        "worlds": worlds,
        "total": total,
    }


def check_memory(trainer: Trainer, budget: int | None = None, src: str = "config") -> dict[str, int]:
    """Raise ResourceError when the run's estimate exceeds `budget` bytes (default: the memory
    available now), naming the field behind the largest share of the total (the learner row's
    storage and update fields for its parts); return the estimate."""
    est = memory_estimate(trainer)
    over = over_budget(est["total"], budget)
    if over is None:
        return est
    cfg = trainer.cfg
    row = learner_table.get(cfg.learner)
    storage = row.storage_size
    if storage == "offpolicy.buffer_size" and cfg.offpolicy.buffer_alloc:
        storage = "offpolicy.buffer_alloc"
    fields = {
        "buffers": storage,
        "networks": f"{row.actor_section}.hidden",
        "env": "env.envs_per_robot",
        "update": row.update_size,
        "steps": "env.envs_per_robot",
        "rooms": "env.envs_per_robot",
        "metrics": "run.episodes",
        "worlds": "env.worlds",
    }
    state = ("buffers", "networks", "env")  # counted STATE_BYTES_FACTOR times in the total
    part = max(fields, key=lambda k: est[k] * (STATE_BYTES_FACTOR if k in state else 1))  # the largest share
    parts = ", ".join(f"{k} {size(est[k])}" for k in (*fields, "compiler") if est[k] >= est["total"] / 100)
    if est[part] * (STATE_BYTES_FACTOR if part in state else 1) < est["compiler"]:  # a budget below compiling
        raise ResourceError(
            f"{src}: the run needs about {size(est['total'])} ({parts}), {over}; compiling the program "
            f"alone takes about {size(est['compiler'])}: raise --memory-budget"
        )
    name = fields[part]
    value = get(cfg, name)
    raise ResourceError(
        f"{src}: {name} = {value if part != 'worlds' else len(value)}: the run needs about {size(est['total'])} "
        f"({parts}; {cfg.run.seeds} seed(s)), {over}; lower {name} or run.seeds"
    )
