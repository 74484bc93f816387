"""The edges of one writer per run directory and of checkpoints (docs/reliability.md): `evaluate`
holds the run's lock, an empty or dead-owner lock is taken over (by exactly one process), a
failed or killed save leaves no unfinished checkpoint folder, and a folder without a config says
how to start again. Nothing here trains: the kills and resumes of real runs are in
tests/test_checkpoint.py (before the first checkpoint, a damaged latest one, --from-checkpoint).
"""

import os
import shlex
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from fedjax_nav import cli, rundir, runlock

TIMEOUT = 120  # s, per subprocess


def one_line(capfd, rc: int, code: int, *needles: str) -> str:
    """Exit `code`, the last line on stderr `error: ...` holding every needle, no traceback."""
    err = capfd.readouterr().err
    assert rc == code and "Traceback" not in err, err[-3000:]
    line = err.strip().splitlines()[-1]
    assert line.startswith("error: ") and all(n in line for n in needles), line
    return line


def dead_pid() -> int:
    """The PID of a process that has ended (not reused this soon)."""
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


# ----------------------------------------------------------------------------- evaluate and the lock


TINY = {
    "method": "iddpg",
    "env": {"worlds": ["train-0", "train-2"], "episode_length": 16},
    "offpolicy": {"hidden": 16, "depth": 2, "batch_size": 8, "buffer_size": 64},
    "run": {"episodes": 2, "seeds": 1, "chunk_episodes": 1},
}


@pytest.fixture(scope="module")
def untrained_run(tmp_path_factory) -> Path:
    """A run directory that evaluate accepts: config.yaml and the initial params.npz (no training)."""
    import jax.numpy as jnp

    from fedjax_nav.config import load_config
    from fedjax_nav.training.hparams import hparams_from_config
    from fedjax_nav.training.trainer import Trainer

    run = tmp_path_factory.mktemp("untrained") / "run"
    run.mkdir()
    (run / "tiny.yaml").write_text(yaml.safe_dump(TINY))
    cfg = load_config(run / "tiny.yaml")
    (run / "tiny.yaml").unlink()
    rundir.write_config(run, cfg)
    states = Trainer(cfg).init_seeds(jnp.arange(1), hparams_from_config(cfg))
    rundir.write_params(run, states.agents)
    return run


@pytest.mark.parametrize("what", [[], ["--suite", "heldout"]])
def test_evaluate_refuses_a_run_in_use_and_writes_nothing(untrained_run, capfd, what):
    """While a writer (here this process, as `train --overwrite` would) holds RUN/.lock, evaluate
    neither reads the run nor writes RUN/eval/."""
    run = untrained_run
    with runlock.RunLock(run):
        rc = cli.main(["evaluate", str(run), "--no-figures", "--attempts", "1", *what])
        one_line(capfd, rc, 2, str(run), "in use", f"process {os.getpid()}", str(run / rundir.LOCK))
        assert (run / rundir.LOCK).read_text().split()[0] == str(os.getpid())  # still the writer's
    assert sorted(p.name for p in run.iterdir()) == [rundir.CONFIG, rundir.PARAMS]


def test_evaluations_written_elsewhere_read_a_run_side_by_side(untrained_run, tmp_path, capfd):
    """While another evaluation reads the run (its reader's lock held here), an evaluation written
    elsewhere (`--out`) runs too and leaves the other's lock alone; one that would write into the
    run is refused, naming the reader."""
    run = untrained_run
    with runlock.ReadLock(run) as other:
        rc = cli.main(["evaluate", str(run), "--no-figures", "--attempts", "1", "--out", str(tmp_path / "ev")])
        assert rc == 0, capfd.readouterr().err[-1500:]
        assert (tmp_path / "ev" / rundir.EVAL_JSON).exists()
        assert sorted(run.glob(f"{rundir.READ_LOCK}-*")) == [other.path]  # its own lock released
        rc = cli.main(["evaluate", str(run), "--no-figures", "--attempts", "1"])
        one_line(capfd, rc, 2, str(run), f"being read by process {os.getpid()}", str(other.path))
    assert sorted(p.name for p in run.iterdir()) == [rundir.CONFIG, rundir.PARAMS]


