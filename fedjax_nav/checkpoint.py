"""Checkpoints of a whole training run with orbax's CheckpointManager.

A checkpoint at step `e` (episodes completed) holds the stacked TrainState of every seed
(parameters, targets, optimiser states, replay buffers, env states, epsilon, PRNG keys) and the
metrics of episodes 0 .. e-1, so a resumed run rebuilds metrics.csv and continues bitwise as the
run that was never interrupted. Saves are asynchronous; a kill during a save leaves a temporary
folder that `latest_step()` ignores, so the previous checkpoint is used.
"""
from __future__ import annotations

from pathlib import Path

import jax
import numpy as np
import orbax.checkpoint as ocp
from absl import logging as absl_logging


class CheckpointError(ValueError):
    """A checkpoint is missing, corrupted or incompatible; the message names the path."""


class Checkpointer:
    def __init__(self, run_dir: str | Path, keep: int = 3, async_save: bool = True):
        # orbax logs routine events (e.g. removing an unfinished save after a kill) as warnings.
        absl_logging.set_verbosity(absl_logging.ERROR)
        self.dir = Path(run_dir).absolute() / "checkpoints"
        self.manager = ocp.CheckpointManager(
            self.dir,
            # not "metrics": orbax reserves that item name for its JSON best-checkpoint metrics
            item_names=("state", "episode_history"),
            options=ocp.CheckpointManagerOptions(max_to_keep=keep, enable_async_checkpointing=async_save,
                                                 create=True),
        )

    def save(self, episodes_done: int, states, metrics: dict) -> None:
        metrics = {k: np.asarray(v) for k, v in metrics.items()}
        self.manager.save(
            episodes_done,
            args=ocp.args.Composite(state=ocp.args.StandardSave(states), episode_history=ocp.args.StandardSave(metrics)),
        )

    def latest(self) -> int | None:
        return self.manager.latest_step()

    def restore(self, template, step: int | None = None):
        """(states, metrics) of `step` (default: the latest), states shaped like `template`."""
        step = self.latest() if step is None else step
        if step is None:
            raise CheckpointError(f"{self.dir}: no checkpoint to resume from")
        abstract = jax.tree.map(ocp.utils.to_shape_dtype_struct, template)
        path = self.dir / str(step)
        try:
            out = self.manager.restore(
                step, args=ocp.args.Composite(state=ocp.args.StandardRestore(abstract),
                                              episode_history=ocp.args.StandardRestore()),
            )
        except Exception as e:  # orbax raises many types: name the file and what did not match
            msg = str(e).splitlines()[0][:300] if str(e) else type(e).__name__
            raise CheckpointError(f"{path}: cannot restore this checkpoint into the run's state ({msg})") from None
        _check_shapes(out.state, template, path)
        return out.state, {k: np.asarray(v) for k, v in out.episode_history.items()}

    def wait(self) -> None:
        self.manager.wait_until_finished()

    def close(self) -> None:
        self.manager.wait_until_finished()
        self.manager.close()


def _check_shapes(restored, template, path: Path) -> None:
    flat_r = jax.tree_util.tree_flatten_with_path(restored)[0]
    flat_t = jax.tree_util.tree_flatten_with_path(template)[0]
    if len(flat_r) != len(flat_t):
        raise CheckpointError(f"{path}: holds {len(flat_r)} arrays, the run's state has {len(flat_t)}")
    for (kp, r), (_, t) in zip(flat_r, flat_t):
        if np.shape(r) != np.shape(t):
            name = jax.tree_util.keystr(kp)
            raise CheckpointError(
                f"{path}: field {name} has shape {list(np.shape(r))}, the config needs {list(np.shape(t))} "
                "(were the network sizes, robots, seeds or buffer changed?)"
            )
