"""The lock of a run directory's one writer: `RUN/.lock` (`fedjax_nav.rundir.LOCK`) holding the
owner's "PID HOST", created atomically; a stale one (its process gone, or empty and old) is taken
over, one process at a time (docs/reliability.md). Readers (an `evaluate` that writes its results
elsewhere) each hold a file of their own (`ReadLock`): any number of them read a run together, and
a writer is refused while one is live.

The file names are `fedjax_nav.rundir`'s (`LOCK`, `LOCK_TAKEOVER`, `READ_LOCK`), and so are the errors: a lock
held by another process is a `RunDirError` (exit 2 at the CLI), one that cannot be created a
`WriteError` (exit 4).
"""

from __future__ import annotations

import os
from pathlib import Path

from fedjax_nav.rundir import LOCK, LOCK_TAKEOVER, READ_LOCK, RunDirError, WriteError, unlink_quietly

EMPTY_LOCK_S = 5.0  # s: an empty .lock older than this was left by a process killed while creating it


class RunLock:
    """`RUN/.lock`, created atomically (O_EXCL) with the owner's "PID HOST": one writer per run
    directory (`train`, `sweep`, `reproduce`, and `evaluate` while it reads a run and writes its
    eval/). `release()` (or leaving a `with` block) removes it.

    A lock is stale, and taken over with a line on stderr, when (1) its PID is not running on this
    host (a killed run), or (2) it is empty and older than `EMPTY_LOCK_S` seconds (a process killed
    between creating the file and writing its owner: a live owner writes it microseconds after
    creating it, so an empty lock that old has no writer coming). A lock of another host, or one
    whose text is not "PID HOST", is never taken over. Take-overs are serialised by a second
    O_EXCL file (`LOCK_TAKEOVER`), so two processes finding the same stale lock never both take it."""

    def __init__(self, directory: str | Path, what: str = "run directory"):
        import socket

        self.path = Path(directory) / LOCK
        self.owner = f"{os.getpid()} {socket.gethostname()}"
        self._acquire(directory, what)
        reader = _live_reader(Path(directory))  # after taking the lock: a reader after us sees it
        if reader is not None:
            self.release()
            raise _in_use(directory, what, reader, "being read by")

    def _acquire(self, directory: str | Path, what: str) -> None:
        import time

        deadline = time.monotonic() + 10.0  # s: a take-over by another process lasts microseconds
        while True:
            if self._create():
                return
            stale = _stale(self.path)
            if stale is None:
                pid, _ = _lock_owner(self.path)
                if pid is None and not self.path.exists() and time.monotonic() < deadline:
                    continue  # released between our attempt and the read: try again
                raise _in_use(directory, what, self.path) from None
            if self._take_over(stale):
                return
            if time.monotonic() > deadline:
                raise RunDirError(f"{directory}: could not take the lock {self.path} (another process keeps taking it)")
            time.sleep(0.02)

    def _create(self) -> bool:
        """Create the lock holding our owner line; False when one exists."""
        try:
            fd = os.open(self.path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            return False
        except OSError as e:
            raise WriteError(f"{self.path}: cannot create the lock file ({e.strerror or e})") from None
        with os.fdopen(fd, "w") as fh:
            fh.write(self.owner + "\n")
        return True

    def _take_over(self, why: str) -> bool:
        """Replace the stale lock (stale for `why`) by ours, holding `LOCK_TAKEOVER` meanwhile (and
        checked stale again under it). False when another process holds the take-over or took the
        lock first."""
        import sys

        guard = self.path.with_name(LOCK_TAKEOVER)
        try:
            fd = os.open(guard, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            if _age(guard) > EMPTY_LOCK_S:  # a take-over killed half-way: nobody is coming back for it
                unlink_quietly(guard)
            return False
        except OSError as e:
            raise WriteError(f"{guard}: cannot create the lock file ({e.strerror or e})") from None
        os.close(fd)
        try:
            if _stale(self.path) is None:  # released or taken over meanwhile
                return False
            print(f"{self.path}: taking over a stale lock ({why})", file=sys.stderr)
            self.path.unlink(missing_ok=True)
            return self._create()
        finally:
            unlink_quietly(guard)

    def release(self) -> None:
        try:
            if self.path.read_text().strip() == self.owner:
                self.path.unlink()
        except OSError:
            pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.release()


class ReadLock:
    """`RUN/.lock.read-HOST-PID-XXXXXXXX` (`rundir.READ_LOCK`) holding the reader's "PID HOST": one of any
    number of readers of a run (`evaluate` writing its results elsewhere, `--out`), refused while a
    live writer holds `RUN/.lock`; a writer (`RunLock`) is refused while a live reader holds one.
    Each side creates its own file first and then looks for the other's, so of a reader and a
    writer arriving together at least one sees the other. A reader's file whose process is gone is
    stale: writers remove it."""

    def __init__(self, directory: str | Path, what: str = "run directory"):
        import socket
        import tempfile

        host, pid = socket.gethostname(), os.getpid()
        try:  # a name of its own, created atomically (O_EXCL), whatever else this process holds
            fd, name = tempfile.mkstemp(prefix=f"{READ_LOCK}-{host}-{pid}-", dir=directory)
        except OSError as e:
            raise WriteError(f"{directory}: cannot create a reader's lock file ({e.strerror or e})") from None
        self.path = Path(name)
        with os.fdopen(fd, "w") as fh:
            fh.write(f"{pid} {host}\n")
        writer = Path(directory) / LOCK
        if writer.exists() and _stale(writer) is None:
            self.release()
            raise _in_use(directory, what, writer)

    def release(self) -> None:
        unlink_quietly(self.path)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.release()


def _in_use(directory: str | Path, what: str, lock: Path, doing: str = "in use by") -> RunDirError:
    """The one-line refusal naming the owner of `lock` (a writer's or a reader's)."""
    pid, host = _lock_owner(lock)
    who = f"process {pid} on {host}" if pid is not None else "another process"
    return RunDirError(
        f"{directory}: this {what} is {doing} {who} (lock {lock}); wait for it to end, or remove the lock file "
        "if that process is gone"
    )


def _live_reader(directory: Path) -> Path | None:
    """A live reader's lock file in `directory`, or None; stale ones found on the way are removed."""
    for path in sorted(directory.glob(f"{READ_LOCK}-*")):
        if _stale(path) is None:
            if path.exists():
                return path
        else:
            unlink_quietly(path)
    return None


def _stale(path: Path) -> str | None:
    """Why the lock at `path` is stale (see RunLock), or None when it is held (or gone)."""
    import socket

    try:
        text = path.read_text()
    except FileNotFoundError:
        return None
    except OSError:
        return None  # unreadable: treat as held
    if not text.strip():
        age = _age(path)
        return f"empty for {age:.0f} s" if age > EMPTY_LOCK_S else None
    pid, host = _lock_owner(path, text)
    if pid is not None and host == socket.gethostname() and not _alive(pid):
        return f"process {pid} is no longer running"
    return None


def _age(path: Path) -> float:
    """Seconds since `path` was last modified (0 when it is gone)."""
    import time

    try:
        return time.time() - path.stat().st_mtime
    except OSError:
        return 0.0


def _lock_owner(path: Path, text: str | None = None) -> tuple[int | None, str | None]:
    try:
        pid, host = (path.read_text() if text is None else text).split()[:2]
        return int(pid), host
    except (OSError, ValueError):  # being written right now, or foreign: treat as held
        return None, None


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process
        return True
    return True
