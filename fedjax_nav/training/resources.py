"""Resource checks before a run allocates anything: the memory its state will take, by part.

`jax.eval_shape` of the trainer's `init` gives the exact bytes of one seed's `TrainState` without
allocating it (the sweeps pack their batches by this estimate: `sweep.plan.point_bytes`), and
`activation_bytes` the batch and activations of one update of every network; `check_memory`
refuses a run whose estimate exceeds the budget (`config.memory.over_budget`, the rule evaluation
refuses by too), with one line naming the config field that dominates (docs/reliability.md).
"""

from __future__ import annotations

import jax

from fedjax_nav.config import ConfigError
from fedjax_nav.config.memory import nbytes, over_budget, size
from fedjax_nav.training.hparams import hparams_from_config
from fedjax_nav.training.trainer import Trainer

# peak memory of a chunk per row / bytes of one TrainState row (donated); sweeps plan with it too
STATE_BYTES_FACTOR = 3

# Host bytes per metrics row (episode x seed x robot): the arrays, the pandas frame and its CSV text.
METRICS_ROW_BYTES = 16 * 8 * 3
# f32 values per batch row and hidden unit of each layer in one `ddpg.update` (critic step, then
# actor step; forward and backward). Measured: XLA CPU's temporaries of the thesis FLDDPG chunk
# program (5 networks), batch 65536 minus batch 4096, per row and network: hidden 16 / depth 1, 2:
# 204, 268 values; hidden 64 / depth 3: 1,054; hidden 256 / depth 1, 3, 6: 1,630, 3,934, 7,006.
# (5 depth + 3) hidden plus the batch twice gives 1.2-1.3x each of them.
ACTIVATIONS_PER_LAYER = 5
ACTIVATIONS_OUTSIDE = 3


class ResourceError(ConfigError):
    """The run would need more memory than the budget; the message names the field (exit 2)."""


def activation_bytes(obs_size: int, hidden: int, depth: int, batch: int, action_size: int = 2) -> int:
    """Peak bytes of one network's `ddpg.update` beyond its state: the sampled batch (obs, next_obs,
    action, reward, done; and its gathered copy) and the actor's and critic's activations and
    gradients, (5 depth + 3) x hidden f32 per row (measured: `ACTIVATIONS_PER_LAYER`)."""
    row = 2 * (2 * obs_size + action_size + 2)
    per_row = (ACTIVATIONS_PER_LAYER * depth + ACTIVATIONS_OUTSIDE) * hidden + row
    return 4 * per_row * int(batch)


def memory_estimate(trainer: Trainer) -> dict[str, int]:
    """Bytes of a run of `trainer.cfg` by part (every seed): "buffers" (replay), "networks"
    (actors, critics, targets, Adam states, the aggregator's models), "env" (env states,
    observations, counters), "activations" (one update of every network at once: batches,
    activations, gradients), "metrics" (host tables of every episode), "worlds", and "total":
    the state parts times STATE_BYTES_FACTOR (a chunk's peak: donated state, outputs, copies)
    plus the others."""
    cfg = trainer.cfg
    d = cfg.offpolicy
    hp = hparams_from_config(cfg)
    shapes = jax.eval_shape(lambda k: trainer.init(k, hp), jax.random.key(0))
    S = cfg.run.seeds
    buffers = nbytes(shapes.buffers) * S
    networks = (nbytes(shapes.agents) + nbytes(shapes.agg_state)) * S
    env = nbytes(shapes) * S - buffers - networks
    activations = activation_bytes(trainer.obs_size, d.hidden, d.depth, d.batch_size) * trainer.n_nets * S
    metrics = cfg.run.episodes * S * cfg.num_robots * METRICS_ROW_BYTES
    worlds = nbytes(trainer.world)
    total = STATE_BYTES_FACTOR * (buffers + networks + env) + activations + metrics + worlds
    return {
        "buffers": buffers,
        "networks": networks,
        "env": env,
        "activations": activations,
        "metrics": metrics,
        "worlds": worlds,
        "total": total,
    }


def check_memory(trainer: Trainer, budget: int | None = None, src: str = "config") -> dict[str, int]:
    """Raise ResourceError when the run's estimate exceeds `budget` bytes (default: the memory
    available now), naming the field behind the largest share of the total; return the estimate."""
    est = memory_estimate(trainer)
    over = over_budget(est["total"], budget)
    if over is None:
        return est
    cfg = trainer.cfg
    buffer_field = "offpolicy.buffer_alloc" if cfg.offpolicy.buffer_alloc else "offpolicy.buffer_size"
    fields = {
        "buffers": buffer_field,
        "networks": "offpolicy.hidden",
        "env": "run.seeds",
        "activations": "offpolicy.batch_size",
        "metrics": "run.episodes",
        "worlds": "env.worlds",
    }
    state = ("buffers", "networks", "env")  # counted STATE_BYTES_FACTOR times in the total
    part = max(fields, key=lambda k: est[k] * (STATE_BYTES_FACTOR if k in state else 1))  # the largest share
    name = fields[part]
    section, key = name.split(".")
    value = getattr(getattr(cfg, section), key)
    parts = ", ".join(f"{k} {size(est[k])}" for k in fields if est[k] >= est["total"] / 100)
    raise ResourceError(
        f"{src}: {name} = {value if part != 'worlds' else len(value)}: the run needs about {size(est['total'])} "
        f"({parts}; {cfg.run.seeds} seed(s)), {over}; lower {name} or run.seeds"
    )
