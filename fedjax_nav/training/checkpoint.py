"""Checkpoints of a whole training run with orbax's CheckpointManager.

A checkpoint at step `e` (episodes completed) holds the stacked TrainState of every seed
(parameters, targets, optimiser states, replay buffers, env states, the exploration carry, PRNG keys) and the
metrics of episodes 0 .. e-1, so a resumed run rebuilds metrics.csv and continues bitwise as the
run that was never interrupted. Saves are asynchronous; a kill during a save leaves a temporary
folder that `latest_step()` ignores, so the previous checkpoint is used; the writer removes such
folders when it opens the checkpoints and after a failed save (a full disk). Every checkpoint also holds
a crc32 of each state array, checked on restore: a damaged file that still decodes is detected,
and the resolved config it was trained with (`saved_config`; `train --resume` compares it with
config.yaml). Errors are one line naming the checkpoint folder: `CheckpointError` when reading,
`rundir.WriteError` when saving (a full disk); orbax's and asyncio's logs are silenced.
"""

from __future__ import annotations

import json
import logging
import math
import re
import sys
import warnings
import zlib
from pathlib import Path

import jax
import numpy as np
import orbax.checkpoint as ocp
from absl import logging as absl_logging

from fedjax_nav import rundir
from fedjax_nav.rundir import WriteError


class CheckpointError(ValueError):
    """A checkpoint is missing, corrupted or incompatible; the message names the path."""


