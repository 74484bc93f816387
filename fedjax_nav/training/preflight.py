"""What a training run refuses before its loop starts, and where a resumed run may start.

A new run refuses a folder that holds results (`check_new_folder`, unless `overwrite`) or
checkpoints (`refuse_held_checkpoints`). A resumed run refuses a config that differs from the one
fingerprinted in its checkpoint, except the `RESUME_CHANGEABLE` fields with
`--allow-config-change`: `refuse_config_change` is the one refusal, called by `fedjax-nav train
--resume` before it loads anything and by `check_resumable` against each checkpoint tried;
`plan_resume` picks the checkpoints to try (`Resume`). The memory refusal is
`fedjax_nav.training.resources.check_memory`. The run itself is `fedjax_nav.training.run`.
Nothing here allocates or compiles.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from fedjax_nav import rundir
from fedjax_nav.config import Config, ConfigError
from fedjax_nav.learner_table import bound_fields

# Fields `train --resume RUN --allow-config-change` may change against the config fingerprinted in
# the run's checkpoint (none changes the program or the numbers of a finished episode): these and
# every learner's divergence bounds (learner_table.Bound), read on the host after each chunk.
RESUME_CHANGEABLE = (
    "run.episodes",
    "run.checkpoint_every",
    "run.keep_checkpoints",
    "run.tensorboard",
    *bound_fields(),
)


# ----------------------------------------------------------------------------- a new run


def check_new_folder(out: Path, overwrite: bool) -> None:
    """A new run's folder `out`: `FileExistsError` (exit 2, naming what it holds and the ways out)
    when it holds results (`rundir.RESULTS`), a run stopped before its first checkpoint included;
    with `overwrite`, they are removed instead."""
    from fedjax_nav.training.checkpoint import finished_steps

    held = rundir.results_in(out)
    if not held:
        return
    if not overwrite:
        if rundir.CONFIG in held and not finished_steps(out):
            raise FileExistsError(
                f"{out}: holds a run stopped before its first checkpoint ({', '.join(held)}); resume it with "
                f"--resume {out} (it starts again from episode 0), pick another --out, or pass --overwrite"
            )
        raise FileExistsError(
            f"{out}: already holds results ({', '.join(held)}); resume it with --resume "
            f"{out}, pick another --out, or pass --overwrite to replace them"
        )
    rundir.clear_results(out)


def refuse_held_checkpoints(ckpt, out: Path) -> None:
    """A new run whose `Checkpointer` `ckpt` finds checkpoints in `out`: `FileExistsError`."""
    if ckpt.latest() is not None:
        raise FileExistsError(f"{out}: already holds checkpoints; resume it with --resume {out} or pick another --out")


# ----------------------------------------------------------------------------- a resumed run


def refuse_config_change(changed, allow_config_change: bool, path: str | Path, against: str) -> None:
    """The one refusal of a resume with a changed config (`fedjax-nav train --resume` before it
    loads anything, `train(resume=True)` against the checkpoint): `ConfigError` (exit 2) naming
    `path`, what it was compared `against` and every field of `changed` (dotted names) that
    `allow_config_change` does not permit: all of them without it, those outside
    `RESUME_CHANGEABLE` with it. Returns when nothing is refused."""
    refused = [k for k in changed if not (allow_config_change and k in RESUME_CHANGEABLE)]
    if not refused:
        return
    sections: dict[str, list[str]] = {}
    for k in RESUME_CHANGEABLE:
        sections.setdefault(k.split(".")[0], []).append(k.split(".", 1)[1])
    permitted = ", ".join(f"{s}.{{{', '.join(names)}}}" for s, names in sections.items())  # run.{episodes, ...}
    hint = (
        f"--allow-config-change permits {permitted} only"
        if allow_config_change
        else f"restore the config, start a new run, or pass --allow-config-change (it permits {permitted} only)"
    )
    raise ConfigError(f"{path}: differs from {against} in {', '.join(refused)}; resuming would mix two runs: {hint}")


def check_resumable(ckpt, cfg: Config, out: Path, allow_config_change: bool, step: int | None = None) -> None:
    """The config to resume with against the one fingerprinted in checkpoint `step` (default: the
    latest; `CheckpointError` when there is none or its history cannot be read)."""
    from fedjax_nav.config import diff, from_dict
    from fedjax_nav.training.checkpoint import fingerprint

    step = ckpt.latest() if step is None else step
    saved = ckpt.saved_config(step)
    if saved is not None:
        src = f"{ckpt.dir / str(step)}"
        try:
            changed = diff(from_dict(saved, src), cfg)
        except ConfigError:  # saved by another version of the code: compare what it holds
            now = to_dict_flat(cfg)
            changed = [k for k, v in to_dict_flat(saved).items() if k in now and now[k] != v]
        against = f"the config saved in {src} (sha1 {fingerprint(saved)[:12]})"
        refuse_config_change(changed, allow_config_change, out / rundir.CONFIG, against)
    if cfg.run.episodes < step:
        raise ConfigError(
            f"{out / rundir.CONFIG}: run.episodes ({cfg.run.episodes}) is below the {step} episodes already done"
        )


@dataclass(frozen=True)
class Resume:
    """Where a resumed run may start: `steps`, the checkpoints to try newest first (empty: none is
    complete, start again from episode 0); `damaged`, newer ones already found unreadable
    ({step: error line}); `asked`, the step of `--from-checkpoint` (no fallback) or None."""

    steps: tuple[int, ...]
    damaged: dict
    asked: int | None
    allow_config_change: bool


def plan_resume(ckpt, cfg: Config, out: Path, allow_config_change: bool, asked: int | None) -> Resume:
    """Before anything is allocated: the newest checkpoint (or `asked`) whose saved config can be
    read is checked against `cfg` (`check_resumable`; a changed config is refused here, never
    fallen back from); newer ones whose history cannot be read are noted as damaged."""
    from fedjax_nav.training.checkpoint import CheckpointError

    steps = ckpt.steps()[::-1]
    if asked is not None:
        if asked not in steps:
            held = ", ".join(map(str, steps[::-1])) or "none"
            raise CheckpointError(f"{ckpt.dir}: no checkpoint {asked} (--from-checkpoint); complete ones: {held}")
        steps = [asked]
    damaged = {}
    for i, step in enumerate(steps):
        try:
            check_resumable(ckpt, cfg, out, allow_config_change, step)
        except CheckpointError as e:
            damaged[step] = str(e)
            continue
        return Resume(tuple(steps[i:]), damaged, asked, allow_config_change)
    if steps:
        raise ckpt.no_intact(damaged, asked)
    return Resume((), {}, asked, allow_config_change)


def to_dict_flat(cfg) -> dict:
    """{"offpolicy.gamma": 0.9, ...} of a Config or of its to_dict mapping (an offpolicy field saved
    under its old name, `ddpg.gamma`, by its name now: config.canonical)."""
    from fedjax_nav.config import canonical, to_dict

    d = cfg if isinstance(cfg, dict) else to_dict(cfg)
    return {
        canonical(f"{s}.{k}") if isinstance(sec, dict) else s: v
        for s, sec in d.items()
        for k, v in (sec.items() if isinstance(sec, dict) else [(s, sec)])
    }
