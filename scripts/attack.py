"""The attack battery of docs/reliability.md ("Re-running the attack"): bad command lines,
out-of-range config and world values, kill -9 and resume, concurrent writers, and hostile disks,
run against the real `fedjax-nav`, with a summary at the end.

    python scripts/attack.py --out /tmp/attack                      # every category (~25 min on 2 cores)
    python scripts/attack.py --out /tmp/attack --only cli,disk      # some of them
    python scripts/attack.py --out /tmp/attack --only cli --limit 20 --csv ''   # a smoke test

Categories (`CATEGORIES`):
  cli          bad command lines, derived from the parser (`fedjax_nav.cli.parser.build_parser`): for
               every command, unknown flags, missing and extra positionals, and for every flag bad
               values of its kind (counts: -1, 0, 1e20, nan, inf, text, empty; paths: missing, a
               directory, a FIFO, /dev/zero, a symlink loop, ...), then the tables of bad `--set`
               values, config, sweep and world files below.
  config       in-process: every config field with bounds (`lo`/`hi`/`choices`, its type) given a value
               below, above, beyond int32/float32, non-finite or of the wrong type, through
               `load_config(..., [--set])` and `from_dict`; and world-file numbers (`worlds.load`).
  kill         SIGKILL of a tiny `train` at varied moments (before its config, while a checkpoint is
               written, after one, while it finishes), then `train --resume`: exit 0 and params.npz
               equal to an uninterrupted run's (np.array_equal).
  concurrency  two writers on one run directory, evaluate against train, stale / empty / foreign locks.
  disk         read-only folders, a full disk (a small tmpfs: needs root; skipped otherwise), symlink
               loops, corrupted and truncated checkpoints and params.npz.

Every command runs as a subprocess (`python -m fedjax_nav.cli`) in its own session under a
wall-clock timeout and an address-space cap (RLIMIT_AS, `--mem`), so that a regression shows up as
a failing case instead of a hung shell or an OOM-killed machine. A case fails on: "Traceback" in its
output, a timeout (a hang), death by a signal, an exit code other than the one expected (0 where it
should be refused, a refusal where it should run, or a code outside the refusal's), or a refusal
that is not exactly one `error: ...` line on stderr. In-process cases fail on any exception other
than the one-line ConfigError / WorldError, or on accepting a value outside the field's bounds.

Training cases use the tiny settings (`TINY`: 3 episodes x 64 steps) and share the persistent
compilation cache (JAX_COMPILATION_CACHE_DIR, default ~/.cache/fedjax_nav_jax), so each is seconds.
Per-case records go to OUT/cases.jsonl; the summary to --csv (default results/attack_summary.csv for the whole
battery, OUT/summary.csv for a part of it).
"""

from __future__ import annotations

import argparse
import collections
import concurrent.futures
import csv
import json
import math
import os
import random
import resource
import shlex
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CATEGORIES = ("cli", "config", "kill", "concurrency", "disk")
TINY = ["--episodes", "3", "--set", "env.episode_length=64", "--set", "offpolicy.batch_size=16"]
TINY += ["--set", "offpolicy.buffer_size=256", "--set", "run.chunk_episodes=1"]
TINY_CKPT = TINY + ["--set", "run.checkpoint_every=1"]  # the kill trials' run: a checkpoint per episode
LONG = "a" * 5000  # a file name no system can look up
HUGE_INT = "99999999999999999999"  # 1e20: beyond int64
TRACEBACK = "Traceback (most recent call last)"


# ----------------------------------------------------------------------------- cases and outcomes


@dataclass
class Case:
    """One command line. expect: "refuse" (an exit code in `codes`, one `error:` line), "ok" (exit 0)
    or "any" (either). `setup(case_dir)` prepares its files before it runs."""

    category: str
    name: str
    argv: list[str]
    expect: str = "refuse"
    codes: tuple[int, ...] = (2,)
    timeout: float = 60.0
    setup: object = None
    prog: tuple[str, ...] = (sys.executable, "-m", "fedjax_nav.cli")


@dataclass
class Outcome:
    """What one case (or one step of a multi-process trial) did, and why it failed (empty: passed)."""

    category: str
    name: str
    command: str
    rc: int | None
    wall_s: float
    failures: list[str] = field(default_factory=list)
    note: str = ""

    def as_row(self) -> dict:
        return dict(self.__dict__)


def show_argv(argv) -> str:
    """A command line for a person: long arguments cut to 80 characters."""
    cut = [a if len(a) <= 80 else f"{a[:60]}...({len(a):,} chars)" for a in map(str, argv)]
    return shlex.join(["fedjax-nav", *cut])


class Runner:
    """Runs subprocesses under the timeout and the memory cap, in a scratch working folder."""

    def __init__(self, out: Path, mem_bytes: int, timeout_scale: float = 1.0):
        self.out, self.mem, self.scale = out, mem_bytes, timeout_scale
        self.cwd = out / "cwd"  # stray writes (e.g. `--out ''`) land here, never in the repository
        self.cwd.mkdir(parents=True, exist_ok=True)
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        env.setdefault("JAX_PLATFORMS", "cpu")
        env.setdefault("JAX_COMPILATION_CACHE_DIR", str(Path.home() / ".cache" / "fedjax_nav_jax"))
        self.env = env
        self.live: set[subprocess.Popen] = set()

    def _limits(self):
        resource.setrlimit(resource.RLIMIT_AS, (self.mem, self.mem))

    def popen(self, argv, prog=(sys.executable, "-m", "fedjax_nav.cli")) -> subprocess.Popen:
        proc = subprocess.Popen(
            [*prog, *map(str, argv)],
            cwd=self.cwd,
            env=self.env,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            preexec_fn=self._limits,
            start_new_session=True,  # a timeout kills the whole group
        )
        self.live.add(proc)
        return proc

    def kill_all(self) -> None:
        """Kill every process group still running (the battery was interrupted)."""
        for proc in list(self.live):
            if proc.poll() is None:
                with _quiet():
                    os.killpg(proc.pid, signal.SIGKILL)

    def finish(self, proc: subprocess.Popen, timeout: float) -> tuple[int | None, str, str, bool]:
        """Wait for `proc`: (rc, stdout, stderr, timed_out); a process past its timeout is killed."""
        try:
            out, err = proc.communicate(timeout=timeout * self.scale)
            timed_out = False
        except subprocess.TimeoutExpired:
            with _quiet():
                os.killpg(proc.pid, signal.SIGKILL)
            out, err = proc.communicate()
            timed_out = True
        self.live.discard(proc)
        dec = lambda b: b.decode("utf-8", "replace")  # noqa: E731
        return proc.returncode, dec(out), dec(err), timed_out

    def run(self, argv, timeout: float, prog=(sys.executable, "-m", "fedjax_nav.cli")):
        t = time.monotonic()
        rc, out, err, timed_out = self.finish(self.popen(argv, prog), timeout)
        return rc, out, err, timed_out, time.monotonic() - t


class _quiet:
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return exc[0] is not None and issubclass(exc[0], OSError)


def judge(rc, out: str, err: str, timed_out: bool, expect: str, codes=(2,)) -> list[str]:
    """Why a finished command failed (empty: it passed); see the module docstring."""
    why = []
    if timed_out:
        return ["hang"] + (["traceback"] if TRACEBACK in err + out else [])
    if TRACEBACK in err or TRACEBACK in out:
        why.append("traceback")
    if rc is not None and rc < 0:
        why.append(f"signal {signal.Signals(-rc).name if -rc in signal.Signals._value2member_map_ else -rc}")
        return why
    if expect == "refuse" and rc == 0:
        why.append("wrong exit: 0 where it should be refused")
    elif expect == "ok" and rc != 0:
        why.append(f"wrong exit: {rc} where it should run")
    elif rc not in (0, *codes):
        why.append(f"wrong exit: {rc} (a refusal is {'/'.join(map(str, codes))})")
    if rc not in (0, None):
        lines = [ln for ln in err.splitlines() if ln.strip()]
        if len(lines) != 1 or not lines[0].startswith("error: "):
            why.append(f"multi-line error ({len(lines)} lines)")
    return why


def run_case(runner: Runner, case: Case) -> Outcome:
    case_dir = runner.out / case.category / case.name
    case_dir.mkdir(parents=True, exist_ok=True)
    if case.setup is not None:
        case.setup(case_dir)
    argv = [str(a).replace("{dir}", str(case_dir)) for a in case.argv]
    try:
        rc, out, err, timed_out, wall = runner.run(argv, case.timeout, case.prog)
    except (OSError, ValueError) as e:  # an argument the system refuses to pass (E2BIG, NUL)
        return Outcome(case.category, case.name, show_argv(argv), None, 0.0, [f"not started: {e}"])
    why = judge(rc, out, err, timed_out, case.expect, case.codes)
    note = (err.strip().splitlines() or [""])[-1][:300]
    return Outcome(case.category, case.name, show_argv(argv), rc, wall, why, note)