class Checkpointer:
    def __init__(self, run_dir: str | Path, keep: int = 3, async_save: bool = True, process: int | None = None):
        """`process`: in a run of several jax processes, the index of this one; its manager then
        works alone (no barriers with the others): process 0 saves host (numpy) states, every
        process may restore. None: the usual single-process manager."""
        # orbax logs routine events (e.g. removing an unfinished save after a kill) as warnings, and
        # failures (a full disk, a damaged file) as pages of tracebacks from its threads: the
        # user gets one line from the exception instead. After a failed write or read, tensorstore's
        # callbacks into orbax's closed event loop are dropped as well.
        _silence()
        _quiet_abandoned_reads()
        self.dir = Path(run_dir).absolute() / rundir.CHECKPOINTS
        if self.dir.is_symlink() and not self.dir.exists() or self.dir.exists() and not self.dir.is_dir():
            # a file (or a dangling link) there: every save would fail, after the episodes were trained
            raise rundir.RunDirError(f"{self.dir}: exists and is not a directory (the run's checkpoints folder)")
        self.writer = process in (None, 0)
        if self.writer:
            _remove_unfinished(self.dir)  # a save cut short by a kill: never to be completed
        alone = {}
        if process is not None:
            if process == 0:
                self.dir.mkdir(parents=True, exist_ok=True)  # orbax cannot create it with active_processes
            alone = {
                "create": False,
                "multiprocessing_options": ocp.options.MultiprocessingOptions(
                    primary_host=process, active_processes={process}
                ),
            }
        self.manager = ocp.CheckpointManager(
            self.dir,
            # not "metrics": orbax reserves that item name for its JSON best-checkpoint metrics
            item_names=("state", "episode_history"),
            options=ocp.CheckpointManagerOptions(
                max_to_keep=keep, enable_async_checkpointing=async_save, **({"create": True} | alone)
            ),
        )

    def save(self, episodes_done: int, states, metrics: dict, config: dict | None = None) -> None:
        """Save asynchronously; `config` (config.to_dict of the run) is fingerprinted with it."""
        metrics = {k: np.asarray(v) for k, v in metrics.items()}
        metrics[_CRC] = _checksums(states)
        if config is not None:
            metrics[_CONFIG] = np.frombuffer(json.dumps(config, sort_keys=True).encode(), np.uint8)
        with self._writing():
            self.manager.save(
                episodes_done,
                args=ocp.args.Composite(
                    state=ocp.args.StandardSave(_storable(states)), episode_history=ocp.args.StandardSave(metrics)
                ),
            )

    def _writing(self, what: str = "save a checkpoint"):
        """Any failure of a save (now or of an earlier asynchronous one) as one WriteError line."""
        import contextlib

        @contextlib.contextmanager
        def ctx():
            try:
                yield
            except Exception as e:
                _silence()
                self._abandon_failed_save()
                raise WriteError(
                    f"{self.dir}: cannot {what} ({_one_line(e)}); the last complete checkpoint is kept"
                ) from None

        return ctx()

    def _abandon_failed_save(self) -> None:
        """After a failed save: let orbax's threads end, then remove the save's temporary folder
        (it can never complete; the previous checkpoints stay)."""
        try:
            self.manager.wait_until_finished()
        except Exception:  # the same failure, reported once by the caller
            pass
        if self.writer:
            _remove_unfinished(self.dir)

    def saved_config(self, step: int | None = None) -> dict | None:
        """The config (a to_dict mapping) saved with checkpoint `step` (default: the latest); None
        for checkpoints written before configs were saved."""
        step = self.latest() if step is None else step
        if step is None:
            raise CheckpointError(f"{self.dir}: no checkpoint to resume from")
        path = self.dir / str(step) / "episode_history"
        _quiet_abandoned_reads()
        try:
            with ocp.StandardCheckpointer() as ck:
                history = ck.restore(path)
            raw = history.get(_CONFIG)
            return None if raw is None else json.loads(np.asarray(raw, np.uint8).tobytes().decode())
        except Exception as e:
            _silence()
            raise CheckpointError(
                f"{path}: cannot be read; the checkpoint is corrupted or incomplete ({_one_line(e)})"
            ) from None

    def latest(self) -> int | None:
        return self.manager.latest_step()

    def steps(self) -> list[int]:
        """The complete checkpoints (episodes done), oldest first."""
        return sorted(int(s) for s in self.manager.all_steps())

    def remove_after(self, step: int) -> list[int]:
        """Delete every checkpoint newer than `step` (before a resume from `step`: the run saves
        those steps again). Returns the steps deleted."""
        newer = [s for s in self.steps() if s > step]
        with self._writing("remove the newer checkpoints"):
            for s in newer:
                self.manager.delete(s)
            self.manager.reload()
        return newer

    def restore(self, template, step: int | None = None):
        """(states, metrics) of `step` (default: the latest), states shaped like `template`."""
        step = self.latest() if step is None else step
        if step is None:
            raise CheckpointError(f"{self.dir}: no checkpoint to resume from")
        stored = _storable(template)
        abstract = jax.tree.map(ocp.utils.to_shape_dtype_struct, stored)
        path = self.dir / str(step)
        _check_stored_shapes(path, stored)  # before any read: e.g. other network sizes, by field
        _quiet_abandoned_reads()
        try:
            out = self.manager.restore(
                step,
                args=ocp.args.Composite(
                    state=ocp.args.StandardRestore(abstract), episode_history=ocp.args.StandardRestore()
                ),
            )
        except Exception as e:  # orbax raises many types: name the file and what did not match
            # tensorstore could not read (decode) an array: its spec names the file's folder, then the array
            fields = [f.rstrip("/") for f in re.findall(r"'path': '([^']+)'", str(e)) if "/" not in f.rstrip("/")]
            if fields:
                raise CheckpointError(
                    f"{path}: field {fields[-1]} cannot be read; the checkpoint is corrupted or incomplete"
                ) from None
            _silence()
            raise CheckpointError(
                f"{path}: cannot restore this checkpoint into the run's state ({_one_line(e)})"
            ) from None
        out_state = _unstorable(out.state, template)
        _check_shapes(out_state, template, path)
        history = {k: np.asarray(v) for k, v in out.episode_history.items()}
        history.pop(_CONFIG, None)
        saved_crc = history.pop(_CRC, None)
        if saved_crc is not None:  # checkpoints written before checksums existed have none
            crc = _checksums(out_state)
            bad = np.nonzero(crc != saved_crc)[0] if crc.shape == saved_crc.shape else [0]
            if len(bad):
                kp = jax.tree_util.tree_flatten_with_path(out_state)[0][bad[0]][0]
                raise CheckpointError(
                    f"{path}: field {'.'.join(_names(kp))} does not match the checksum saved with "
                    "it; the checkpoint is corrupted"
                )
        return out_state, history

    def restore_intact(self, template, steps, check=None, damaged=None, asked: int | None = None):
        """The first of `steps` (newest first) that restores: (step, states, metrics, damaged),
        `damaged` {step: error line} of those that failed before it (added to the given ones).
        `check(step)`, before each restore: e.g. its saved config against the run's (any
        CheckpointError of it or of the restore: a damaged checkpoint, the next one is tried; other
        errors stop). None restores: `no_intact`'s error."""
        damaged = dict(damaged or {})
        for step in steps:
            try:
                if check is not None:
                    check(step)
                return (step, *self.restore(template, step), damaged)
            except CheckpointError as e:
                damaged[step] = str(e)
        raise self.no_intact(damaged, asked)

    def no_intact(self, damaged: dict, asked: int | None = None) -> CheckpointError:
        """The error when no checkpoint tried restores: the newest one's error line, the older ones
        tried, and (a step `asked` for) the others to ask for instead."""
        newest = max(damaged)
        msg = damaged[newest]
        older = sorted(set(damaged) - {newest}, reverse=True)
        if older:
            msg += f"; the older checkpoints ({', '.join(map(str, older))}) cannot be restored either"
        others = [s for s in self.steps() if s != newest]
        if asked is not None and others:
            msg += f"; resume from another with --from-checkpoint N ({', '.join(map(str, others))})"
        return CheckpointError(msg)

    def wait(self) -> None:
        with self._writing():
            self.manager.wait_until_finished()

    def close(self) -> None:
        with self._writing():
            self.manager.wait_until_finished()
            self.manager.close()


_CRC = "state_crc32"  # key in the episode_history item


def _empty(x) -> bool:
    return math.prod(x.shape) == 0


