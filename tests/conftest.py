"""Shared fixtures for the simulator tests.

Every jitted function lives in a session-scoped fixture so that it compiles once for the whole
run; hand-built worlds are padded to one common shape (`TINY_SHAPE`) so that every env test of
one NavEnv configuration reuses one compiled `step`.
"""

import json
import os
from pathlib import Path

os.environ.setdefault("JAX_PLATFORMS", "cpu")
# A persistent compilation cache shared by the test process and the subprocesses it starts
# (the CLI tests compile the same trainer again in each subprocess).
os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", os.path.join(os.path.expanduser("~"), ".cache", "fedjax_nav_jax"))
# Every compilation into it, the small ones too (jax keeps only those over 1 s by default): the suite
# compiles hundreds of programs of 0.1-1 s (env steps, federated rounds, evaluation loops), and with
# them cached a second run of a group of env and evaluation test files took 72 s instead of 144 s
# (docs/benchmarks.md, "The test suite").
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")
# XLA's default compile options on purpose: the tests run the program a user runs. Options that
# compile faster were measured (docs/benchmarks.md, "the test suite cold"): LLVM at -O0
# (jax_disable_most_optimizations) saves a third of the fingerprint file's CPU but changes the
# programme's numbers; the options that keep the numbers save nothing.

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402
import yaml  # noqa: E402

from fedjax_nav import worlds  # noqa: E402
from fedjax_nav.env import NavEnv, lidar, make_params, nearest_distance  # noqa: E402

# The costliest test files, costliest first, for the order in which the two xdist workers take files
# (pyproject's addopts: `--dist loadfile --no-loadscope-reorder`). xdist's default order is by the
# number of tests in a file, which queues these few-test, compile-heavy files last (the fingerprint
# file, 3 tests and 283 CPU s cold, was the 51st of 55): the run then ends with one worker
# compiling alone. Heaviest first (longest-processing-time order), the many small files fill the
# end. Measured costs: docs/benchmarks.md, "The test suite". Every other file keeps its place.
HEAVY_FILES = (
    "test_trainer.py",
    "test_rooms_training.py",
    "test_programme_fingerprint.py",
    "test_checkpoint.py",
    "test_sweep.py",
    "test_learner_runs.py",
    "test_sharding.py",
    "test_reproduce.py",
)


# The full tier (docs/benchmarks.md, "The test suite: two tiers"): the tests that took 10 s or more
# in a cold run on the 2-core reference VM, and the files that start other processes or devices,
# listed in tests/full_tier.txt (written by scripts/test_tiers.py from that run's junit report).
# pyproject's addopts leave them out (`-m "not full"`): the README's test command stays under 15
# minutes on a fresh machine; `pytest -m full` runs them, and .ci/run runs both tiers.
FULL_TIER = frozenset(
    line.strip()
    for line in (Path(__file__).parent / "full_tier.txt").read_text().splitlines()
    if line.strip() and not line.startswith("#")
)


@pytest.hookimpl(tryfirst=True)  # the markers must be on the items before `-m` deselects
def pytest_collection_modifyitems(config, items):
    """The full tier's marker (FULL_TIER); heavy files first (HEAVY_FILES), each file's tests in their own order."""
    for item in items:
        if f"{item.path.name}::{item.name}" in FULL_TIER:
            item.add_marker(pytest.mark.full)
    rank = {name: i for i, name in enumerate(HEAVY_FILES)}
    items.sort(key=lambda item: rank.get(item.path.name, len(HEAVY_FILES)))


def pytest_terminal_summary(terminalreporter, exitstatus, config):
    """Say where the deselected full tier went (an easy thing to forget when a file runs alone)."""
    if "not full" in (config.getoption("markexpr") or "") and terminalreporter.stats.get("deselected"):
        terminalreporter.write_line("the full tier (tests/full_tier.txt) was left out: `pytest -m full` runs it")


