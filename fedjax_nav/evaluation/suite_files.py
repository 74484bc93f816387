"""The rooms of a held-out suite evaluation (`fedjax-nav evaluate RUN --suite NAME|DIR|GLOB`): a
named suite's generated rooms (`fedjax_nav.worlds.suites`), or every world file of a folder or glob,
padded to one shape, its file name stem as its family; and the folder under RUN/eval/ an evaluation
on it is kept in. `evaluation.suite` evaluates them; `evaluation.worst_rooms` rebuilds them.
"""

from __future__ import annotations

import glob
from pathlib import Path

import numpy as np

from fedjax_nav import worlds as _worlds
from fedjax_nav.evaluation.limits import EvalError
from fedjax_nav.messages import show
from fedjax_nav.worlds import WorldError, input_files
from fedjax_nav.worlds.suites import SUITE_GROUPS, SUITES, suite_rooms

WORLD_SUFFIXES = (".json", ".yaml", ".yml")  # the world files of a folder (worlds.load's formats)


def is_file_suite(suite: str) -> bool:
    """Whether `--suite` names world files (a folder, a glob, a path) rather than a named suite: a
    suite or group name wins; otherwise a glob character, a path separator or an existing path."""
    if suite in SUITES or suite in SUITE_GROUPS:
        return False
    try:
        exists = Path(suite).exists()
    except (OSError, ValueError):  # a NUL byte, an over-long name: not a path, so a name (refused as one)
        exists = False
    return any(c in suite for c in "*?[/\\") or exists


def suite_folder(suite: str) -> str:
    """The folder name of an evaluation on `suite` under RUN/eval/: a named suite's name; a file
    suite's folder (a folder's own name; a glob's or a file's: the folder holding it)."""
    if not is_file_suite(suite):
        return suite
    p = Path(suite)
    if not p.is_dir():
        head = []
        for part in p.parts[:-1]:
            if any(c in part for c in "*?["):
                break
            head.append(part)
        p = Path(*head) if head else Path(".")
    return p.resolve().name or "suite"


def world_files(suite: str) -> list[Path]:
    """The world files of a file suite, sorted: a folder's entries named *.json, *.yaml, *.yml (not
    recursive), or those among a glob's matches. None: an EvalError naming the folder or glob. An
    entry so named that is not a regular file (a symlink loop, a link to a missing file, a FIFO, a
    folder, ...) is not left out: an EvalError naming it (docs/evaluation.md: a file that does not
    load refuses the suite; a suite with a room missing would report fewer rooms)."""
    p = Path(suite)
    try:
        folder = p.is_dir()
        found = p.iterdir() if folder else (Path(f) for f in glob.glob(suite))
        files = sorted(f for f in found if f.suffix.lower() in WORLD_SUFFIXES)
    except (OSError, ValueError) as e:  # a folder that cannot be listed, a NUL byte, an over-long name
        why = getattr(e, "strerror", None) or type(e).__name__
        msg = f"--suite {show(suite, 240)}: cannot be read as a folder or glob of world files ({why})"
        raise EvalError(msg) from None
    for f in files:
        try:
            input_files.check_regular(f, "world")
        except input_files.InputError as e:
            raise EvalError(
                f"{f}: {e} (--suite {show(suite, 240)}: every *.json, *.yaml, *.yml there is read as a room)"
            ) from None
    if not files:
        kinds = ", ".join(f"*{x}" for x in WORLD_SUFFIXES)
        where = "in this folder" if folder else "matches this folder, glob or file"
        raise EvalError(f"--suite {show(suite, 240)}: no world file ({kinds}) {where}")
    return files


def file_suite(suite: str) -> tuple:
    """The rooms of a folder or glob of world files as one stacked World (`worlds.stack`: padded to
    one shape), each room's family (its file name stem; the file name where two stems are equal),
    room seeds (-1: none) and the files. A file that does not load: an EvalError naming it."""
    files = world_files(suite)
    try:
        loaded = [_worlds.load(f) for f in files]
    except WorldError as e:
        raise EvalError(str(e)) from None
    stems = [f.stem for f in files]
    fams = np.asarray([f.stem if stems.count(f.stem) == 1 else f.name for f in files])
    return _worlds.stack(loaded), fams, np.full(len(files), -1, np.int64), [str(f) for f in files]


def suite_world(suite: str) -> tuple:
    """The rooms of `suite` (a suite or group name: `worlds.suites.suite_rooms`; a folder or glob:
    `file_suite`) as one stacked World [rooms, ...], with each room's family and room seed, in the
    order of an evaluation's room index."""
    if is_file_suite(suite):
        return file_suite(suite)[:3]
    return suite_rooms(suite)