# ----------------------------------------------------------------------------- fixtures


ALIAS_BOMB = "a: &a [x, x, x, x, x, x, x, x, x]\n" + "".join(
    f"{c}: &{c} [{', '.join([f'*{p}'] * 9)}]\n" for p, c in zip("abcdefgh", "bcdefghi")
)


class Fixtures:
    """The files the cases point at: special paths, bad config / sweep / world files, and one
    tiny trained run (`run`, TINY_CKPT: checkpoints 1-3) that is the kill trials' reference too."""

    def __init__(self, out: Path):
        d = self.dir = out / "fixtures"
        d.mkdir(parents=True, exist_ok=True)
        self.missing = str(d / "no-such-file.yaml")
        self.directory = str(d / "a-directory")
        os.makedirs(self.directory, exist_ok=True)
        self.fifo = str(d / "a-fifo")
        if not os.path.exists(self.fifo):
            os.mkfifo(self.fifo)
        self.loop = str(d / "a-loop")
        if not os.path.lexists(self.loop):
            os.symlink(self.loop, self.loop)
        self.empty = self._write("empty.yaml", "")
        self.garbage = self._write("garbage.yaml", b"\xff\xfe\x00\x81 not utf-8 \xc3\x28")
        self.file = self._write("a-file", "x\n")
        self.under_file = str(Path(self.file) / "sub")
        self.tiny = self._write(
            "tiny.yaml", "env: {episode_length: 64}\noffpolicy: {batch_size: 16, buffer_size: 256}\n"
        )
        self.sweep = self.sweep_file("ok", {})
        self.run = d / "run"

    def _write(self, name: str, content) -> str:
        path = self.dir / name
        if isinstance(content, bytes):
            path.write_bytes(content)
        else:
            path.write_text(content)
        return str(path)

    def config_file(self, name: str, text) -> str:
        return self._write(f"config-{name}.yaml", text)

    def sweep_file(self, name: str, fields: dict, raw: str | None = None) -> str:
        """A tiny sweep (one point, one seed, 3 episodes) with `fields` replaced, or `raw` text."""
        import yaml

        spec = {
            "name": f"t-{name}",
            "base": self.tiny if hasattr(self, "tiny") else None,
            "grid": {"fed.tau": [0.5]},
            "seeds": 1,
            "set": ["run.episodes=3", "run.chunk_episodes=1"],
        }
        spec.update(fields)
        spec = {k: v for k, v in spec.items() if v is not _DROP}
        return self._write(f"sweep-{name}.yaml", raw if raw is not None else yaml.safe_dump(spec))

    def world_file(self, name: str, spec, suffix: str = ".json") -> str:
        import yaml

        text = json.dumps(spec) if suffix == ".json" else yaml.safe_dump(spec)
        return self._write(f"world-{name}{suffix}", text)

    def train_reference(self, runner: Runner) -> None:
        """The uninterrupted tiny run (TINY_CKPT); built once, reused by later invocations."""
        if (self.run / "summary.json").exists() and (self.run / "params.npz").exists():
            return
        shutil.rmtree(self.run, ignore_errors=True)
        rc, _, err, timed_out, _ = runner.run(["train", "--quiet", "--out", self.run, *TINY_CKPT], 600)
        if rc != 0:
            raise SystemExit(f"the reference run failed (rc {rc}, timed out {timed_out}): {err[-2000:]}")

    def copy_run(self, dest: Path, checkpoints: bool = False) -> Path:
        """A private copy of the reference run (each case its own: evaluate takes the run's lock)."""
        shutil.rmtree(dest, ignore_errors=True)
        ignore = None if checkpoints else shutil.ignore_patterns("checkpoints", "eval", ".lock")
        shutil.copytree(self.run, dest, ignore=ignore, symlinks=True)
        return dest


_DROP = object()  # a sweep field to leave out


BASE_WORLD = {
    "name": "w",
    "size": [6.0, 6.0],
    "boxes": [[1.5, -1.5, 0.5, 0.5, 0.3]],
    "segments": [[-2.0, 2.0, -1.0, 2.0]],
    "circles": [[0.0, 0.0, 0.2]],
    "starts": [[2.0, 2.15, 3.1416]],
    "goals": [[-2.0, -1.85]],
}
# One bad number at a time, in every column of every numeric field of a world file.
WORLD_NUMBERS = {
    "1e39": 1e39,
    "-1e39": -1e39,
    "1e300": 1e300,
    "1e5": 1e5,
    "nan": float("nan"),
    "inf": float("inf"),
    "-inf": float("-inf"),
    "text": "abc",
    "num-text": "3",  # numpy would parse it
    "bool": True,  # numpy would read it as 1.0
    "null": None,
    "list": [1.0],
}


def world_variants():
    """(name, spec) of world files each holding one bad number (all must be refused)."""
    for fld in ("size", "boxes", "segments", "circles", "starts", "goals"):
        row = BASE_WORLD[fld] if fld == "size" else BASE_WORLD[fld][0]
        for col in range(len(row)):
            for label, value in WORLD_NUMBERS.items():
                spec = json.loads(json.dumps(BASE_WORLD))
                target = spec[fld] if fld == "size" else spec[fld][0]
                target[col] = value
                yield f"{fld}{col}-{label}", spec


def world_shapes():
    """(name, spec or raw text) of world files wrong in shape rather than in a number."""
    base = BASE_WORLD
    yield "empty-object", {}
    yield "a-list", [1, 2]
    yield "row-too-short", {**base, "circles": [[0.0, 0.0]]}
    yield "rows-not-a-list", {**base, "starts": 5}
    yield "no-starts", {**base, "starts": []}
    yield "name-not-text", {**base, "name": [1, 2]}
    yield "unknown-field", {**base, "walls": []}
    yield "5001-circles", {**base, "circles": [[2.5, -2.5, 0.01]] * 5001}
    yield "deep-nesting", "[" * 100000 + "]" * 100000
    yield "start-outside", {**base, "starts": [[100.0, 0.0, 0.0]]}
    yield "size-booleans", {**base, "size": [True, True]}
    yield "size-texts", {**base, "size": ["6", "6"]}


# ----------------------------------------------------------------------------- 1. command lines


def verbs(parser) -> dict[str, argparse.ArgumentParser]:
    """Every command's parser by its words ("train", "worlds generate"), from the subparsers."""
    out = {}

    def walk(p, words):
        subs = [a for a in p._actions if isinstance(a, argparse._SubParsersAction)]
        if not subs:
            out[" ".join(words)] = p
            return
        for name, sp in subs[0].choices.items():
            walk(sp, [*words, name])

    walk(parser, [])
    return out


# Each command's valid, cheap command line; a case changes one thing in it. "{dir}" is the case's folder.
def bases(fx: Fixtures) -> dict[str, dict]:
    return {
        "train": {"pos": [], "flags": {"--quiet": None, "--out": "{dir}/run"}, "tail": TINY, "timeout": 180},
        "evaluate": {"pos": ["{dir}/run"], "flags": {"--no-figures": None, "--out": "{dir}/eval"}, "timeout": 180},
        "render": {"pos": ["train-0"], "flags": {"--steps": "10", "--out": "{dir}/png"}, "timeout": 120},
        "sweep": {"pos": [fx.sweep], "flags": {"--quiet": None, "--out": "{dir}/sweep"}, "timeout": 180},
        "reproduce": {"pos": [], "flags": {"--quiet": None, "--only": "tau", "--out": "{dir}/rep"}},
        "bench": {"pos": ["env"], "flags": {"--quick": None}},
        "export": {"pos": ["{dir}/run"], "flags": {"--out": "{dir}/exp"}, "timeout": 120},
        "worlds generate": {"pos": [], "flags": {"--family": "cylinders", "--seed": "1", "--out": "{dir}/w.json"}},
        "worlds import": {"pos": [str(ROOT / "examples" / "maps" / "flat.yaml")], "flags": {"--out": "{dir}/w.json"}},
        "configs": {"pos": [], "flags": {}},
    }