def test_readers_share_a_folder_and_hold_off_a_writer(tmp_path):
    """Two readers hold one folder together; a writer is refused while one is live and leaves no
    lock behind; a reader is refused while the writer holds it; a dead reader's file is removed by
    the next writer."""
    with runlock.ReadLock(tmp_path) as a, runlock.ReadLock(tmp_path) as b:
        assert a.path != b.path and a.path.exists() and b.path.exists()
        with pytest.raises(rundir.RunDirError, match=f"being read by process {os.getpid()}"):
            runlock.RunLock(tmp_path)
        assert not (tmp_path / rundir.LOCK).exists()
    with runlock.RunLock(tmp_path):
        with pytest.raises(rundir.RunDirError, match=f"in use by process {os.getpid()}"):
            runlock.ReadLock(tmp_path)
        assert not list(tmp_path.glob(f"{rundir.READ_LOCK}-*"))
    pid = dead_pid()
    dead = tmp_path / f"{rundir.READ_LOCK}-{socket.gethostname()}-{pid}-1"
    dead.write_text(f"{pid} {socket.gethostname()}\n")
    with runlock.RunLock(tmp_path):
        assert not dead.exists()
    assert not any(tmp_path.iterdir())


def test_evaluate_of_a_missing_folder_names_it(tmp_path, capfd):
    """No lock is created for a run folder that does not exist: the loader names it."""
    one_line(capfd, cli.main(["evaluate", str(tmp_path / "nope")]), 2, "no such run directory")
    assert not (tmp_path / "nope").exists()


# ----------------------------------------------------------------------------- stale locks


def test_an_empty_lock_is_taken_over_once_it_is_old(tmp_path, capfd):
    """An empty .lock: a process killed between creating it and writing its owner. Fresh, it may be
    being written (refused); older than runlock.EMPTY_LOCK_S, it is stale (taken over, one line)."""
    lock = tmp_path / rundir.LOCK
    lock.touch()
    with pytest.raises(rundir.RunDirError, match="in use by another process"):
        runlock.RunLock(tmp_path)
    old = time.time() - 60  # s, well beyond runlock.EMPTY_LOCK_S
    os.utime(lock, (old, old))
    with runlock.RunLock(tmp_path):
        assert lock.read_text().split() == [str(os.getpid()), socket.gethostname()]
    assert "taking over a stale lock (empty for" in capfd.readouterr().err
    assert not lock.exists() and not (tmp_path / rundir.LOCK_TAKEOVER).exists()
    # a lock of another host is never taken over, however old
    lock.write_text(f"{dead_pid()} another-host\n")
    os.utime(lock, (old, old))
    with pytest.raises(rundir.RunDirError, match="on another-host"):
        runlock.RunLock(tmp_path)


def test_a_stale_lock_is_taken_over_by_exactly_one_of_several(tmp_path):
    """Four processes find the same dead-owner lock at the same moment: one takes it, three are
    told it is in use. They meet at a barrier of files (not a clock time: on a loaded machine an
    interpreter may start seconds late), and whoever took the lock holds it until all four have
    tried."""
    run, sync = tmp_path / "run", tmp_path / "sync"
    run.mkdir(), sync.mkdir()
    (run / rundir.LOCK).write_text(f"{dead_pid()} {socket.gethostname()}\n")
    script = (
        "import sys, time, pathlib\nfrom fedjax_nav import rundir, runlock\n"
        "sync, me = pathlib.Path(sys.argv[2]), sys.argv[3]\n(sync / f'ready-{me}').touch()\n"
        "while len(list(sync.glob('ready-*'))) < 4: time.sleep(0.001)\n"
        "try:\n    lock = runlock.RunLock(sys.argv[1])\nexcept rundir.RunDirError:\n"
        "    (sync / f'refused-{me}').touch(); print('refused'); sys.exit()\n"
        "(sync / f'took-{me}').touch(); print('took', flush=True)\n"
        "while len([*sync.glob('refused-*'), *sync.glob('took-*')]) < 4: time.sleep(0.01)\nlock.release()\n"
    )
    procs = [
        subprocess.Popen([sys.executable, "-c", script, str(run), str(sync), str(i)], stdout=subprocess.PIPE, text=True)
        for i in range(4)
    ]
    outs = sorted(p.communicate(timeout=TIMEOUT)[0].strip() for p in procs)
    assert outs == ["refused", "refused", "refused", "took"], outs
    assert not (run / rundir.LOCK).exists() and not (run / rundir.LOCK_TAKEOVER).exists()


