"""The training programme bit for bit: tiny runs of the robust federation with an attack, a
thesis rule with an attack, and procedural rooms with the probe and the robot model hashed
(metrics, final networks and buffers) against fingerprints recorded before a refactoring; every
thesis method is checked the same way by tests/test_trainer.py.

A refactoring of the trainer, the aggregators or the env builder must leave every one of these
hashes as it was. The hashes hold for one jax/XLA version on one kind of CPU (XLA compiles for the
host's instruction set, and another set rounds differently): `tests/data/programme_fingerprints.json`
holds one record per (versions, CPU kind), each recorded from the code before a refactoring; on a
machine with no record the test is skipped and says so, before training anything. To record for
this machine (from a checkout of the code before your change, or anew when a change is meant to
change the numbers, and say so in the commit):
`FEDJAX_NAV_RECORD_FINGERPRINTS=1 pytest -p no:xdist tests/test_programme_fingerprint.py`.
"""

from __future__ import annotations

import hashlib
import json
import os
import platform
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from fedjax_nav.config import load_config
from fedjax_nav.training.hparams import hparams_from_config
from fedjax_nav.training.trainer import Trainer

ROOT = Path(__file__).resolve().parents[1]
FILE = Path(__file__).resolve().parent / "data" / "programme_fingerprints.json"
RECORD = os.environ.get("FEDJAX_NAV_RECORD_FINGERPRINTS") == "1"
TINY = [
    "env.episode_length=16",
    "run.chunk_episodes=2",
    "run.episodes=2",
    "offpolicy.batch_size=8",
    "offpolicy.buffer_size=128",
    "offpolicy.hidden=16",
    "run.checkpoint_every=0",
    "fed.period=1",
]
PPO_TINY = ["env.envs_per_robot=4", "ppo.rollout=8", "ppo.hidden=16", "run.eval_every=0", "run.seeds=1"]
# Every thesis method is held to its numbers by tests/test_trainer.py, on the runs that module
# trains anyway (tests/data/trainer_run_fingerprints.json); here: what those runs do not cover.
CASES = {
    "robust-attack": (
        "thesis/flddpg.yaml",
        ["fed.aggregator=norm_bounded", "fed.attack=scale", "fed.byzantine=1", "fed.participation=0.8"],
    ),
    "method-stale": ("thesis/pwddpg.yaml", ["fed.attack=stale", "fed.byzantine=1"]),
    # PPO with many environments per robot, federated and central (its minibatch permutation is
    # agents/shuffle.py's: the same numbers as jax.random.permutation's)
    "ppo-fleet": ("learners/ppo.yaml", [*PPO_TINY, "method=flddpg"]),
    "ppo-central": ("learners/ppo.yaml", [*PPO_TINY, "method=snddpg"]),
    "procedural-probe-robot": (
        "thesis/flddpg.yaml",
        ["env.rooms=procedural", "run.eval_every=1", "robot.model=turtlebot3_burger"],
    ),
}


def versions() -> dict:
    import flax
    import jaxlib

    return {
        "jax": jax.__version__,
        "jaxlib": jaxlib.__version__,
        "flax": flax.__version__,
        "machine": platform.machine(),
        "cpu": cpu_kind(),
    }


def cpu_kind() -> str:
    """The CPU as XLA's code generation sees it: vendor, family, model and a digest of the
    instruction-set flags (/proc/cpuinfo; the platform's processor name elsewhere)."""
    info = Path("/proc/cpuinfo")
    if not info.exists():
        return platform.processor() or "unknown"
    fields = {}
    for line in info.read_text().splitlines():
        key, _, value = line.partition(":")
        fields.setdefault(key.strip(), value.strip())
    flags = hashlib.sha1(" ".join(sorted(fields.get("flags", "").split())).encode()).hexdigest()[:12]
    vendor, family, model = (fields.get(k, "?") for k in ("vendor_id", "cpu family", "model"))
    return f"{vendor} family {family} model {model} flags {flags}"


def record_for(data: dict) -> dict | None:
    """The record of `data` (a fingerprint file) made with this machine's versions and CPU kind."""
    return next((r for r in data["records"] if r["versions"] == versions()), None)


def skip_unless_recorded(data: dict, what: str) -> dict:
    """This machine's record of `data`, or skip naming the kinds recorded."""
    rec = record_for(data)
    if rec is None:
        kinds = "; ".join(str(r["versions"]) for r in data["records"])
        pytest.skip(f"{what}: no fingerprints recorded for {versions()} (recorded: {kinds})")
    return rec


def _bytes(x) -> bytes:
    x = jax.random.key_data(x) if jax.dtypes.issubdtype(getattr(x, "dtype", np.float32), jax.dtypes.prng_key) else x
    return np.ascontiguousarray(np.asarray(x)).tobytes()


def digest(metrics: dict, states) -> str:
    """sha256 of a run's metrics (by name) and its final networks and buffers."""
    h = hashlib.sha256()
    for k in sorted(metrics):
        h.update(k.encode() + _bytes(metrics[k]))
    for leaf in jax.tree.leaves(states.agents) + jax.tree.leaves(states.buffers):
        h.update(_bytes(leaf))
    return h.hexdigest()


def fingerprint(case: str) -> str:
    path, extra = CASES[case]
    cfg = load_config(ROOT / "configs" / path, TINY + extra)
    tr, hp = Trainer(cfg), hparams_from_config(cfg)
    states = tr.init_seeds(jnp.arange(1), hp)
    states, metrics = tr.compiled_chunk()(states, hp, jnp.int32(0))
    return digest(metrics, states)


@pytest.fixture(scope="module")
def recorded():
    data = json.loads(FILE.read_text()) if FILE.exists() else {"records": []}
    if RECORD and record_for(data) is None:
        data["records"].append({"versions": versions(), "cases": {}})
    yield data
    if RECORD:
        FILE.parent.mkdir(exist_ok=True)
        FILE.write_text(json.dumps(data, indent=1, sort_keys=True) + "\n")


@pytest.mark.parametrize("case", sorted(CASES))
def test_programme_is_bitwise_as_recorded(case, recorded):
    if RECORD:
        record_for(recorded)["cases"][case] = fingerprint(case)
        return
    rec = skip_unless_recorded(recorded, str(FILE.name))
    assert case in rec["cases"], f"no fingerprint recorded for {case!r} (see the module docstring)"
    assert fingerprint(case) == rec["cases"][case], f"{case}: the programme's numbers changed"