def _storable(tree):
    """Zero-size leaves (a feed-forward PPO's empty GRU state) as one zero element: orbax refuses
    to save arrays of size 0. `_unstorable` gives them back as the template's own leaves."""
    return jax.tree.map(lambda x: np.zeros((1,), x.dtype) if _empty(x) else x, tree)


def _unstorable(tree, template):
    """The template's leaf for each zero-size one (nothing to restore), placed as the run placed
    it: a numpy stand-in there made the first chunk after a resume on several devices compile
    again once its outputs came back sharded (two traces per resumed PPO sweep, measured)."""
    return jax.tree.map(lambda x, t: t if _empty(t) else x, tree, template)


_CONFIG = "config_json"  # key in the episode_history item: the run's config, as UTF-8 JSON bytes


def finished_steps(run_dir: str | Path) -> list[int]:
    """The complete checkpoints of a run directory (orbax names one `<step>` once it is complete),
    oldest first; read without opening a manager (nothing is created)."""
    d = Path(run_dir) / rundir.CHECKPOINTS
    try:
        return sorted(int(p.name) for p in d.iterdir() if p.name.isdigit() and p.is_dir())
    except OSError:  # no checkpoints folder
        return []


def _remove_unfinished(directory: Path) -> None:
    """Remove the temporary folders of unfinished saves (`<step>.orbax-checkpoint-tmp...`)."""
    import shutil

    try:
        unfinished = [p for p in directory.iterdir() if _UNFINISHED in p.name]
    except OSError:  # not created yet
        return
    for p in unfinished:
        shutil.rmtree(p, ignore_errors=True)


_UNFINISHED = ".orbax-checkpoint-tmp"  # orbax's suffix of a save in progress


def fingerprint(config: dict) -> str:
    """sha1 of a resolved config (`config.to_dict(cfg)`), as saved with every checkpoint."""
    import hashlib

    return hashlib.sha1(json.dumps(config, sort_keys=True).encode()).hexdigest()


def _silence() -> None:
    """Drop orbax's (absl) and asyncio's log records: failures reach the user as one line."""
    absl_logging.set_verbosity(absl_logging.FATAL)
    for name in ("asyncio", "absl", "orbax"):
        logging.getLogger(name).setLevel(logging.CRITICAL)


def _one_line(e: BaseException) -> str:
    """An exception's message in one short line: its first line, without tensorstore's JSON specs."""
    text = (str(e).strip().splitlines() or [""])[0]
    text = re.sub(r"\s*(\[tensorstore_spec|\{).*", "", text).rstrip(" :,;[(") or type(e).__name__
    text = re.sub(r' in OCDBT database at local file "[^"]*"', "", text)  # the path is already in the message
    return text if len(text) <= 160 else text[:157] + "..."


def _names(kp) -> tuple:
    return tuple(str(getattr(k, "name", getattr(k, "key", getattr(k, "idx", k)))) for k in kp)


def _is_key(x) -> bool:
    return jax.dtypes.issubdtype(x.dtype, jax.dtypes.prng_key)


def _checksums(states) -> np.ndarray:
    """crc32 of every leaf (PRNG keys by their key data), in tree order."""

    def raw(x):
        x = np.ascontiguousarray(jax.device_get(jax.random.key_data(x) if _is_key(x) else x))
        return x.reshape(-1).view(np.uint8)

    return np.array([zlib.crc32(raw(x)) for x in jax.tree.leaves(states)], np.uint32)


def _check_stored_shapes(path: Path, template) -> None:
    """Raise a CheckpointError naming the first field whose stored shape differs from the template's."""
    try:
        with ocp.StandardCheckpointer() as ck:
            meta = ck.metadata(path / "state").item_metadata
        stored = {
            _names(kp): tuple(v.shape) for kp, v in jax.tree_util.tree_flatten_with_path(meta)[0] if hasattr(v, "shape")
        }
    except Exception:  # unreadable metadata: the caller reports the original error
        return
    for kp, t in jax.tree_util.tree_flatten_with_path(template)[0]:
        name = _names(kp)
        if not _is_key(t) and name in stored and stored[name] != tuple(np.shape(t)):
            raise CheckpointError(
                f"{path}: field {'.'.join(name)} has shape {list(stored[name])}, the config needs "
                f"{list(np.shape(t))} (were the network sizes, robots, seeds or buffer changed?)"
            )


def _quiet_abandoned_reads() -> None:
    """When a restore fails, orbax closes its event loop while other tensorstore reads are still
    in flight; they report into the closed loop through sys.unraisablehook, at any time from then
    on (tracebacks around the one-line error), and the reads never started warn at exit. Drop those
    reports (installed once, before restores)."""
    warnings.filterwarnings("ignore", message=r"coroutine '.*' was never awaited", category=RuntimeWarning)
    prev = sys.unraisablehook
    if getattr(prev, "_fedjax_nav", False):
        return

    def hook(u):
        msg = str(u.exc_value)
        if msg == "Event loop is closed" or "error while reading array" in msg:
            return
        prev(u)

    hook._fedjax_nav = True
    sys.unraisablehook = hook


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
