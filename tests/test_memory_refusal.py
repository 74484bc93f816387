"""Unbounded work is refused before it is allocated (docs/reliability.md, "Memory: evaluation and
activations"): an evaluation whose trajectories or episode states would not fit (`--attempts`,
`--max-steps`), a training run whose per-update activations would not fit (`offpolicy.batch_size`),
by the one budget rule of `fedjax_nav.config.memory`; and the degenerate inputs of evaluate and
export (zero counts, a params.npz without seeds) as one line, exit 2.

The run directory is written directly (config.yaml + params.npz of random actors), so nothing is
trained; every refusal comes before any compilation. Two tests compile a small program to check
that the estimates bound what XLA allocates.
"""

import os

os.environ.setdefault("JAX_PLATFORMS", "cpu")

from pathlib import Path  # noqa: E402

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from fedjax_nav import cli, worlds  # noqa: E402
from fedjax_nav.agents import buffer as rb  # noqa: E402
from fedjax_nav.agents import ddpg  # noqa: E402
from fedjax_nav.agents.networks import Actor  # noqa: E402
from fedjax_nav.config import from_dict, load_config, save_config  # noqa: E402
from fedjax_nav.config.memory import nbytes, over_budget  # noqa: E402
from fedjax_nav.env.nav import make_params  # noqa: E402
from fedjax_nav.evaluation import (  # noqa: E402
    EvalError,
    actor_policy,
    evaluate_policy,
    evaluate_run,
    evaluate_runs,
    load_run,
)
from fedjax_nav.evaluation.limits import eval_memory  # noqa: E402
from fedjax_nav.evaluation.rollout import episode_state, eval_program  # noqa: E402
from fedjax_nav.evaluation.suite import evaluate_suite  # noqa: E402
from fedjax_nav.training.resources import ResourceError, activation_bytes, check_memory  # noqa: E402
from fedjax_nav.training.trainer import Trainer  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
HIDDEN, DEPTH, SEEDS, ROBOTS = 16, 1, 2, 2
GIB = 2**30


def one_line(capfd, argv, *needles) -> str:
    """`fedjax-nav ARGV` exits 2 with exactly one `error: ...` line holding every needle."""
    rc = cli.main([str(a) for a in argv])
    err = capfd.readouterr().err
    assert rc == 2, err[-3000:]
    assert "Traceback" not in err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), err[-3000:]
    for n in needles:
        assert n in lines[0], (n, lines[0])
    return lines[0]


def write_run(root: Path, seeds: int = SEEDS) -> Path:
    """An IDDPG run directory (2 robots, `seeds` seeds, T = 32) with random actors, untrained."""
    root.mkdir(parents=True)
    cfg = from_dict(
        {
            "method": "iddpg",
            "env": {"worlds": ["train-0", "train-2"], "episode_length": 32},
            "offpolicy": {"hidden": HIDDEN, "depth": DEPTH},
            "run": {"seeds": max(seeds, 1)},
        }
    )
    save_config(cfg, root / "config.yaml")
    params = Actor(HIDDEN, DEPTH).init(jax.random.key(0), jnp.zeros((28,)))
    flat = {
        "actor/" + "/".join(str(getattr(k, "key", k)) for k in kp): np.zeros((seeds, ROBOTS, *leaf.shape), np.float32)
        for kp, leaf in jax.tree_util.tree_flatten_with_path(params)[0]
    }
    np.savez(root / "params.npz", **flat)
    return root


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    return write_run(tmp_path_factory.mktemp("memrun") / "iddpg")


# ----------------------------------------------------------------------------- evaluation


@pytest.mark.parametrize(
    "flags, needles",
    [
        (["--attempts", "100000000"], ["--attempts 100000000", "4 agents x 4 goals x 100000000 attempts"]),
        (["--max-steps", "100000000"], ["--max-steps 100000000", "episodes of up to 100000000 steps"]),
        (["--suite", "cylinders-probe", "--attempts", "100000000"], ["--attempts 100000000", "4 rooms x 4 agents"]),
    ],
    ids=["attempts", "max-steps", "suite"],
)
def test_an_evaluation_beyond_the_memory_is_refused_before_allocating(run_dir, capfd, flags, needles):
    """Before: 22.5 GB and the OOM killer (--attempts 1e8), 17.8 GB in 30 s (--max-steps 1e8)."""
    line = one_line(
        capfd, ["evaluate", run_dir, *flags], *needles, "more than the memory available now", "lower --attempts"
    )
    assert "trajectories" in line and str(run_dir) in line
    assert not (run_dir / "eval").exists()