RUN_DIRS = ("resume", "run_dirs", "run_dir")  # path arguments that name a run directory
NEEDS_RUN = ("evaluate", "export")  # their base points at a private copy of the reference run
# The bad-number worlds given to render: a size, a box's yaw, a segment, a radius, a start's x and yaw, a goal.
CLI_WORLDS = tuple(f"{c}-{v}" for c in ("size0", "circles2", "starts2", "goals0") for v in ("1e39", "nan"))
CLI_WORLDS += ("size0-bool", "starts2-num-text")  # numbers numpy would have read: true, "3"
EVAL_WORLDS = (
    "size0-",
    "starts2-",
    "goals0-",
)  # the bad-number worlds also given to evaluate --world (yaw, size, goal)
# The commands whose base would do long work (a benchmark, chapter 4's reproduction): only cases
# refused before any work are generated for them.
LONG_WORK = ("bench", "reproduce")
# The value kinds of the flags, and the bad values each is given.
VALUES = {
    "int": ["-1", "0", HUGE_INT, "nan", ""],
    "float": ["-1", "0", "1e300", "nan", "inf", ""],
    "choice": ["nope", ""],
    "size": ["inf", "1K", "-1G", "nan", "0", ""],
    "text": ["nope", "", "-1", HUGE_INT, LONG],
    "path_in": ["missing", "directory", "fifo", "/dev/zero", "empty", "garbage", "loop", "", LONG],
    "path_out": ["file", "loop", "under_file", LONG, ""],
}
INPUT_FILES = {("train", "config"), ("train", "resume"), ("evaluate", "world"), ("evaluate", "run_dirs")}
INPUT_FILES |= {("render", "worlds"), ("sweep", "file"), ("export", "run_dir"), ("worlds import", "map")}
# Bad values a flag may accept (exit 0 is then fine; a refusal must still be one line): a value of
# a flag that is ignored without --distributed, a seed, a zero noise level, an empty config file.
ACCEPTS = {
    ("train", "--config"): {"empty"},  # an empty config file is the defaults
    ("train", "--num-processes"): {HUGE_INT},
    ("train", "--process-id"): {"-1", "0", HUGE_INT},
    ("train", "--coordinator"): set(VALUES["text"]) - {""},
    ("evaluate", "--seed"): {"-1", "0"},
    ("evaluate", "--range-noise"): {"0"},
    ("evaluate", "--action-noise"): {"0"},
    ("render", "--seed"): {"-1", "0"},
    ("export", "--agent"): {"0"},
    ("worlds generate", "--out"): {"file"},
    ("worlds import", "--out"): {"file"},
}
SKIP = {("bench", "--record", None)}  # would run a benchmark first


def value_kind(verb: str, action) -> str:
    """The kind of value a flag takes (a key of VALUES), from its argparse action."""
    if action.choices and not isinstance(action, argparse._SubParsersAction):
        return "choice"
    tname = getattr(action.type, "__name__", "")
    if tname in ("int", "positive_int"):
        return "int"
    if tname == "float":
        return "float"
    if action.dest == "memory_budget":
        return "size"
    if (verb, action.dest) in INPUT_FILES:
        return "path_in"
    if action.dest in ("out", "record"):
        return "path_out"
    if action.dest == "set":
        return "set"
    return "text"


def resolve_value(fx: Fixtures, v: str) -> str:
    named = {
        "missing": fx.missing,
        "directory": fx.directory,
        "fifo": fx.fifo,
        "empty": fx.empty,
        "garbage": fx.garbage,
        "loop": fx.loop,
        "file": fx.file,
        "under_file": fx.under_file,
    }
    return named.get(v, v)


def label(v: str) -> str:
    return {"": "blank", LONG: "long-name", HUGE_INT: "1e20"}.get(v, v.replace("/", "_").strip("_") or "root")


def command_line(verb: str, base: dict, pos=None, flags=None, tail=None, drop=()) -> list[str]:
    """`verb` + positionals + flags (`flags` replace or add to the base's, also a flag of its tail:
    the last one given would win; `drop` removes) + tail."""
    flags = dict(flags or {})
    tail = list(base.get("tail", []) if tail is None else tail)
    for i, a in enumerate(tail[:-1]):
        if a in flags and a != "--set":
            tail[i + 1] = flags.pop(a)
    merged = {**base["flags"], **flags}
    argv = [*verb.split(), *(base["pos"] if pos is None else pos)]
    for k, v in merged.items():
        if k not in drop:
            argv += [k] if v is None else [k, v]
    return argv + tail


def cli_cases(fx: Fixtures, parser) -> list[Case]:
    """Every command line of category `cli`: derived from the parser, then the tables below."""
    cases: list[Case] = []
    table = bases(fx)

    def add(name, verb, argv, expect="refuse", codes=(2,), timeout=None):
        base = table.get(verb, {})
        setup = (lambda d: fx.copy_run(d / "run")) if verb in NEEDS_RUN else None
        t = timeout or (base.get("timeout", 60) if expect != "refuse" else 60)
        cases.append(Case("cli", name, argv, expect, codes, t, setup))

    # the program itself
    add("top-no-command", "", [])
    add("top-unknown-command", "", ["nope"])
    add("top-unknown-flag", "", ["--nope"])
    add("top-command-case", "", ["TRAIN"])
    for verb, p in verbs(parser).items():
        base, slug = table[verb], verb.replace(" ", "-")
        long_work = verb in LONG_WORK
        add(f"{slug}-unknown-flag", verb, command_line(verb, base, tail=[]) + ["--no-such-flag"])
        add(f"{slug}-unknown-short-flag", verb, command_line(verb, base, tail=[]) + ["-Z"])
        positionals = [a for a in p._actions if not a.option_strings]
        if not any(a.nargs in ("*", "+") for a in positionals):
            add(f"{slug}-extra-positional", verb, command_line(verb, base) + ["EXTRA"])
        if any(a.nargs in (None, "+") for a in positionals):
            add(f"{slug}-missing-positional", verb, command_line(verb, base, pos=[]))
        for a in p._actions:
            if a.option_strings and a.required:
                add(f"{slug}-missing{a.option_strings[0]}", verb, command_line(verb, base, drop=(a.option_strings[0],)))
        for a in p._actions:
            if isinstance(a, (argparse._HelpAction, argparse._VersionAction)) or (a.option_strings and a.nargs == 0):
                continue
            kind = value_kind(verb, a)
            flag = a.option_strings[0] if a.option_strings else None
            if kind == "set" or (verb, flag, None) in SKIP or (long_work and kind in ("path_in",)):
                continue
            ok = ACCEPTS.get((verb, flag or a.dest), set())
            for v in VALUES[kind]:
                if (verb, flag, v) in SKIP or (v in ok and long_work) or (a.dest in RUN_DIRS and v == "empty"):
                    continue
                real = resolve_value(fx, v)
                if flag is None:  # a positional
                    argv = command_line(verb, base, pos=[real])
                else:
                    argv = command_line(verb, base, flags={flag: real})
                add(f"{slug}-{(flag or a.dest).lstrip('-')}-{label(v)}", verb, argv, "any" if v in ok else "refuse")
    cases += table_cases(fx, table)
    return cases


