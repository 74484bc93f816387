"""Shared rooms (docs/shared_rooms.md, env/shared.py): the fleet drives in one room together.

Checked against independent references: the lidar with robots as discs against the float64
numpy lidar of tests/test_geometry.py; robot-robot contact against a brute-force float64
distance check; the placement against exact distances and the grid search of
tests/test_generate.py. A fleet of one in shared rooms is today's single-robot program, bitwise
(fixed and procedural rooms); bad settings are one line naming the field, exit 2.
"""

import json
import math
import os

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest
import yaml
from test_checkpoint import SEEDS, TINY, assert_same_run, run_cli, start_until_checkpoint, stop
from test_generate import nearest, real_rows, unreachable_pairs
from test_geometry import lidar_ref

from fedjax_nav import cli, worlds
from fedjax_nav.config import load_config
from fedjax_nav.env import shared
from fedjax_nav.env.nav import NavEnv, make_params
from fedjax_nav.training.hparams import hparams_from_config
from fedjax_nav.training.trainer import Trainer
from fedjax_nav.worlds.procedural import generate
from fedjax_nav.worlds.rooms import make_spec
from fedjax_nav.worlds.suites import train_room_key

R = 0.25  # D_c, the robots' disc radius


def test_the_lidar_sees_the_other_robots_as_discs_as_the_float64_reference():
    world = worlds.load("train-2")
    env, params = NavEnv(), make_params(worlds.load("train-2"))
    ranges = jax.jit(env.ranges)
    rng = np.random.default_rng(0)
    room = real_rows(world)
    checked = 0
    for _ in range(40):
        pose = np.array([*rng.uniform(-2.5, 2.5, 2), rng.uniform(-np.pi, np.pi)], np.float32)
        others = np.concatenate([pose[:2] + rng.uniform(-1.5, 1.5, (5, 2)), np.full((5, 1), R)], 1).astype(np.float32)
        others[rng.integers(5), 2] = 0.0  # one row is the robot itself: never seen
        got = np.asarray(ranges(jnp.asarray(pose), params, jnp.asarray(others)))
        ref = lidar_ref(room["segments"], pose, circles=np.concatenate([room["circles"], others[others[:, 2] > 0]]))
        np.testing.assert_allclose(got, ref, atol=2e-4)
        checked += int((got < 3.5).sum())
    assert checked > 200  # the beams did hit robots and walls


def test_two_robots_closer_than_twice_the_radius_both_collide_as_a_brute_force_check():
    robots, per = 6, 3
    env = NavEnv()
    world = worlds.load("eval")  # 12 x 12 m; only robot-robot contact is checked here
    params = jax.vmap(lambda _: make_params(world))(jnp.arange(robots * per))
    keys = jax.random.split(jax.random.key(1), robots * per)
    _, states = jax.vmap(env.reset)(keys, params)
    rng = np.random.default_rng(2)
    present = np.array([True, True, True, True, True, False])  # the last: a mesh's padding client
    step = jax.jit(shared.fleet_step(env, present, per))
    seen = 0
    for _ in range(20):
        xy = rng.uniform(-1.0, 1.0, (robots * per, 2)).astype(np.float32)
        states = states.replace(pose=jnp.asarray(np.concatenate([xy, np.zeros((robots * per, 1), np.float32)], 1)))
        stay = jnp.zeros((robots * per, 2))  # v = 0, omega = 0: the poses reached are these
        *_, info = step(keys, states, stay, params)
        p = xy.astype(np.float64).reshape(robots, per, 2)
        d = np.linalg.norm(p[:, None] - p[None, :], axis=-1)  # [i, i', room]
        near = (d < 2 * R) & ~np.eye(robots, dtype=bool)[..., None] & present[None, :, None]
        want = near.any(axis=1) & present[:, None]  # [robot, room]
        clear = np.abs(d - 2 * R) > 1e-5
        ok = clear.all(axis=1)
        got = np.asarray(info["robot_collision"]).reshape(robots, per)
        np.testing.assert_array_equal(got[ok], want[ok])
        assert not got[~present].any()
        seen += int(want.sum())
    assert seen > 20


