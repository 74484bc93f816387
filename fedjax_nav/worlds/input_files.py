"""Reading a user's input file (world, config, sweep) or `--set` value without trusting it.

The one reader of `fedjax_nav.worlds` (world files, map images) and `fedjax_nav.config` (configs, sweep
files, `--set` values; config imports it when it first reads, as `import fedjax_nav.config`
stays free of jax). This module itself imports only yaml. What it refuses, fast and before
anything is built:

- anything but a regular file (a FIFO would block forever, `/dev/zero` never ends): `os.stat`
  before opening, `fstat` of the opened descriptor again (the name may change in between);
- a file larger than the caller's byte bound (at most that many bytes are ever read);
- YAML whose aliases expand it beyond a node budget (an "alias bomb": nine levels of nine
  aliases are 9^9 values from 400 bytes) or that refer to themselves (a recursive alias): the
  composed node graph is measured before a single Python object is constructed;
- a key given twice in one mapping (YAML and JSON readers keep the last one silently).

YAML timestamps (`2024-01-01`) stay the text they are: no field of ours is a date, and a
`datetime.date` would reach JSON writers (a world's name, a sweep's grid values).

Every problem is an `InputError` whose message does not name the input: the caller prefixes
the file (or `--set key`) and raises its own error type (`ConfigError`, `WorldError`).
"""

from __future__ import annotations

import errno
import json
import os
import stat
from pathlib import Path
from typing import Any

import yaml

from fedjax_nav.messages import show

MIB = 2**20


class InputError(ValueError):
    """What is wrong with an input, without its name (the caller adds it)."""


# ----------------------------------------------------------------------------- bounded reading

_NOT_REGULAR = (
    (stat.S_ISFIFO, "a FIFO"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
    (stat.S_ISSOCK, "a socket"),
)


def _not_regular(mode: int, kind: str) -> InputError:
    if stat.S_ISDIR(mode):
        return InputError(f"is a directory, not a {kind} file")
    what = next((name for test, name in _NOT_REGULAR if test(mode)), "a special file")
    return InputError(f"is {what}, not a regular file; a {kind} file must be a regular file")


def missing_link(path: str | Path) -> str | None:
    """Why a path that `Path.exists` calls absent is a symbolic link that leads nowhere: "is a
    symlink loop (...)" or "is a symbolic link to a missing file (...)"; None for a plain missing
    path (or one that exists)."""
    try:
        os.stat(path)
    except OSError as e:
        if e.errno == errno.ELOOP:
            return f"is a symlink loop ({e.strerror})"
        if os.path.islink(path):
            return f"is a symbolic link to a missing file ({e.strerror})"
    except ValueError:
        pass
    return None


def _os_error(e: OSError) -> InputError:
    """An OSError of stat or open as the reason an input cannot be read (a loop named as one)."""
    if e.errno == errno.ELOOP:
        return InputError(f"is a symlink loop ({e.strerror})")
    return InputError(f"cannot be read ({e.strerror or type(e).__name__})")


def check_regular(path: str | Path, kind: str) -> None:
    """An InputError unless `path` is a regular file (after symbolic links): a directory, a FIFO, a
    device, a socket, a symlink loop, a link to a missing file or a missing path are each named."""
    try:
        st = os.stat(path)
    except OSError as e:
        why = missing_link(path)
        raise (InputError(why) if why else _os_error(e)) from None
    except ValueError as e:  # a NUL byte in the name
        raise InputError(f"cannot be read ({type(e).__name__})") from None
    if not stat.S_ISREG(st.st_mode):
        raise _not_regular(st.st_mode, kind)


def read_bytes(path: str | Path, kind: str, max_bytes: int) -> bytes:
    """The content of the regular file `path`, at most `max_bytes` bytes long.

    Never blocks on a FIFO nor reads a device: the type is checked by `stat` before opening and
    by `fstat` after (opened with O_NONBLOCK, so even a FIFO swapped in between does not wait)."""
    too_big = f"a {kind} file holds at most {max_bytes:,} bytes ({max_bytes / MIB:g} MiB)"
    try:
        st = os.stat(path)
        if not stat.S_ISREG(st.st_mode):
            raise _not_regular(st.st_mode, kind)
        if st.st_size > max_bytes:
            raise InputError(f"is {st.st_size:,} bytes; {too_big}")
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0))
        with os.fdopen(fd, "rb") as f:
            mode = os.fstat(f.fileno()).st_mode
            if not stat.S_ISREG(mode):
                raise _not_regular(mode, kind)
            data = f.read(max_bytes + 1)  # a file that grows (or /proc's size-0 files) is still bounded
    except OSError as e:  # permission denied, a name too long, a symlink loop, I/O errors, ...
        raise _os_error(e) from None
    except ValueError as e:  # a NUL byte in the name
        if isinstance(e, InputError):
            raise
        raise InputError(f"cannot be read ({type(e).__name__})") from None
    if len(data) > max_bytes:
        raise InputError(f"is more than {max_bytes:,} bytes; {too_big}")
    return data