# `--set` values (train): bad keys, types, YAML tricks; each refused.
SET_VALUES = {
    "unknown-field": "ddpg.nope=1",
    "unknown-section": "nope.x=1",
    "no-equals": "offpolicy.gamma",
    "no-value": "offpolicy.gamma=",
    "int-text": "offpolicy.hidden=abc",
    "int-fraction": "offpolicy.hidden=1.5",
    "float-list": "offpolicy.gamma=[1, 2]",
    "float-nan": "offpolicy.gamma=.nan",
    "float-date": "offpolicy.gamma=2024-01-01",
    "worlds-number": "env.worlds=5",
    "worlds-empty": "env.worlds=[]",
    "worlds-missing": "env.worlds=[/no/such/world.json]",
    "worlds-dev-zero": "env.worlds=[/dev/zero]",
    "method-number": "method=7",
    "method-unknown": "method=nope",
    "learner-unknown": "learner=nope",
    "alias-bomb": "env.worlds=" + ALIAS_BOMB.replace("\n", " ").replace("a: &a", "{a: &a").rstrip() + "}",
    "alias-recursive": "env.worlds=&a [*a]",
    "python-tag": "offpolicy.gamma=!!python/object/apply:os.system [echo hi]",
    "yaml-error": "offpolicy.gamma=[1, 2",
    "text-100k": "env.worlds=[" + "x" * 100_000 + "]",
    "buffer-1e8": "offpolicy.buffer_size=100000000",
    "batch-1e6": "offpolicy.batch_size=1000000",
    "room-spec-fixed": "env.room_spec=walls_max=2",
    "seed-int32": "run.seed=2147483647",
}
# Config files (train --config): each refused.
CONFIG_TEXTS = {
    "alias-bomb": ALIAS_BOMB,
    "recursive-alias": "a: &a [*a]\n",
    "a-list": "- 1\n- 2\n",
    "a-scalar": "5\n",
    "unknown-key": "nope: 1\n",
    "duplicate-key": "ddpg:\n  gamma: 0.9\n  gamma: 0.8\n",
    "section-not-mapping": "ddpg: 5\n",
    "python-tag": "ddpg: !!python/object/apply:os.system [echo hi]\n",
    "yaml-error": "ddpg: [1, 2\n",
    "a-date": "offpolicy:\n  gamma: 2024-01-01\n",
    "old-name-a-date": "ddpg:\n  gamma: 2024-01-01\n",  # an offpolicy field by its old name
    "old-and-new-name": "ddpg:\n  gamma: 0.9\noffpolicy:\n  gamma: 0.8\n",  # one field, two values
    "30mb-string": None,  # written below: 30 MB
}
# Sweep files (sweep FILE): each refused.
SWEEP_FIELDS = {
    "seeds-text": {"seeds": "abc"},
    "seeds-list": {"seeds": [1, 2]},
    "seeds-inf": {"seeds": float("inf")},
    "seeds-1e3": {"seeds": "1e3"},
    "seeds-zero": {"seeds": 0},
    "thesis-5": {"thesis": 5},
    "grid-date": {"grid": {"fed.tau": ["2026-01-01"]}},
    "grid-300x300": {"grid": {"fed.tau": [i / 300 for i in range(300)], "fed.beta": list(range(300))}},
    "grid-values-number": {"grid": {"fed.tau": 5}},
    "grid-empty-values": {"grid": {"fed.tau": []}},
    "grid-unknown-field": {"grid": {"nope.x": [1]}},
    "grid-bad-value": {"grid": {"fed.tau": [5.0]}},
    "set-number": {"set": 5},
    "set-unknown": {"set": ["nope.x=1"]},
    "base-missing": {"base": "/no/such/base.yaml"},
    "base-dev-zero": {"base": "/dev/zero"},
    "base-number": {"base": 5},
    "no-base": {"base": _DROP},
    "name-long": {"name": LONG},
    "unknown-key": {"nope": 1},
}
SWEEP_TEXTS = {"no-text": "", "a-list": "- 1\n", "alias-bomb": ALIAS_BOMB, "control-chars": "\x00\x01\x02"}


def table_cases(fx: Fixtures, table: dict) -> list[Case]:
    cases = []
    tr, sw = table["train"], table["sweep"]
    for name, item in SET_VALUES.items():
        cases.append(Case("cli", f"train-set-{name}", command_line("train", tr) + ["--set", item]))
    for name in ("unknown-field", "alias-recursive", "text-100k"):
        cases.append(Case("cli", f"sweep-set-{name}", command_line("sweep", sw) + ["--set", SET_VALUES[name]]))
    for name, text in CONFIG_TEXTS.items():
        path = fx.config_file(name, text if text is not None else "ddpg:\n  activation: " + "x" * 30_000_000 + "\n")
        cases.append(Case("cli", f"train-config-{name}", command_line("train", tr, flags={"--config": path})))
    for name, fields in SWEEP_FIELDS.items():
        drop = ("--out",) if name == "name-long" else ()  # the name is then the folder: runs/sweeps/<name>
        argv = command_line("sweep", sw, pos=[fx.sweep_file(name, fields)], drop=drop)
        cases.append(Case("cli", f"sweep-file-{name}", argv))
    for name, text in SWEEP_TEXTS.items():
        path = fx.sweep_file(name, {}, raw=text)
        cases.append(Case("cli", f"sweep-file-{name}", command_line("sweep", sw, pos=[path])))
    # world files: evaluate --world and render (yaw, sizes, coordinates 1e39 / nan; shapes)
    ev, rd = table["evaluate"], table["render"]
    copy = lambda d: fx.copy_run(d / "run")  # noqa: E731
    shapes = list(world_shapes())
    for name, spec in [*(v for v in world_variants() if v[0].startswith(CLI_WORLDS)), *shapes]:
        path = fx.world_file(name, spec) if not isinstance(spec, str) else fx._write(f"world-{name}.json", spec)
        cases.append(Case("cli", f"render-world-{name}", command_line("render", rd, pos=[path])))
        if name.startswith(EVAL_WORLDS) or name in [n for n, _ in shapes[:3]]:
            argv = command_line("evaluate", ev, flags={"--world": path})
            cases.append(Case("cli", f"evaluate-world-{name}", argv, setup=copy))
    big = fx._write("world-30mb.json", json.dumps({**BASE_WORLD, "description": "x" * 30_000_000}))
    cases.append(Case("cli", "render-world-30mb", command_line("render", rd, pos=[big])))
    # counts that once grew without bound
    for flag, v in (("--attempts", "100000000"), ("--max-steps", "100000000"), ("--max-steps", "2147483647")):
        cases.append(Case("cli", f"evaluate{flag}-{v}", command_line("evaluate", ev, flags={flag: v}), setup=copy))
    cases.append(
        Case(
            "cli",
            "evaluate-suite-attempts-1e8",
            command_line("evaluate", ev, flags={"--suite": "heldout", "--attempts": "100000000"}),
            setup=copy,
        )
    )
    for v in ("100000000", "2147483647", "2147483648"):
        cases.append(Case("cli", f"render-steps-{v}", command_line("render", rd, flags={"--steps": v})))
    cases.append(Case("cli", "train-max-memory-budget-1K", command_line("train", tr, flags={"--memory-budget": "1K"})))
    cases.append(
        Case("cli", "train-distributed-no-out", command_line("train", tr, drop=("--out",)) + ["--distributed"])
    )
    cases.append(
        Case("cli", "train-from-checkpoint-no-resume", command_line("train", tr, flags={"--from-checkpoint": "1"}))
    )
    cases.append(
        Case("cli", "reproduce-only-empty-items", command_line("reproduce", table["reproduce"], flags={"--only": ",,"}))
    )
    cases += third_pass_cases(tr, sw, fx)
    return cases


def third_pass_cases(tr: dict, sw: dict, fx: Fixtures) -> list[Case]:
    """Many environments against the memory budget (refused before allocating, naming the learner's
    own field), PPO's divergence bounds (exit 3) and a sweep whose `base:` is a shipped name."""
    thesis = ["--config", "thesis/flddpg", "--episodes", "2", "--set", "env.episode_length=32"]
    thesis += ["--set", "run.chunk_episodes=1", "--out", "{dir}/run", "--quiet"]
    cases = []
    # refused below the estimate (1G: below compiling), else trained to the end
    for learner, envs, budget, expect in (
        ("sac", "65536", "1G", "refuse"),
        ("sac", "65536", "4G", "refuse"),  # 7.5 GiB estimated, 7.4 GB measured (docs/reliability.md)
        ("sac", "8192", "3G", "ok"),
        ("ppo", "65536", "4G", "refuse"),
        ("ppo", "8192", "2G", "refuse"),
    ):
        argv = ["train", *thesis, "--set", f"learner={learner}", "--set", f"env.envs_per_robot={envs}"]
        name = f"train-{learner}-{envs}-envs-budget-{budget}"
        cases.append(Case("cli", name, argv + ["--memory-budget", budget], expect=expect, timeout=900.0))
    ppo = ["train", *thesis, "--set", "learner=ppo", "--set", "ppo.rollout=16"]
    for name, item in (("max-critic-loss-1", "run.max_critic_loss=1"), ("lr-1", "ppo.lr=1.0")):
        cases.append(Case("cli", f"train-ppo-{name}", ppo + ["--set", item], codes=(3,), timeout=300.0))
    gru = ppo + ["--set", "ppo.recurrent=gru", "--set", "ppo.minibatches=1", "--set", "ppo.lr=1.0"]
    cases.append(Case("cli", "train-ppo-gru-lr-1", gru, codes=(3,), timeout=300.0))
    small = ["run.episodes=2", "run.chunk_episodes=1", "env.episode_length=32"]
    base = fx.sweep_file("base-shipped-name", {"base": "thesis/flddpg", "set": small})
    cases.append(
        Case("cli", "sweep-base-shipped-name", command_line("sweep", sw, pos=[base]), expect="ok", timeout=300.0)
    )
    return cases


# ----------------------------------------------------------------------------- 2. values in-process