def test_the_near_reward_is_paid_when_another_disc_is_within_the_clearance_as_a_brute_force_check():
    robots, clearance, near = 5, 0.3, -1.0
    env, world = NavEnv(), worlds.load("eval")
    base = jax.vmap(lambda _: make_params(world))(jnp.arange(robots))
    paid = base.replace(
        reward_robot_near=jnp.full(robots, near, jnp.float32), robot_clearance=jnp.full(robots, clearance, jnp.float32)
    )
    keys = jax.random.split(jax.random.key(3), robots)
    _, states = jax.vmap(env.reset)(keys, base)
    step = jax.jit(shared.fleet_step(env, np.ones(robots, bool), 1))
    rng, seen = np.random.default_rng(4), 0
    for _ in range(20):
        xy = rng.uniform(-1.2, 1.2, (robots, 2)).astype(np.float32)
        states = states.replace(pose=jnp.asarray(np.concatenate([xy, np.zeros((robots, 1), np.float32)], 1)))
        stay = jnp.zeros((robots, 2))
        off = step(keys, states, stay, base)[2]
        on = step(keys, states, stay, paid)[2]
        d = np.linalg.norm(xy.astype(np.float64)[:, None] - xy[None], axis=-1) + 1e9 * np.eye(robots)
        ok = (np.abs(d - (2 * R + clearance)) > 1e-5).all(axis=1)
        want = np.where((d < 2 * R + clearance).any(axis=1), near, 0.0)
        np.testing.assert_allclose(np.asarray(on - off)[ok], want[ok], atol=1e-5)
        seen += int((want[ok] != 0).sum())
    assert seen > 10


@pytest.fixture(scope="module")
def mixture_rooms():
    spec = make_spec("mixture")
    keys = jax.vmap(train_room_key)(jnp.arange(64, dtype=jnp.uint32))
    rooms = jax.jit(jax.vmap(lambda k: generate(k, spec)))(keys)
    placed = jax.jit(jax.vmap(lambda w, k: shared.place_fleet(w, k, 4)))(rooms, jax.random.split(jax.random.key(3), 64))
    return rooms, placed


def test_a_room_robots_start_and_end_apart_clear_of_every_obstacle(mixture_rooms):
    rooms, placed = mixture_rooms
    for i in range(64):
        room = real_rows(rooms, i)
        pts = np.concatenate([np.asarray(placed.starts[i, :, 0, :2]), np.asarray(placed.goals[i, :, 0])])
        d = np.linalg.norm(pts[:, None] - pts[None], axis=-1) + np.eye(8) * 1e9
        assert d.min() >= shared.SEPARATION - 1e-5, (i, d.min())
        assert min(nearest(room, p) for p in pts) > worlds.CLEARANCE, i
        assert np.all(np.asarray(placed.num_starts[i]) == 1) and np.all(np.asarray(placed.num_goals[i]) == 1)


def test_the_drawn_starts_reach_their_goals_by_the_independent_grid_search(mixture_rooms):
    """Drawn in free space, not by the generator's construction: reachable in these 64 mixture
    rooms x 4 robots (the grid search of tests/test_generate.py decides)."""
    rooms, placed = mixture_rooms
    bad = []
    for i in range(64):
        room = real_rows(rooms, i)
        for r in range(4):
            one = dict(room, starts=np.asarray(placed.starts[i, r, :1]), goals=np.asarray(placed.goals[i, r, :1]))
            bad += [(i, r)] if unreachable_pairs(one) else []
    assert len(bad) <= 256 // 50, bad  # at most 2% of the pairs


def _chunk(cfg, episodes=2):
    tr = Trainer(cfg)
    hp = hparams_from_config(cfg)
    states = tr.init_seeds(jnp.arange(1), hp)
    states, metrics = jax.jit(lambda s: tr.chunk(s, hp, jnp.int32(0), episodes))(states)
    return states, metrics