@pytest.mark.parametrize("flags", [[], ["--suite", "cylinders-probe"]], ids=["world", "suite"])
def test_evaluate_takes_a_memory_budget_as_train_does(run_dir, capfd, flags):
    """`evaluate --memory-budget SIZE` (before: an unrecognized argument; only the API took one)."""
    one_line(
        capfd,
        ["evaluate", run_dir, *flags, "--memory-budget", "1K"],
        "--max-steps 32: the evaluation needs about",
        "more than the memory budget (--memory-budget), 1.0 KiB",
    )
    assert not (run_dir / "eval").exists()


@pytest.mark.parametrize("text", ["inf", "0", "-1G", "lots"])
def test_evaluate_refuses_a_budget_that_is_not_a_size(run_dir, capfd, text):
    one_line(capfd, ["evaluate", run_dir, f"--memory-budget={text}"], "--memory-budget", "expected a positive size")
    assert not (run_dir / ".lock").exists()  # refused before the run was locked


def test_evaluation_takes_trains_budget_rule(run_dir):
    """One rule (`config.memory.over_budget`) with the budget given, for runs, suites and policies."""
    run = load_run(run_dir)
    with pytest.raises(EvalError, match=r"more than the memory budget \(--memory-budget\), 10.0 KiB"):
        evaluate_run(run, "eval", attempts=4, memory_budget=10 * 2**10)
    with pytest.raises(EvalError, match=r"--attempts 2, --max-steps 32: .*4 rooms x 4 agents x 2 goals x 2 attempts"):
        evaluate_suite(run_dir, "cylinders-probe", attempts=2, memory_budget=2**10)
    with pytest.raises(EvalError, match="1 agents x 1 goals x 3 attempts = 3 episodes of up to 1000 steps"):
        evaluate_policy(lambda obs: jnp.zeros(2), "eval", goals=[0], attempts=3, max_steps=1000, memory_budget=2**10)
    assert over_budget(10 * 2**10, 10 * 2**10) is None and "10.0 KiB" in over_budget(10 * 2**10 + 1, 10 * 2**10)


def test_the_evaluation_estimate_bounds_the_compiled_program():
    """XLA's output + temporaries of the evaluation program fit in the estimate's device part,
    within 2x: the estimate is an honest bound, not a guess far above it."""
    A, G, K, T = 2, 1, 8, 64
    world = worlds.load("train-0")
    settings = {"num_beams": 24, "max_range": 3.5, "collision_test": "exact", "episode_length": T}
    settings |= {"mode": "eval", "noise": True}
    params = make_params(world, range_noise=0.01, action_noise=0.01)
    actor = jax.eval_shape(
        lambda k: jax.vmap(lambda kk: Actor(HIDDEN, DEPTH).init(kk, jnp.zeros((28,))))(jax.random.split(k, A)),
        jax.random.key(0),
    )
    keys = jax.eval_shape(lambda: jax.random.split(jax.random.key(0), A * G * K).reshape(A, G * K))
    program = eval_program(settings, actor_policy(HIDDEN, DEPTH, "relu"), 32)
    mem = program.lower(actor, params, jnp.zeros(G, jnp.int32), keys).compile().memory_analysis()
    compiled = mem.output_size_in_bytes + mem.temp_size_in_bytes
    est = eval_memory(settings, episode_state(settings, params), A * G * K, 32)
    device = est["total"] - est["host"]
    assert compiled <= device <= 2 * compiled, (compiled, est)


@pytest.mark.parametrize(
    "counts, needle",
    [
        ({"max_steps": 0}, r"--max-steps: must be an integer in \[1, 2,147,483,646\], got 0"),
        ({"max_steps": -5}, "--max-steps: .* got -5"),
        ({"attempts": 0}, "--attempts: must be an integer >= 1, got 0"),
        ({"attempts": -1}, "--attempts: must be an integer >= 1, got -1"),
    ],
    ids=["max-steps-0", "max-steps-negative", "attempts-0", "attempts-negative"],
)
def test_zero_attempts_or_steps_are_refused(run_dir, counts, needle):
    """Before: max_steps 0 silently meant the run's T; the suite ran 0 or -1 attempts. (The CLI's
    parser refuses them too; these are the API's callers: reports, scripts, notebooks.)"""
    calls = {
        "evaluate_run": lambda: evaluate_run(run_dir, **counts),
        "evaluate_runs": lambda: evaluate_runs([run_dir], figures=False, echo=lambda _: None, **counts),
        "evaluate_suite": lambda: evaluate_suite(run_dir, "cylinders-probe", **counts),
    }
    for name, call in calls.items():
        with pytest.raises(EvalError, match=needle):
            call()
            pytest.fail(f"{name} accepted {counts}")
    assert not (run_dir / "eval").exists()