def config_values(typ: str, meta: dict):
    """(text for --set, the number it means or None, "refuse" | "any") for one field."""
    lo, hi, choices = meta.get("lo"), meta.get("hi"), meta.get("choices")
    if choices:
        for t in ("nope", "5", "''", f"[{choices[0]}]", "null", "true", str(choices[0]).upper() + "X"):
            yield t, None, "refuse"
        return
    if typ == "bool":
        for t in ("abc", "5", "2", "[1]", "null", "{a: 1}"):
            yield t, None, "refuse"
        return
    if typ not in ("int", "float"):  # tuples and free text: accepted or a one-line refusal
        for t in ("5", "[5]", "[]", "{a: 1}", "nope", "[/dev/zero]", "[2024-01-01]", "[[1]]", "null", "x" * 100_000):
            yield t, None, "any"
        return
    nums = {
        repr(2**31): 2**31,
        repr(-(2**31) - 1): -(2**31) - 1,
        "1e39": 1e39,
        "-1e39": -1e39,
        "1e300": 1e300,
        "1e400": math.inf,
        ".nan": math.nan,
        "nan": math.nan,
        ".inf": math.inf,
        "-.inf": -math.inf,
        "inf": math.inf,
    }
    if lo is not None:
        below = lo - 1 if typ == "int" else lo - max(abs(lo) * 1e-3, 1e-3)
        nums[repr(below)] = below
    if hi is not None:
        above = hi + 1 if typ == "int" else hi + max(abs(hi) * 1e-3, 1e-3)
        nums[repr(above)] = above
    for t, x in nums.items():
        yield t, x, "refuse" if should_refuse(typ, lo, hi, x) else "any"
    for t in ("abc", "[1, 2]", "{a: 1}", "null", "true", "''", "2024-01-01"):
        yield t, None, "refuse"
    if typ == "int":
        yield "1.5", None, "refuse"


def should_refuse(typ: str, lo, hi, x: float) -> bool:
    """A value outside what the field declares: its bounds, finite, int32 / float32."""
    if not math.isfinite(x) or (lo is not None and x < lo) or (hi is not None and x > hi):
        return True
    if typ == "int":
        return x != int(x) or not -(2**31) <= x < 2**31
    return abs(x) > 3.4028234663852886e38


PY_VALUES = {  # values given through from_dict (a Python caller, a notebook)
    "nan": math.nan,
    "inf": math.inf,
    "1e40-int": 10**40,
    "-1e40-int": -(10**40),
    "np-1e39": "np.float64(1e39)",
    "np-2**40": "np.int64(2**40)",
    "bool": True,
    "text-1e39": "1e39",
    "list": [1],
    "none": None,
}


def config_outcomes(limit: int | None = None) -> list[Outcome]:
    """Category `config`: every bounded field through --set and from_dict, then world files."""
    import numpy as np

    from fedjax_nav.config import SECTIONS, TOP_LEVEL, ConfigError, field_info, from_dict, load_config
    from fedjax_nav.worlds import WorldError

    names = list(TOP_LEVEL) + [
        f"{s}.{f.name}" for s, cls in SECTIONS.items() for f in cls.__dataclass_fields__.values()
    ]
    items = []
    for dotted in names:
        f = field_info(dotted)
        typ = f.type if isinstance(f.type, str) else f.type.__name__
        for text, _, expect in config_values(typ, dict(f.metadata)):
            items.append(
                (
                    f"set {dotted}={text[:40]}",
                    lambda d=dotted, t=text: load_config("thesis/flddpg", [f"{d}={t}"]),
                    expect,
                    typ,
                )
            )
        if typ in ("int", "float"):
            lo, hi = f.metadata.get("lo"), f.metadata.get("hi")
            for lab, v in PY_VALUES.items():
                value = eval(v, {"np": np}) if isinstance(v, str) and v.startswith("np.") else v  # noqa: S307
                num = (
                    float(value) if isinstance(value, (int, float, np.number)) and not isinstance(value, bool) else None
                )
                expect = "refuse" if num is None or should_refuse(typ, lo, hi, num) else "any"
                data = {dotted: value} if "." not in dotted else {dotted.split(".")[0]: {dotted.split(".")[1]: value}}
                items.append((f"from_dict {dotted}={lab}", lambda data=data: from_dict(data), expect, typ))
    fx_dir = Path(os.environ.get("ATTACK_WORLD_DIR", "/tmp")) / f"attack-worlds-{os.getpid()}"
    fx_dir.mkdir(parents=True, exist_ok=True)
    import yaml

    from fedjax_nav import worlds

    for name, spec in [*world_variants(), *world_shapes()]:
        for suffix in (".json", ".yaml") if not isinstance(spec, str) else (".json",):
            path = fx_dir / f"{name}{suffix}"
            path.write_text(
                spec if isinstance(spec, str) else json.dumps(spec) if suffix == ".json" else yaml.safe_dump(spec)
            )
            items.append((f"world {name}{suffix}", lambda p=path: worlds.load(p), "refuse", "world"))
    items = items[:limit] if limit else items
    outs = []
    for name, call, expect, typ in items:
        t = time.monotonic()
        why, rc, note = [], 0, ""
        try:
            call()
        except (ConfigError, WorldError) as e:
            rc, note = 2, str(e)[:300]
            if "\n" in str(e):
                why.append("multi-line error")
            if typ in ("int", "float", "bool") and isinstance(e, WorldError):
                why.append("wrong exception: WorldError for a config number")
        except Exception as e:  # anything else would be a traceback at the command line
            rc, note = 1, f"{type(e).__name__}: {str(e)[:300]}"
            why.append("traceback")
        wall = time.monotonic() - t
        if expect == "refuse" and rc == 0:
            why.append("wrong exit: accepted a value outside the field's bounds")
        if wall > 5:
            why.append("hang")
        outs.append(Outcome("config", name, name, rc, wall, why, note))
    shutil.rmtree(fx_dir, ignore_errors=True)
    return outs


# ----------------------------------------------------------------------------- 3. kill and resume


def checkpoints(out: Path) -> list[str]:
    d = out / "checkpoints"
    try:
        return sorted(os.listdir(d))
    except OSError:
        return []


def done(out: Path) -> list[int]:
    return [int(n) for n in checkpoints(out) if n.isdigit()]


def saving(out: Path) -> bool:
    return any("tmp" in n for n in checkpoints(out))


# When each trial kills the run (a predicate of its folder and the seconds since the start).
KILL_AT = {
    "at-0.3s": lambda o, t: t > 0.3,
    "lock-taken": lambda o, t: (o / ".lock").exists(),
    "config-written": lambda o, t: (o / "config.yaml").exists(),
    "saving-1": lambda o, t: saving(o) or bool(done(o)),
    "checkpoint-1": lambda o, t: 1 in done(o),
    "saving-2": lambda o, t: 2 in done(o) or (1 in done(o) and saving(o)),
    "checkpoint-2": lambda o, t: 2 in done(o),
    "checkpoint-3": lambda o, t: 3 in done(o),
    "params-written": lambda o, t: (o / "params.npz").exists(),
    "summary-written": lambda o, t: (o / "summary.json").exists(),
}


def params_equal(a: Path, b: Path) -> str:
    """'' when both params.npz hold the same arrays (np.array_equal), else what differs."""
    import numpy as np

    try:
        pa, pb = np.load(a / "params.npz"), np.load(b / "params.npz")
    except (OSError, ValueError) as e:
        return f"params.npz unreadable: {e}"
    if sorted(pa.files) != sorted(pb.files):
        return "params.npz keys differ"
    bad = [k for k in pa.files if not np.array_equal(pa[k], pb[k])]
    return f"params differ: {bad[:3]}" if bad else ""


class Trial:
    """A multi-step case: each step's command and failures are collected into one Outcome."""

    def __init__(self, runner: Runner, category: str, name: str):
        self.runner, self.category, self.name = runner, category, name
        self.dir = runner.out / category / name
        shutil.rmtree(self.dir, ignore_errors=True)
        self.dir.mkdir(parents=True)
        self.steps, self.failures, self.rcs, self.notes = [], [], [], []
        self.t0 = time.monotonic()

    def step(self, argv, expect="ok", codes=(2,), timeout=180.0, contains: str | None = None):
        rc, out, err, timed_out, _ = self.runner.run(argv, timeout)
        self.record(argv, rc, out, err, timed_out, expect, codes, contains)
        return rc, err

    def record(self, argv, rc, out, err, timed_out, expect, codes=(2,), contains=None):
        self.steps.append(show_argv(argv))
        self.rcs.append(rc)
        why = judge(rc, out, err, timed_out, expect, codes)
        if contains and contains not in err + out:
            why.append(f"message without {contains!r}")
        self.failures += [f"step {len(self.steps)}: {w}" for w in why]
        if err.strip():
            self.notes.append(err.strip().splitlines()[-1][:200])

    def fail(self, why: str):
        self.failures.append(why)

    def outcome(self) -> Outcome:
        rc = next((r for r in reversed(self.rcs) if r is not None), None)
        o = Outcome(self.category, self.name, " ; ".join(self.steps), rc, time.monotonic() - self.t0, self.failures)
        o.note = " | ".join(self.notes)[-400:]
        o.rcs = self.rcs
        return o