@pytest.mark.parametrize(
    "sets",
    [
        ["method=iddpg", "env.worlds=[train-0]", "env.episode_length=64", "offpolicy.hidden=16"],
        pytest.param(
            [
                "method=iddpg",
                "learner=ppo",
                "env.worlds=[train-0]",
                "env.rooms=procedural",
                "env.episode_length=64",
                "env.envs_per_robot=2",
                "ppo.rollout=32",
                "ppo.hidden=16",
            ],
            marks=pytest.mark.full,
        ),
    ],
    ids=["fixed", "procedural"],
)
def test_a_fleet_of_one_in_shared_rooms_is_the_single_robot_program_bitwise(sets):
    cfg = load_config(None, sets + ["run.seeds=1"])
    on = load_config(None, sets + ["run.seeds=1", "env.shared_rooms=true"])
    (a, ma), (b, mb) = _chunk(cfg), _chunk(on)
    assert "robot_collisions" in mb and int(np.asarray(mb["robot_collisions"]).sum()) == 0
    for x, y in zip(
        jax.tree.leaves((a.agents, ma["reward"], ma["collisions"])),
        jax.tree.leaves((b.agents, mb["reward"], mb["collisions"])),
    ):
        assert np.asarray(x).tobytes() == np.asarray(y).tobytes()


@pytest.mark.full
def test_a_shared_fleet_is_placed_together_and_meets(tmp_path):
    """Four robots in two shared procedural rooms: every environment j holds the same room for
    every robot, the robots' starts apart; a short run reports robot-robot collisions."""
    sets = [
        "method=iddpg",
        "learner=ppo",
        "env.worlds=[train-0,train-0,train-0,train-0]",
        "env.rooms=procedural",
        "env.episode_length=64",
        "env.envs_per_robot=2",
        "ppo.rollout=32",
        "ppo.hidden=16",
        "run.seeds=1",
        "env.shared_rooms=true",
    ]
    cfg = load_config(None, sets)
    tr = Trainer(cfg)
    state = tr.init_seeds(jnp.arange(1), hparams_from_config(cfg))
    st = jax.tree.map(lambda x: x[0], state)
    _, world = tr.rooms.episode_world(st, hparams_from_config(cfg), jnp.int32(0))
    segs = np.asarray(world.segments).reshape(4, 2, *world.segments.shape[1:])
    assert (segs == segs[:1]).all()  # room j: one room for the fleet
    starts = np.asarray(world.starts[:, 0, :2]).reshape(4, 2, 2)
    d = np.linalg.norm(starts[:, None] - starts[None], axis=-1) + np.eye(4)[..., None] * 1e9
    assert d.min() >= shared.SEPARATION - 1e-5
    fast = load_config(None, sets + ["env.v_max=1.0", "env.episode_length=128"])
    _, m = _chunk(fast, episodes=3)
    assert np.asarray(m["robot_collisions"]).sum() > 0  # untrained robots do meet (12 of 244 collisions here)
    assert (np.asarray(m["robot_collisions"]) <= np.asarray(m["collisions"])).all()


@pytest.mark.parametrize(
    "sets, field",
    [
        (["env.shared_rooms=true"], "env.worlds"),  # the thesis's five different playgrounds
        (["env.shared_rooms=true", "env.worlds=[train-0,train-0,train-0,train-0,train-0]"], "env.worlds"),  # 1 goal
        (["env.shared_rooms=true", "env.rooms=procedural", "env.room_sampling=learnability"], "env.room_sampling"),
        (
            ["env.shared_rooms=true", "env.rooms=procedural", "env.room_families=[forest,maze,cave,mixture,warehouse]"],
            "env.room_families",
        ),
        (["env.reward_robot_near=-0.5"], "env.reward_robot_near"),  # robots alone: never paid
        (["env.plan_keep_right=0.3"], "env.plan_keep_right"),  # robots alone: no one to keep right of
        (["env.give_way=0.05"], "env.give_way"),  # nor to give way to
        (["env.give_way_door=1.2"], "env.give_way_door"),  # nor to wait for at a door
    ],
    ids=[
        "five-worlds",
        "one-goal",
        "learnability",
        "families",
        "near-alone",
        "keep-right-alone",
        "give-way-alone",
        "door-alone",
    ],
)
def test_bad_shared_room_settings_are_one_line_naming_the_field(sets, field, tmp_path, capfd):
    argv = ["train", "--config", "thesis/flddpg", "--episodes", "2", "--out", str(tmp_path / "run")]
    for s in sets:
        argv += ["--set", s]
    assert cli.main(argv) == 2
    err = capfd.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and field in lines[0] and "Traceback" not in err, err
    assert not (tmp_path / "run").exists()