def read_text(path: str | Path, kind: str, max_bytes: int, formats: str = "YAML") -> str:
    """The UTF-8 text of the regular file `path`, at most `max_bytes` bytes long (`read_bytes`)."""
    data = read_bytes(path, kind, max_bytes)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as e:
        raise InputError(f"not UTF-8 text (byte {e.start}); a {kind} file must be UTF-8 {formats}") from None


# ----------------------------------------------------------------------------- YAML


class _BudgetError(yaml.YAMLError):
    def __init__(self, problem: str, mark):
        self.problem, self.problem_mark = problem, mark


def _expanded_size(root: yaml.Node, budget: int) -> int:
    """The values `root` stands for once every alias is expanded (a node reached twice counts
    twice), refusing beyond `budget` or on a cycle. Linear in the distinct nodes: each node's
    size is computed once."""
    sizes: dict[int, int] = {}
    open_nodes: set[int] = set()

    def size(node: yaml.Node) -> int:
        key = id(node)
        if key in sizes:
            return sizes[key]
        if key in open_nodes:
            raise _BudgetError(
                "a recursive YAML alias (it refers to a node that holds it); not allowed", node.start_mark
            )
        open_nodes.add(key)
        n = 1
        if isinstance(node, yaml.SequenceNode):
            n += sum(size(child) for child in node.value)
        elif isinstance(node, yaml.MappingNode):
            n += sum(size(k) + size(v) for k, v in node.value)
        if n > budget:
            raise _BudgetError(
                f"YAML aliases expand the document to more than {budget:,} values (each use of an alias "
                f"counts its values again); at most {budget:,} are allowed",
                node.start_mark,
            )
        open_nodes.discard(key)
        sizes[key] = n
        return n

    return size(root)


class _Loader(yaml.SafeLoader):
    """yaml.SafeLoader with a node budget, no duplicate keys, and timestamps as text."""

    def __init__(self, stream, budget: int):
        super().__init__(stream)
        self.budget = budget

    def compose_document(self):
        node = super().compose_document()
        _expanded_size(node, self.budget)
        return node

    def construct_mapping(self, node, deep=False):
        if isinstance(node, yaml.MappingNode):
            seen: dict[Any, Any] = {}  # key -> where it was first given
            for key_node, _ in node.value:
                if key_node.tag == "tag:yaml.org,2002:merge":  # keys merged by `<<: *base` may be overridden
                    continue
                key = self.construct_object(key_node, deep=True)
                try:
                    first = seen.get(key)
                except TypeError:  # unhashable: SafeConstructor names it
                    continue
                if first is not None:
                    raise yaml.constructor.ConstructorError(
                        None,
                        None,
                        f"duplicate key {show(key)} (first on line {first.line + 1}); "
                        "a key may appear once per mapping",
                        key_node.start_mark,
                    )
                seen[key] = key_node.start_mark
        return super().construct_mapping(node, deep=deep)


_Loader.add_constructor("tag:yaml.org,2002:timestamp", yaml.SafeLoader.construct_yaml_str)


def load_yaml(text: str, budget: int = 100_000) -> Any:
    """yaml.safe_load with `_Loader`'s refusals; any problem is one `InputError` line, 'not valid
    YAML (line L, column C: problem)'."""
    loader = None
    try:
        loader = _Loader(text, budget)  # the reader refuses control characters here already
        return loader.get_single_data()  # what yaml.load does
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None) or getattr(e, "context_mark", None)
        where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark is not None else ""
        problem = " ".join(f"{where}{getattr(e, 'problem', None) or getattr(e, 'context', None) or e}".split())
        raise InputError(problem if isinstance(e, _BudgetError) else f"not valid YAML ({problem})") from None
    except Exception as e:  # e.g. RecursionError on absurd nesting, an int of 5000 digits
        raise InputError(f"not valid YAML ({type(e).__name__})") from None
    finally:
        if loader is not None:
            loader.dispose()


# ----------------------------------------------------------------------------- JSON


def _unique_pairs(pairs: list) -> dict:
    out: dict = {}
    for k, v in pairs:
        if k in out:
            raise InputError(f"not valid JSON (duplicate key {show(k)}; a key may appear once per object)")
        out[k] = v
    return out


def load_json(text: str) -> Any:
    """json.loads refusing duplicate keys; any problem is one `InputError` line."""
    try:
        return json.loads(text, object_pairs_hook=_unique_pairs)
    except InputError:
        raise
    except json.JSONDecodeError as e:
        raise InputError(f"not valid JSON ({e})") from None
    except Exception as e:  # e.g. RecursionError on absurd nesting
        raise InputError(f"not valid JSON ({type(e).__name__})") from None