def start_and_kill(trial: Trial, argv, when, deadline: float = 180.0) -> str:
    """Start `fedjax-nav ARGV`, SIGKILL it once `when(out, seconds)` holds; what the folder held then."""
    out = Path(argv[argv.index("--out") + 1]) if "--out" in argv else Path(argv[argv.index("--resume") + 1])
    proc = trial.runner.popen(argv)
    t0 = time.monotonic()
    while proc.poll() is None and not when(out, time.monotonic() - t0) and time.monotonic() - t0 < deadline:
        time.sleep(0.003)
    ended = proc.poll() is not None
    with _quiet():
        os.killpg(proc.pid, signal.SIGKILL)
    rc, o, err, _ = trial.runner.finish(proc, 30)
    held = sorted(p.name for p in out.iterdir()) if out.is_dir() else []
    state = f"killed at {time.monotonic() - t0:.1f} s holding {held}, checkpoints {checkpoints(out)}"
    trial.steps.append(show_argv(argv) + " (SIGKILL)")
    if ended:
        state = f"ended (rc {rc}) before the kill; " + state
        trial.record(argv, rc, o, err, False, "ok")
    elif TRACEBACK in err:
        trial.fail("traceback before the kill")
    return state


def resume(trial: Trial, out: Path, reference: Path) -> None:
    """`train --resume OUT` (or, for a folder killed before its config, the `--out` it says to use):
    exit 0, and the parameters of the uninterrupted run."""
    rc, err = trial.step(["train", "--resume", out, "--quiet"], expect="any")
    before_config = not (out / "config.yaml").exists()
    if rc == 2 and before_config and ("start it again with --out" in err or not out.exists()):
        # killed before it wrote its config: nothing to resume, the documented recovery is to start again
        trial.step(["train", "--quiet", "--out", out, *TINY_CKPT], expect="ok")
    elif rc != 0:
        trial.fail(f"resume exit {rc}")
    diff = params_equal(reference, out)
    if diff:
        trial.fail(diff)


def kill_outcomes(runner: Runner, fx: Fixtures, keep=lambda plans: plans, seed: int = 0) -> list[Outcome]:
    rng = random.Random(seed)
    plans = [(name, [when]) for name, when in KILL_AT.items()]
    plans += [(f"random-{i}", [lambda o, t, s=rng.uniform(1.0, 14.0): t > s]) for i in range(4)]
    plans += [("twice", [KILL_AT["checkpoint-1"], KILL_AT["checkpoint-2"]])]  # the resumed run killed again
    plans += [("resume-at-start", [KILL_AT["checkpoint-2"], lambda o, t: t > 1.0])]
    outs = []
    for name, kills in keep(plans):
        trial = Trial(runner, "kill", name)
        out = trial.dir / "run"
        states = [start_and_kill(trial, ["train", "--quiet", "--out", out, *TINY_CKPT], kills[0])]
        for when in kills[1:]:
            states.append(start_and_kill(trial, ["train", "--resume", out, "--quiet"], when))
        resume(trial, out, fx.run)
        o = trial.outcome()
        o.note = " / ".join(states) + " | " + o.note
        outs.append(o)
        shutil.rmtree(trial.dir, ignore_errors=True)
    return outs


# ----------------------------------------------------------------------------- 4. concurrency


def together(trial: Trial, commands: list[list]) -> list[tuple]:
    """Start every command at once; (rc, out, err, timed_out) of each."""
    procs = [trial.runner.popen(c) for c in commands]
    results = [trial.runner.finish(p, 240) for p in procs]
    for c in commands:
        trial.steps.append(show_argv(c) + " &")
    return results


def one_winner(trial: Trial, results, allow_all_ok: bool = False) -> None:
    """Exactly one exit 0 (or all when `allow_all_ok`); every other a one-line exit 2."""
    for rc, out, err, timed_out in results:
        trial.rcs.append(rc)
        trial.failures += judge(rc, out, err, timed_out, "any")
    wins = sum(r[0] == 0 for r in results)
    if not (wins == 1 or (allow_all_ok and wins >= 1)):
        trial.fail(f"{wins} of {len(results)} processes succeeded")


def wait_for(path: Path, proc: subprocess.Popen, seconds: float = 120) -> bool:
    t = time.monotonic()
    while not path.exists() and proc.poll() is None and time.monotonic() - t < seconds:
        time.sleep(0.01)
    return path.exists()


def dead_pid() -> int:
    p = subprocess.Popen(["true"])
    p.wait()
    return p.pid


def concurrency_outcomes(runner: Runner, fx: Fixtures) -> list[Outcome]:
    host = socket.gethostname()
    train = lambda out, *x: ["train", "--quiet", "--out", out, *TINY_CKPT, *x]  # noqa: E731
    outs = []

    t = Trial(runner, "concurrency", "two-trains-one-out")
    one_winner(t, together(t, [train(t.dir / "run"), train(t.dir / "run")]))
    if (d := params_equal(fx.run, t.dir / "run")) != "":
        t.fail(d)
    outs.append(t.outcome())

    t = Trial(runner, "concurrency", "three-trains-one-stale-lock")
    (t.dir / "run").mkdir()
    (t.dir / "run" / ".lock").write_text(f"{dead_pid()} {host}")
    one_winner(t, together(t, [train(t.dir / "run")] * 3))
    outs.append(t.outcome())

    t = Trial(runner, "concurrency", "train-overwrite-while-evaluate")
    run = fx.copy_run(t.dir / "run")
    ev = runner.popen(["evaluate", run, "--no-figures"])
    t.steps.append(show_argv(["evaluate", run, "--no-figures"]) + " &")
    if wait_for(run / ".lock", ev):
        t.step(train(run, "--overwrite"), expect="refuse", contains="in use")
    else:
        t.fail("the evaluation ended before it took the lock")
    t.record(["evaluate", run], *runner.finish(ev, 240), "ok")
    outs.append(t.outcome())

    t = Trial(runner, "concurrency", "evaluate-while-train")
    tr = runner.popen(train(t.dir / "run"))
    t.steps.append(show_argv(train(t.dir / "run")) + " &")
    if wait_for(t.dir / "run" / "config.yaml", tr):
        t.step(["evaluate", t.dir / "run", "--no-figures"], expect="refuse", contains="in use")
    t.record(train(t.dir / "run"), *runner.finish(tr, 240), "ok")
    outs.append(t.outcome())

    t = Trial(runner, "concurrency", "two-evaluates-one-run")
    run = fx.copy_run(t.dir / "run")
    one_winner(t, together(t, [["evaluate", run, "--no-figures"]] * 2), allow_all_ok=True)
    outs.append(t.outcome())

    t = Trial(runner, "concurrency", "two-sweeps-one-out")
    sweep = ["sweep", fx.sweep, "--out", t.dir / "sweep", "--quiet"]
    one_winner(t, together(t, [sweep, sweep]), allow_all_ok=True)
    outs.append(t.outcome())

    for name, text, age, expect in (
        ("stale-lock-dead-pid", f"{dead_pid()} {host}", 0, "ok"),
        ("empty-lock-old", "", 60, "ok"),
        ("empty-lock-young", "", None, "refuse"),  # kept young while the run starts
        ("lock-of-another-host", "1 another-host.example", 0, "refuse"),
        ("lock-holding-garbage", "hello world\n", 0, "refuse"),
    ):
        t = Trial(runner, "concurrency", name)
        lock = t.dir / "run" / ".lock"
        lock.parent.mkdir()
        lock.write_text(text)
        if age:
            os.utime(lock, (time.time() - age, time.time() - age))
        stop = threading.Event()
        if age is None:
            threading.Thread(target=_keep_young, args=(lock, stop), daemon=True).start()
        t.step(train(t.dir / "run"), expect=expect)
        stop.set()
        outs.append(t.outcome())
    return outs


def _keep_young(path: Path, stop: threading.Event) -> None:
    while not stop.wait(0.5):
        with _quiet():
            os.utime(path)


# ----------------------------------------------------------------------------- 5. disk