@pytest.fixture(scope="module")
def cli_env():
    return dict(os.environ, JAX_PLATFORMS="cpu", PYTHONUNBUFFERED="1")


@pytest.mark.full
def test_a_shared_room_run_resumes_bitwise_after_a_kill(cli_env, tmp_path):
    env = cli_env
    tiny = dict(TINY, env=dict(TINY["env"], shared_rooms=True, placement="random"))
    cfg = tmp_path / "shared.yaml"
    cfg.write_text(yaml.safe_dump(tiny))
    ref = tmp_path / "ref"
    r = run_cli(env, "train", "--config", cfg, "--out", ref, "--quiet")
    assert r.returncode == 0, r.stderr[-3000:]
    out = tmp_path / "run"
    proc = start_until_checkpoint(env, out, "--config", cfg, "--out", out)
    stop(proc)
    r = run_cli(env, "train", "--resume", out, "--quiet")
    assert r.returncode == 0, r.stderr[-3000:]
    assert_same_run(ref, out)
    assert SEEDS == 2


def test_the_shared_room_benchmark_row_times_both_sides():
    from fedjax_nav.experiments.bench import format_rows
    from fedjax_nav.experiments.bench_shared import bench_shared

    (row,) = bench_shared(ks=(2,), rooms=4, steps=5)
    assert row["robots_per_room"] == 2 and row["shared_steps_per_s"] > 0 and row["separate_steps_per_s"] > 0
    assert abs(row["cost_per_robot"] - row["separate_steps_per_s"] / row["shared_steps_per_s"]) < 1e-9
    assert "2 robots per room x 4 procedural mixture rooms" in format_rows([row])


# ----------------------------------------------------------------------------- evaluation with K robots per room


def test_a_deadlock_is_a_timed_out_robot_near_another_timed_out_one():
    from fedjax_nav.evaluation.shared_rooms import DEADLOCK_DISTANCE, deadlocks

    rng = np.random.default_rng(4)
    final = rng.uniform(-1.5, 1.5, (30, 5, 3))
    timeout = rng.random((30, 5)) < 0.6
    got = deadlocks(final, timeout)
    for r in range(30):
        for i in range(5):
            near = [
                j
                for j in range(5)
                if j != i and timeout[r, j] and math.dist(final[r, i, :2], final[r, j, :2]) < DEADLOCK_DISTANCE
            ]
            assert got[r, i] == (bool(timeout[r, i]) and bool(near))
    assert got.any() and not got.all()


@pytest.fixture(scope="module")
def untrained(tmp_path_factory):
    """A run directory evaluate accepts: config.yaml and the initial params.npz of 2 robots, 1 seed."""
    from fedjax_nav import rundir

    run = tmp_path_factory.mktemp("shared_eval") / "run"
    run.mkdir()
    cfg = load_config(None, ["method=iddpg", "env.worlds=[train-0,train-0]", "offpolicy.hidden=16", "run.seeds=1"])
    rundir.write_config(run, cfg)
    rundir.write_params(run, Trainer(cfg).init_seeds(jnp.arange(1), hparams_from_config(cfg)).agents)
    return run


