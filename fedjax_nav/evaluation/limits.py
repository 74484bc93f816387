"""What an evaluation may ask for, checked before anything is allocated or compiled
(docs/reliability.md, "Memory: evaluation and activations").

    check_counts(attempts, max_steps)                        --attempts, --max-steps: integers >= 1
    eval_memory(env_settings, episode_state, episodes)       peak bytes by part, from shapes
    check_eval_memory(env_settings, episode_state, shape)    EvalError beyond the budget

The trajectories f32[..., T + 1, 3] grow with attempts x T and the episode states with agents x
goals x attempts (x rooms for a suite): both are estimated from shapes and compared with the budget
by `config.memory.over_budget`, the rule `train` refuses by. `episode_state` is the shapes of one
episode's running state (`rollout.episode_state`).
"""

from __future__ import annotations

import jax
import numpy as np

from fedjax_nav.config.memory import nbytes, over_budget, size

MAX_STEPS = 2**31 - 2  # the time-out T: the step counters are int32
# Host bytes per evaluated episode: its row of the episodes frame (18 columns, one of them text),
# the arrays it is built from, and its CSV line.
EVAL_ROW_BYTES = 512


class EvalError(ValueError):
    """An evaluation input (run directory, params file, setting) is invalid; the message says which."""


def check_counts(attempts, max_steps=None) -> None:
    """--attempts and --max-steps (None: the run's T) as the protocol takes them: integers >= 1,
    T within int32 (the step counters); else an EvalError naming the flag."""
    if not (isinstance(attempts, (int, np.integer)) and attempts >= 1):
        raise EvalError(f"--attempts: must be an integer >= 1, got {attempts!r}")
    if max_steps is not None and not (isinstance(max_steps, (int, np.integer)) and 1 <= max_steps <= MAX_STEPS):
        raise EvalError(f"--max-steps: must be an integer in [1, {MAX_STEPS:,}], got {max_steps!r}")


def eval_memory(env_settings: dict, episode_state, episodes: int, chunk: int) -> dict[str, int]:
    """Peak bytes of `episodes` episodes of the evaluation program under `env_settings` (its
    episode_length is T; steps run in scans of `chunk`), by part:

    "trajectories": the poses f32[E, T + 1, 3] three times (the program's chunk buffer, its output,
    the host copy; XLA CPU's output + temporaries measure 2.0-2.1x the poses), "episodes": each
    episode's running state (`episode_state`, shapes) three times (the carry, the stepped state and
    the select between them; measured 2.6-2.9x, lidar included) and its key, "host": the episodes
    table (`EVAL_ROW_BYTES` each), and "total"."""
    T, E = int(env_settings["episode_length"]), int(episodes)
    chunk = min(int(chunk), T)
    pose_rows = -(-T // chunk) * chunk + 2 * (T + 1)
    out = {
        "trajectories": E * pose_rows * 3 * 4,
        "episodes": E * (3 * nbytes(episode_state) + nbytes(jax.random.key(0))),
        "host": E * EVAL_ROW_BYTES,
    }
    return {**out, "total": sum(out.values())}


def check_eval_memory(
    env_settings: dict,
    episode_state,
    shape: tuple[int, ...],
    chunk: int,
    attempts_asked: int | None = None,
    budget: int | None = None,
    src: str = "evaluation",
) -> dict[str, int]:
    """Raise EvalError when `eval_memory` of the episodes `shape` ((rooms,) agents, goals, attempts
    per agent) exceeds `budget` bytes (default: the memory available now), naming --attempts (the
    value asked, `attempts_asked`; default the last axis) and --max-steps; return the estimate."""
    episodes = int(np.prod(shape, dtype=object))
    est = eval_memory(env_settings, episode_state, episodes, chunk)
    over = over_budget(est["total"], budget)
    if over is None:
        return est
    T = int(env_settings["episode_length"])
    names = ("rooms", "agents", "goals", "attempts")[-len(shape) :]
    product = " x ".join(f"{n} {k}" for n, k in zip(shape, names))
    asked = shape[-1] if attempts_asked is None else attempts_asked
    raise EvalError(
        f"{src}: --attempts {asked}, --max-steps {T}: the evaluation needs about {size(est['total'])} "
        f"({product} = {episodes:,} episodes of up to {T} steps: trajectories {size(est['trajectories'])}, "
        f"episode states {size(est['episodes'])}), {over}; lower --attempts or --max-steps"
    )