# ----------------------------------------------------------------------------- unfinished saves


SAVE = """
import sys
import numpy as np
from fedjax_nav.training.checkpoint import Checkpointer
from fedjax_nav.rundir import WriteError
ck = Checkpointer(sys.argv[1])
try:
    ck.save(1, {"a": np.random.default_rng(0).normal(size=100_000).astype(np.float32)}, {"reward": np.zeros(2)})
    ck.close()
except WriteError as e:
    print(e)
"""


def test_a_failed_save_leaves_no_unfinished_folder(tmp_path):
    """A real failed write (files limited to 8 KiB, SIGXFSZ ignored: EFBIG as on a full disk)."""
    run = tmp_path / "run"
    argv = shlex.join([sys.executable, "-c", SAVE, str(run)])
    r = subprocess.run(
        ["bash", "-c", f"trap '' XFSZ; ulimit -f 8; exec {argv}"],
        env=dict(os.environ, JAX_PLATFORMS="cpu"),
        capture_output=True,
        text=True,
        timeout=TIMEOUT,
    )
    assert r.returncode == 0 and "cannot save a checkpoint" in r.stdout, r.stdout + r.stderr[-3000:]
    assert list((run / rundir.CHECKPOINTS).iterdir()) == []


def test_opening_the_checkpoints_removes_an_unfinished_save(tmp_path):
    """A kill during a save leaves `<step>.orbax-checkpoint-tmp`: the next writer removes it."""
    from fedjax_nav.training.checkpoint import Checkpointer

    unfinished = tmp_path / rundir.CHECKPOINTS / "3.orbax-checkpoint-tmp" / "state"
    unfinished.mkdir(parents=True)
    (unfinished / "part").write_bytes(b"\0" * 64)
    ck = Checkpointer(tmp_path)
    try:
        assert list((tmp_path / rundir.CHECKPOINTS).iterdir()) == [] and ck.latest() is None
    finally:
        ck.close()


# ----------------------------------------------------------------------------- a run that never began


def test_resume_of_a_folder_without_a_config_says_to_start_again(tmp_path, capfd):
    """Killed before it wrote its config (only a lock left): nothing to resume; the line says how
    to start it again, and `--from-checkpoint` alone is refused."""
    run = tmp_path / "run"
    run.mkdir()
    (run / rundir.LOCK).write_text(f"{dead_pid()} {socket.gethostname()}\n")
    rc = cli.main(["train", "--resume", str(run), "--quiet"])
    one_line(capfd, rc, 2, str(run / rundir.CONFIG), "holds no run to resume", f"--out {run}")
    rc = cli.main(["train", "--from-checkpoint", "2", "--quiet"])
    one_line(capfd, rc, 2, "--from-checkpoint N needs --resume")
    assert sorted(p.name for p in run.iterdir()) == [rundir.LOCK]


def test_flat_config_names_every_field():
    """The fallback comparison of a resume against a config saved by other code reads every field
    by its dotted name (a section's keys once collapsed to the section's name, so only its last
    field was compared)."""
    from fedjax_nav.config import Config, to_dict
    from fedjax_nav.training.preflight import to_dict_flat

    flat = to_dict_flat(Config())
    assert flat["offpolicy.gamma"] == 0.9 and flat["env.episode_length"] == 1024 and flat["method"] == "flddpg"
    assert len(flat) == sum(len(v) if isinstance(v, dict) else 1 for v in to_dict(Config()).values())