class Mounts:
    """Small tmpfs mounts (root only): a read-only one holding a run, and a nearly full one."""

    def __init__(self, root: Path):
        self.root, self.points = root, []

    def mount(self, name: str, size: str) -> Path | None:
        point = self.root / name
        point.mkdir(parents=True, exist_ok=True)
        if os.geteuid() != 0:
            return None
        r = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(point)], capture_output=True)
        if r.returncode != 0:
            return None
        self.points.append(point)
        return point

    def read_only(self, point: Path) -> bool:
        return subprocess.run(["mount", "-o", "remount,ro", str(point)], capture_output=True).returncode == 0

    def unmount_all(self):
        for p in reversed(self.points):
            subprocess.run(["umount", "-l", str(p)], capture_output=True)
        self.points = []


def fill(point: Path, leave: int) -> Path:
    """Fill the tmpfs at `point` up to `leave` free bytes; the filler file (remove it to free the disk)."""
    filler = point / "filler"
    st = os.statvfs(point)
    free = st.f_bavail * st.f_frsize
    with open(filler, "ab") as f:
        f.write(b"\0" * max(free - leave, 0))
    with _quiet(), open(point / "filler2", "ab") as f:  # the last partial blocks
        while os.statvfs(point).f_bavail * os.statvfs(point).f_frsize > leave:
            f.write(b"\0" * 4096)
            f.flush()
    return filler


def damage(path: Path, how: str) -> None:
    """Damage a file: "flip" bytes in its middle, "truncate" it to half, "empty" it, "garbage" it."""
    data = path.read_bytes()
    if how == "flip":
        mid = len(data) // 2
        data = data[:mid] + bytes(b ^ 0xFF for b in data[mid : mid + 64]) + data[mid + 64 :]
    elif how == "truncate":
        data = data[: len(data) // 2]
    elif how == "empty":
        data = b""
    else:
        data = os.urandom(max(len(data), 64))
    path.write_bytes(data)


def biggest_file(d: Path) -> Path:
    return max((p for p in d.rglob("*") if p.is_file()), key=lambda p: p.stat().st_size)


def replace_with(path: Path, kind: str, fx: Fixtures) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path)
    elif path.exists() or path.is_symlink():
        path.unlink()
    if kind == "directory":
        path.mkdir()
    elif kind == "fifo":
        os.mkfifo(path)
    elif kind == "loop":
        os.symlink(path, path)
    elif kind == "file":
        path.write_text("x\n")