def sigint_at_default() -> None:
    """`preexec_fn` of the subprocesses a test Ctrl-C's: SIGINT at its default, as a terminal starts
    a command. A suite launched as a script's background job inherits SIGINT ignored (POSIX), and a
    run keeps ignoring it (docs/reliability.md), so without this those tests fail there."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_DFL)


# Common padded shape of the hand-built worlds: (segments, circles, starts, goals).
TINY_SHAPE = (8, 2, 4, 2)
# Episode length of the env fixtures (short, so truncation is reached in a few steps).
EPISODE_LENGTH = 4
# Playgrounds of the batch tests, small (compile time grows with the number of obstacles) and
# different in every padded dimension: segments, circles, starts, goals, size.
BATCH_WORLD_SPECS = {
    "room-a.json": {
        "size": [3.0, 3.0],
        "circles": [[0.5, 0.5, 0.3]],
        "starts": [[-1.0, -1.0, 0.0], [1.0, -1.0, 1.5708], [-1.0, 1.0, -1.5708]],
        "goals": [[1.0, 1.0]],
    },
    "room-b.yaml": {
        "size": [5.0, 2.5],
        "boxes": [[0.0, 0.0, 0.6, 0.6, 0.3]],
        "starts": [[-2.0, 0.0, 0.0]],
        "goals": [[2.0, 0.5]],
    },
    "room-c.json": {
        "size": [4.0, 4.0],
        "segments": [[-1.0, 1.0, 1.0, 1.5]],
        "circles": [[1.0, -1.0, 0.4], [-1.0, -0.5, 0.25]],
        "starts": [[0.0, -1.5, 1.5708], [1.5, 0.0, 3.1416]],
        "goals": [[-1.5, 1.5], [1.5, 1.5]],
    },
}
ROLLOUT_STEPS = 30


def tiny_world(starts, goals, size=(10.0, 2.0), segments=None, circles=None, boxes=None, pad=True):
    """A hand-built world through `worlds.from_dict` (so it is validated like a user's file),
    padded to TINY_SHAPE unless pad=False."""
    spec = {"size": list(size), "starts": starts, "goals": goals}
    if segments is not None:
        spec["segments"] = segments
    if circles is not None:
        spec["circles"] = circles
    if boxes is not None:
        spec["boxes"] = boxes
    world, _ = worlds.from_dict(spec, "<test>")
    return worlds.pad(world, *TINY_SHAPE) if pad else world


class JittedEnv:
    """A NavEnv with `reset` and `step` jitted once (single robot, and vmapped over robots);
    counts how often the single `step` is traced."""

    def __init__(self, env: NavEnv):
        self.env = env
        self.traces = 0

        def step(key, state, action, params):
            self.traces += 1
            return env.step(key, state, action, params)

        self.reset = jax.jit(env.reset)
        self.step = jax.jit(step)
        self.reset_keys = jax.jit(jax.vmap(env.reset, in_axes=(0, None)))  # many keys, one world
        self.reset_many = jax.jit(jax.vmap(env.reset))  # one robot per (key, params) row
        self.step_many = jax.jit(jax.vmap(env.step))


@pytest.fixture(scope="session")
def lidar_jit():
    return jax.jit(lidar, static_argnames=("num_beams", "max_range"))


@pytest.fixture(scope="session")
def nearest_jit():
    return jax.jit(nearest_distance)


@pytest.fixture(scope="session")
def learn_env():
    return JittedEnv(NavEnv(episode_length=EPISODE_LENGTH, mode="learn", collision_test="exact"))


@pytest.fixture(scope="session")
def lidar_env():
    return JittedEnv(NavEnv(episode_length=EPISODE_LENGTH, mode="learn", collision_test="lidar"))


@pytest.fixture(scope="session")
def eval_env():
    return JittedEnv(NavEnv(episode_length=EPISODE_LENGTH, mode="eval", collision_test="exact"))


# ----------------------------------------------------------------------------- batch rollouts


def drive(jenv: JittedEnv, keys, params, actions, batched: bool):
    """Reset, then one step per action, from a Python loop over jitted calls. batched: keys [n],
    params with a leading robot axis, actions [n, T, 2], through the vmapped functions; else one
    robot: one key, actions [T, 2]. Either way robot i uses its key the same way.
    Returns numpy (obs0, obs, reward, terminated, truncated, pose, start_index, t), the per-step
    ones with the step axis after the robot axis."""
    if batched:
        split2 = jax.vmap(jax.random.split)(keys)
        k_reset = split2[:, 0]
        k_steps = jax.vmap(lambda k: jax.random.split(k, actions.shape[1]))(split2[:, 1])
        reset, step = jenv.reset_many, jenv.step_many
        step_key, step_action = (lambda j: k_steps[:, j]), (lambda j: actions[:, j])
    else:
        k_reset, k = jax.random.split(keys)
        k_steps = jax.random.split(k, actions.shape[0])
        reset, step = jenv.reset, jenv.step
        step_key, step_action = (lambda j: k_steps[j]), (lambda j: actions[j])
    obs0, state = reset(k_reset, params)
    out = []
    for j in range(actions.shape[-2]):
        obs, state, reward, term, trunc, info = step(step_key(j), state, step_action(j), params)
        out.append((obs, reward, term, trunc, info["pose"], state.start_index, state.t))
    axis = 1 if batched else 0
    per_step = [np.stack([np.asarray(o[i]) for o in out], axis) for i in range(7)]
    return (np.asarray(obs0), *per_step)


@pytest.fixture(scope="session")
def batch_setup(tmp_path_factory):
    """Stacked playgrounds, their params (fast robots so that collisions and goals happen within
    ROLLOUT_STEPS, random starts on) and per-robot keys and actions."""
    folder = tmp_path_factory.mktemp("batch_worlds")
    names = []
    for file, spec in BATCH_WORLD_SPECS.items():
        path = folder / file
        path.write_text(yaml.safe_dump(spec) if file.endswith(".yaml") else json.dumps(spec))
        names.append(str(path))
    stacked = worlds.load_many(names)
    n = len(names)
    overrides = dict(v_max=2.0, random_starts=True)
    params = make_params(stacked, **overrides)
    rng = np.random.default_rng(7)
    actions = np.stack([rng.uniform([0.8, -0.5], [1.0, 0.5], size=(ROLLOUT_STEPS, 2)) for _ in range(n)]).astype(
        np.float32
    )
    keys = jax.random.split(jax.random.key(42), n)
    return {
        "names": names,
        "stacked": stacked,
        "params": params,
        "actions": jnp.asarray(actions),
        "keys": keys,
        "overrides": overrides,
    }


@pytest.fixture(scope="session")
def batch_env():
    """The noise-free learn-mode env with the default episode length."""
    return JittedEnv(NavEnv(episode_length=1024))


@pytest.fixture(scope="session")
def noisy_env():
    """The same with noise=True (the stds come from the params)."""
    return JittedEnv(NavEnv(episode_length=1024, noise=True))