@pytest.mark.parametrize("command", ["evaluate", "export"])
def test_a_params_file_without_seeds_is_one_line(tmp_path, capfd, command):
    run = write_run(tmp_path / "empty", seeds=0)
    argv = [command, run] + (["--out", tmp_path / "exported"] if command == "export" else [])
    one_line(capfd, argv, f"{run / 'params.npz'}: the actor arrays have no seeds")


# ----------------------------------------------------------------------------- training


# 1000 episodes: a buffer receives 1,024,000 rows, so a batch of 1e6 is drawn (shorter, the run
# could never update and the config itself is refused: tests/test_config.py)
BIG_BATCH = ["offpolicy.batch_size=1000000", "offpolicy.buffer_size=1000000", "run.episodes=1000"]


def big_batch_config():
    return load_config(ROOT / "configs/thesis/flddpg.yaml", BIG_BATCH)


def test_train_counts_the_update_activations():
    """batch 1e6 x buffer 1e6 (FLDDPG, 5 networks): the state is ~1.1 GiB, one update ~21 GB (the
    allocation that failed with a traceback); the estimate names offpolicy.batch_size."""
    with pytest.raises(ResourceError) as info:
        check_memory(Trainer(big_batch_config()), budget=8 * GIB, src="flddpg.yaml")
    msg = str(info.value)
    assert msg.startswith("flddpg.yaml: offpolicy.batch_size = 1000000: the run needs about 2"), msg
    assert "update 23.7 GiB" in msg and "memory budget (--memory-budget), 8.0 GiB" in msg, msg


def test_train_refuses_the_big_batch_before_allocating(tmp_path, capfd):
    out = tmp_path / "run"
    one_line(
        capfd,
        ["train", "--config", ROOT / "configs/thesis/flddpg.yaml", "--out", out, "--quiet", "--memory-budget", "8G"]
        + [arg for item in BIG_BATCH for arg in ("--set", item)],
        "offpolicy.batch_size = 1000000",
        "update 23.7 GiB",
    )
    assert not out.exists()


@pytest.mark.parametrize("name", sorted(p.name for p in (ROOT / "configs/thesis").glob("*.yaml")))
def test_thesis_presets_fit_with_a_big_margin(name):
    est = check_memory(Trainer(load_config(ROOT / "configs/thesis" / name)), budget=2 * GIB)
    assert est["update"] > 0 and est["total"] - est["compiler"] < 256 * 2**20, est


def test_a_budget_below_compiling_the_program_says_so():
    """Below what compiling takes (the largest part of a small run), the line names the compiler and
    --memory-budget, not a field that would not help."""
    with pytest.raises(ResourceError, match="compiling the program alone takes about 1.2 GiB: raise --memory-budget"):
        check_memory(Trainer(load_config(ROOT / "configs/thesis/flddpg.yaml")), budget=GIB)


@pytest.mark.parametrize("batch, hidden, depth", [(4096, 64, 3), (2048, 128, 1)])
def test_the_activation_estimate_bounds_the_compiled_update(batch, hidden, depth):
    """XLA's temporaries of one vmapped `ddpg.update` (2 networks) fit in `activation_bytes`, within 2x."""
    nets, obs = 2, 28
    n = ddpg.make_nets(hidden, depth, "relu")
    agents = jax.eval_shape(
        lambda k: jax.vmap(lambda kk: ddpg.init_agent(n, kk, obs))(jax.random.split(k, nets)), jax.random.key(0)
    )
    f32 = lambda *s: jax.ShapeDtypeStruct(s, jnp.float32)  # noqa: E731
    batch_shapes = rb.Transition(
        obs=f32(nets, batch, obs),
        action=f32(nets, batch, 2),
        reward=f32(nets, batch),
        next_obs=f32(nets, batch, obs),
        done=f32(nets, batch),
    )
    update = jax.jit(jax.vmap(lambda a, b: ddpg.update(n, a, b, 0.9, 1e-3)))
    temp = update.lower(agents, batch_shapes).compile().memory_analysis().temp_size_in_bytes
    est = activation_bytes(obs, hidden, depth, batch) * nets
    assert temp <= est <= 2 * temp, (temp, est)
    assert nbytes(batch_shapes) < est