@pytest.mark.full
def test_every_robot_episode_has_one_outcome_per_k_and_family(untrained, capfd):
    argv = ["evaluate", str(untrained), "--suite", "mixture-50", "--robots-per-room", "1,3", "--max-steps", "48"]
    assert cli.main(argv) == 0
    out = untrained / "eval" / "mixture-50-shared"
    ep = pd.read_csv(out / "shared_episodes.csv")
    assert sorted(ep.robots_per_room.unique()) == [1, 3]
    for k in (1, 3):
        part = ep[ep.robots_per_room == k]
        assert len(part) == 50 * 2 * k  # rooms x agents x robots
    ends = ep[["success", "collision", "robot_collision", "timeout"]].sum(axis=1)
    assert (ends == 1).all()  # one outcome each, as the single-robot evaluation
    one = ep[ep.robots_per_room == 1]
    assert one.robot_collision.sum() == 0 and one.deadlock.sum() == 0
    assert (ep.deadlock <= ep.timeout).all()
    fams = pd.read_csv(out / "shared_families.csv")
    assert list(fams.family) == ["mixture", "all", "mixture", "all"]
    summary = json.loads((out / "shared.json").read_text())
    assert summary["robots_per_room"] == [1, 3] and summary["rooms"] == 50
    assert (out / "shared_trajectories.png").stat().st_size > 10_000
    assert "3 robot(s) per room: success" in capfd.readouterr().out


@pytest.mark.parametrize(
    "flags, field",
    [
        (["--robots-per-room", "2"], "eval-crossing"),
        (["--suite", "mixture-50", "--robots-per-room", "1,17"], "[1, 16]"),
    ],
    ids=["one-start-world", "too-many"],
)
def test_bad_robots_per_room_are_one_line(untrained, capfd, flags, field):
    assert cli.main(["evaluate", str(untrained), *flags]) == 2
    err = capfd.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--robots-per-room" in err[0] and field in err[0], err


@pytest.mark.full
def test_the_arena_crossing_drives_robot_i_from_start_i_to_goal_i(untrained, capfd):
    argv = ["evaluate", str(untrained), "--world", "eval-crossing", "--robots-per-room", "4", "--attempts", "2"]
    assert cli.main(argv + ["--max-steps", "32", "--no-figures"]) == 0
    out = untrained / "eval" / "eval-crossing-shared"
    ep = pd.read_csv(out / "shared_episodes.csv")
    assert len(ep) == 2 * 2 * 4 and set(ep.family) == {"eval-crossing"}  # attempts x agents x robots
    assert (ep[["success", "collision", "robot_collision", "timeout"]].sum(axis=1) == 1).all()
    w = worlds.load("eval-crossing")
    starts, goals = np.asarray(w.starts)[:, :2], np.asarray(w.goals)
    np.testing.assert_allclose(goals, -0.84 * starts)  # each robot towards the opposite corner: the paths cross
    assert json.loads((out / "shared.json").read_text())["world"] == "eval-crossing"


@pytest.mark.full
def test_out_takes_the_shared_evaluation_elsewhere_and_leaves_the_run_as_it_was(untrained, tmp_path):
    before = sorted(p.relative_to(untrained) for p in untrained.rglob("*"))
    argv = ["evaluate", str(untrained), "--world", "eval-crossing", "--robots-per-room", "4", "--attempts", "1"]
    assert cli.main(argv + ["--max-steps", "16", "--no-figures", "--out", str(tmp_path / "x")]) == 0
    assert len(pd.read_csv(tmp_path / "x" / "shared_episodes.csv")) == 1 * 2 * 4  # attempts x agents x robots
    assert sorted(p.relative_to(untrained) for p in untrained.rglob("*") if p.name != ".lock") == [
        p for p in before if p.name != ".lock"
    ]


def test_out_with_several_runs_in_shared_rooms_is_one_line(untrained, tmp_path, capfd):
    argv = ["evaluate", str(untrained), str(untrained), "--world", "eval-crossing", "--robots-per-room", "4"]
    assert cli.main(argv + ["--out", str(tmp_path / "x")]) == 2
    err = capfd.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--out" in err[0], err
    assert not (tmp_path / "x").exists()