def suite_folder_with(folder: Path, kind: str, fx: Fixtures) -> None:
    """A folder of one good world file and `bad.json`, a `kind` ("loop", "fifo", ...: replace_with)."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "good.json").write_text(json.dumps(BASE_WORLD))
    replace_with(folder / "bad.json", kind, fx)


def disk_outcomes(runner: Runner, fx: Fixtures) -> tuple[list[Outcome], list[str]]:
    outs, skipped = [], []
    train = lambda out, *x: ["train", "--quiet", "--out", out, *TINY_CKPT, *x]  # noqa: E731

    def case(name, argv, expect="refuse", codes=(2,), prepare=None, after=None, contains=None):
        t = Trial(runner, "disk", name)
        run = fx.copy_run(t.dir / "run", checkpoints=True)
        if prepare:
            prepare(t, run)
        t.step(
            [str(a).replace("{run}", str(run)).replace("{dir}", str(t.dir)) for a in argv],
            expect,
            codes,
            contains=contains,
        )
        if after:
            after(t, run)
        outs.append(t.outcome())

    def same_as_reference(t, run):
        if d := params_equal(fx.run, run):
            t.fail(d)

    newest = lambda run: run / "checkpoints" / str(max(done(run)))  # noqa: E731
    for how in ("flip", "truncate"):
        case(
            f"resume-newest-checkpoint-{how}",
            ["train", "--resume", "{run}", "--quiet"],
            "ok",
            prepare=lambda t, run, how=how: damage(biggest_file(newest(run)), how),
            after=same_as_reference,
        )
    case(
        "resume-newest-checkpoint-file-missing",
        ["train", "--resume", "{run}", "--quiet"],
        "ok",
        prepare=lambda t, run: biggest_file(newest(run)).unlink(),
        after=same_as_reference,
    )
    case(
        "resume-every-checkpoint-damaged",
        ["train", "--resume", "{run}", "--quiet"],
        prepare=lambda t, run: [damage(biggest_file(run / "checkpoints" / str(s)), "flip") for s in done(run)],
    )
    case(
        "resume-checkpoints-is-a-file",
        ["train", "--resume", "{run}", "--quiet"],
        prepare=lambda t, run: replace_with(run / "checkpoints", "file", fx),
    )
    case(
        "resume-metrics-csv-truncated",
        ["train", "--resume", "{run}", "--quiet"],
        "any",
        prepare=lambda t, run: damage(run / "metrics.csv", "truncate"),
        after=same_as_reference,
    )
    for how in ("truncate", "empty", "garbage"):
        for verb in ("evaluate", "export"):
            extra = ["--no-figures", "--out", "{dir}/eval"] if verb == "evaluate" else ["--out", "{dir}/exp"]
            case(
                f"{verb}-params-{how}",
                [verb, "{run}", *extra],
                prepare=lambda t, run, how=how: damage(run / "params.npz", how),
            )
    for kind in ("directory", "fifo", "loop"):
        case(
            f"evaluate-params-is-a-{kind}",
            ["evaluate", "{run}", "--no-figures"],
            prepare=lambda t, run, k=kind: replace_with(run / "params.npz", k, fx),
        )
        case(
            f"export-params-is-a-{kind}",
            ["export", "{run}", "--out", "{dir}/exp"],
            prepare=lambda t, run, k=kind: replace_with(run / "params.npz", k, fx),
        )
        case(
            f"resume-config-is-a-{kind}",
            ["train", "--resume", "{run}", "--quiet"],
            prepare=lambda t, run, k=kind: replace_with(run / "config.yaml", k, fx),
        )
    case(
        "evaluate-config-truncated",
        ["evaluate", "{run}", "--no-figures"],
        prepare=lambda t, run: damage(run / "config.yaml", "truncate"),
    )
    # a suite folder whose *.json / *.yaml entry cannot be read: refused naming it (it was left out)
    for kind, words in (("loop", "is a symlink loop"), ("fifo", "is a FIFO")):
        case(
            f"evaluate-suite-folder-with-a-{kind}",
            ["evaluate", "{run}", "--no-figures", "--suite", "{dir}/rooms"],
            prepare=lambda t, run, k=kind: suite_folder_with(t.dir / "rooms", k, fx),
            contains=words,
        )
    case(
        "evaluate-world-symlink-loop",
        ["evaluate", "{run}", "--no-figures", "--world", "{dir}/loop.json"],
        prepare=lambda t, run: replace_with(t.dir / "loop.json", "loop", fx),
        contains="is a symlink loop",
    )
    case("train-out-symlink-loop", train(fx.loop))
    case("train-resume-symlink-loop", ["train", "--resume", fx.loop, "--quiet"])
    case("train-out-is-a-file", train(fx.file))
    case("train-out-under-a-file", train(fx.under_file))

    mounts = Mounts(runner.out / "mnt")
    try:
        ro = mounts.mount("ro", "32m")  # the reference run with its checkpoints: ~5 MB
        if ro is not None:
            fx.copy_run(ro / "run", checkpoints=True)
            (ro / "empty").mkdir()
            if not mounts.read_only(ro):
                ro = None
        if ro is None:
            skipped.append("read-only tmpfs (needs root and mount)")
        else:
            for name, argv, expect, codes in (
                ("ro-train-out", train(ro / "empty" / "run"), "refuse", (4,)),
                ("ro-train-resume", ["train", "--resume", ro / "run", "--quiet"], "refuse", (4,)),
                ("ro-evaluate-into-the-run", ["evaluate", ro / "run", "--no-figures"], "refuse", (4,)),
                (
                    "ro-evaluate-out-elsewhere",
                    ["evaluate", ro / "run", "--no-figures", "--out", "{dir}/eval"],
                    "ok",
                    (2,),
                ),
                ("ro-export-out", ["export", ro / "run", "--out", ro / "exp"], "refuse", (4,)),
                ("ro-render-out", ["render", "train-0", "--steps", "10", "--out", ro / "png"], "refuse", (4,)),
                (
                    "ro-worlds-generate-out",
                    ["worlds", "generate", "--family", "cylinders", "--seed", "1", "--out", ro / "w.json"],
                    "refuse",
                    (2, 4),
                ),
                ("ro-sweep-out", ["sweep", fx.sweep, "--quiet", "--out", ro / "sweep"], "refuse", (4,)),
            ):
                t = Trial(runner, "disk", name)
                t.step([str(a).replace("{dir}", str(t.dir)) for a in argv], expect, codes)
                outs.append(t.outcome())
        full = mounts.mount("full", "16m")  # filled to a few KiB; freed, it holds the whole run
        if full is None:
            skipped.append("full disk (a 16 MiB tmpfs: needs root and mount)")
        else:
            run_src = fx.copy_run(runner.out / "disk" / "full-src" / "run")
            for name, leave, argv, expect, free_after in (
                ("full-disk-train-checkpoint", 96 * 1024, train(full / "run"), "refuse", True),
                ("full-disk-train-config", 0, train(full / "run0"), "refuse", False),
                (
                    "full-disk-evaluate",
                    0,
                    ["evaluate", run_src, "--no-figures", "--out", full / "eval"],
                    "refuse",
                    False,
                ),
                ("full-disk-export", 0, ["export", run_src, "--out", full / "exp"], "refuse", False),
                ("full-disk-render", 0, ["render", "train-0", "--steps", "10", "--out", full / "png"], "refuse", False),
                (
                    "full-disk-sweep",
                    64 * 1024,
                    ["sweep", fx.sweep, "--quiet", "--out", full / "sweep"],
                    "refuse",
                    False,
                ),
            ):
                for p in full.iterdir():
                    shutil.rmtree(p) if p.is_dir() else p.unlink()
                filler = fill(full, leave)
                t = Trial(runner, "disk", name)
                t.step(argv, expect, (4,))
                if free_after:  # the disk freed, the run resumes to the uninterrupted run's numbers
                    filler.unlink()
                    with _quiet():
                        (full / "filler2").unlink()
                    resume(t, full / "run", fx.run)
                outs.append(t.outcome())
    finally:
        mounts.unmount_all()
    return outs, skipped


# ----------------------------------------------------------------------------- summary


def summarize(outcomes: list[Outcome]) -> list[dict]:
    rows = []
    for cat in [c for c in CATEGORIES if any(o.category == c for o in outcomes)]:
        os_ = [o for o in outcomes if o.category == cat]
        has = lambda o, w: any(w in f for f in o.failures)  # noqa: E731
        codes = collections.Counter()
        for o in os_:
            for rc in getattr(o, "rcs", [o.rc]):
                codes["timeout" if rc is None else str(rc)] += 1
        rows.append(
            {
                "category": cat,
                "cases": len(os_),
                "tracebacks": sum(has(o, "traceback") for o in os_),
                "hangs": sum(has(o, "hang") for o in os_),
                "signal_deaths": sum(has(o, "signal") for o in os_),
                "wrong_exits": sum(has(o, "wrong exit") or has(o, "exit ") for o in os_),
                "multi_line_errors": sum(has(o, "multi-line") for o in os_),
                "failed": sum(bool(o.failures) for o in os_),
                "exit_codes": " ".join(f"{k}:{v}" for k, v in sorted(codes.items(), key=lambda kv: kv[0])),
            }
        )
    return rows


def print_summary(rows, outcomes, skipped) -> None:
    cols = list(rows[0]) if rows else []
    widths = {c: max(len(c), *(len(str(r[c])) for r in rows)) for c in cols}
    print("\n" + "  ".join(c.ljust(widths[c]) for c in cols))
    for r in rows:
        print("  ".join(str(r[c]).ljust(widths[c]) for c in cols))
    failing = [o for o in outcomes if o.failures]
    print(f"\n{len(failing)} failing case(s)" + (":" if failing else ""))
    for o in failing:
        print(f"- [{o.category}] {o.name}: {'; '.join(o.failures)}\n    {o.command[:600]}\n    -> {o.note[:300]}")
    for s in skipped:
        print(f"skipped: {s}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--out", type=Path, default=Path("/tmp/attack"), help="scratch folder (fixtures, case folders)")
    ap.add_argument(
        "--only", default=",".join(CATEGORIES), help=f"comma-separated categories ({', '.join(CATEGORIES)})"
    )
    ap.add_argument("--limit", type=int, default=None, help="at most N cases per category (a smoke test)")
    ap.add_argument("--match", default=None, help="only cases whose name contains one of these comma-separated texts")
    ap.add_argument("--jobs", type=int, default=2, help="command lines run at once (category cli)")
    ap.add_argument("--mem", default="4G", help="address-space cap of every subprocess (RLIMIT_AS), e.g. 4G")
    ap.add_argument("--timeout-scale", type=float, default=1.0, help="multiply every timeout (a slow machine)")
    ap.add_argument(
        "--csv",
        default=None,
        help="summary table ('' = none; default results/attack_summary.csv for the whole battery, OUT/summary.csv "
        "for a part of it: --only, --limit or --match never overwrite the committed table)",
    )
    args = ap.parse_args(argv)
    if args.csv is None:
        part = args.limit is not None or args.match or set(args.only.split(",")) != set(CATEGORIES)
        args.csv = str(Path(args.out) / "summary.csv") if part else str(ROOT / "results" / "attack_summary.csv")
    only = [c.strip() for c in args.only.split(",") if c.strip()]
    if bad := [c for c in only if c not in CATEGORIES]:
        ap.error(f"unknown categories {bad}")
    mem = (
        int(float(args.mem[:-1]) * {"K": 2**10, "M": 2**20, "G": 2**30}[args.mem[-1].upper()])
        if args.mem[-1].isalpha()
        else int(args.mem)
    )
    args.out.mkdir(parents=True, exist_ok=True)
    runner, fx = Runner(args.out, mem, args.timeout_scale), Fixtures(args.out)
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))  # `kill PID`: leave through the finally below
    try:
        return battery(args, only, runner, fx)
    finally:
        runner.kill_all()


def battery(args, only, runner: Runner, fx: Fixtures) -> int:
    outcomes, skipped, t0 = [], [], time.monotonic()
    log = open(args.out / "cases.jsonl", "w")  # written as the cases finish: an interrupted battery keeps them

    def record(got: list[Outcome]) -> None:
        for o in got:
            outcomes.append(o)
            log.write(json.dumps(o.as_row()) + "\n")
            log.flush()

    def keep(items):
        name = lambda i: i[0] if isinstance(i, tuple) else i.name  # noqa: E731
        items = [i for i in items if args.match is None or any(m in name(i) for m in args.match.split(","))]
        return items[: args.limit] if args.limit else items

    def cli_category():
        from fedjax_nav.cli.parser import build_parser

        cases = keep(cli_cases(fx, build_parser()))
        print(f"cli: {len(cases)} command lines, {args.jobs} at a time ...", flush=True)
        pool = concurrent.futures.ThreadPoolExecutor(args.jobs)
        try:
            for i, o in enumerate(pool.map(lambda c: run_case(runner, c), cases)):
                record([o])
                if o.failures:
                    print(f"  FAIL {o.name}: {'; '.join(o.failures)} -> {o.note[:160]}", flush=True)
                elif (i + 1) % 50 == 0:
                    print(f"  {i + 1} done", flush=True)
        finally:
            pool.shutdown(wait=False, cancel_futures=True)

    def disk_category():
        got, why = disk_outcomes(runner, fx)
        skipped.extend(why)
        record(keep(got))

    categories = {
        "cli": cli_category,
        "config": lambda: record(keep(config_outcomes())),
        "kill": lambda: record(kill_outcomes(runner, fx, keep)),
        "concurrency": lambda: record(keep(concurrency_outcomes(runner, fx))),
        "disk": disk_category,
    }
    if set(only) - {"config"}:
        print("training the reference run ...", flush=True)
        fx.train_reference(runner)
    for cat in [c for c in CATEGORIES if c in only]:
        print(f"{cat} ...", flush=True)
        try:
            categories[cat]()
        except Exception as e:  # the battery's own failure: counted, and the other categories still run
            import traceback

            traceback.print_exc()
            record([Outcome(cat, "battery-error", "", None, 0.0, [f"battery error: {type(e).__name__}: {e}"[:500]])])
    log.close()
    rows = summarize(outcomes)
    print_summary(rows, outcomes, skipped)
    print(f"\n{time.monotonic() - t0:.0f} s; every case in {args.out / 'cases.jsonl'}")
    if args.csv and rows:
        Path(args.csv).parent.mkdir(parents=True, exist_ok=True)
        with open(args.csv, "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=list(rows[0]))
            w.writeheader()
            w.writerows(rows)
        print(f"wrote {args.csv}")
    return 1 if any(o.failures for o in outcomes) else 0


if __name__ == "__main__":
    sys.exit(main())
