"""The global plan (docs/planning.md, `fedjax_nav/env/plan.py`): the distance field against an
independent float64 Dijkstra (scipy) on a thesis world and procedural maze and office rooms, the
waypoint's descent and clearance, the observation with the plan on, a tiny training run that
resumes and is evaluated, and the refusal of a world whose start cannot reach its goal."""

import io
import json
from contextlib import redirect_stderr, redirect_stdout
from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest
from scipy.sparse.csgraph import dijkstra
from test_rooms_training import TINY as ROOMS_TINY

from fedjax_nav import cli, worlds
from fedjax_nav.config import load_config
from fedjax_nav.config.envs import env_settings
from fedjax_nav.env import make, nearest_distance, plan
from fedjax_nav.evaluation.paths import _graph
from fedjax_nav.worlds import point_segment_distance_np
from fedjax_nav.worlds.procedural import generate
from fedjax_nav.worlds.rooms import make_spec

CELLS = 48
D_C, D_G = 0.25, 0.5


@pytest.fixture(scope="module")
def rooms():
    return {
        "train-2": worlds.load("train-2"),
        "maze": generate(jax.random.key(3), make_spec("maze")),
        "office": generate(jax.random.key(5), make_spec("office")),
    }


@pytest.fixture(scope="module")
def fields():
    """jit(free, seeds, res, field) of one room (compiled once per room shape)."""

    def one(world, goal):
        free = plan.free_cells(world, D_C, CELLS)
        seeds = plan.goal_cells(free, world.size, goal, D_G)
        res = plan.grid(world.size, CELLS)[0]
        field, passes = plan.distance_field(free, seeds, res)
        return free, seeds, res, field, passes

    return jax.jit(one)


def _free_f64(world) -> tuple[np.ndarray, np.ndarray]:
    """(free, margin): the grid's free cells in float64 from the world's rows, and each centre's
    distance to the threshold (cells within float32 rounding of it may differ)."""
    size = np.asarray(world.size, np.float64)
    res = size.max() / CELLS
    xs = res * (np.arange(CELLS) + 0.5) - size[0] / 2
    ys = res * (np.arange(CELLS) + 0.5) - size[1] / 2
    pts = np.stack(np.meshgrid(xs, ys), axis=-1)
    segs = np.asarray(world.segments, np.float64)
    segs = segs[np.hypot(segs[:, 2] - segs[:, 0], segs[:, 3] - segs[:, 1]) > 0]
    d = point_segment_distance_np(pts, segs).min(-1)
    for cx, cy, r in np.asarray(world.circles, np.float64):
        if r > 0:
            d = np.minimum(d, np.hypot(pts[..., 0] - cx, pts[..., 1] - cy) - r)
    inside = (np.abs(xs)[None, :] < size[0] / 2) & (np.abs(ys)[:, None] < size[1] / 2)
    return inside & (d >= D_C), np.abs(d - D_C)


@pytest.mark.parametrize("name", ["train-2", "maze", "office"])
def test_the_field_is_dijkstras_on_the_inflated_grid(rooms, fields, name):
    world = rooms[name]
    free, seeds, res, field, passes = (np.asarray(a) for a in fields(world, world.goals[0]))
    ref_free, margin = _free_f64(world)
    assert ((free == ref_free) | (margin < 1e-5)).all()
    src = np.flatnonzero(seeds.ravel())
    assert src.size, "the goal has free cells"
    ref = dijkstra(_graph(free, float(res)), directed=False, indices=src, min_only=True).reshape(free.shape)
    reach = np.isfinite(ref)
    assert (np.isfinite(field) == reach).all()
    np.testing.assert_allclose(field[reach], ref[reach], rtol=2e-6, atol=1e-5)
    assert reach.sum() > 0.5 * free.sum() and 1 <= int(passes) < 20


MARGIN = 0.3


@pytest.fixture(scope="module")
def margin_fields():
    """jit(free, seeds, res, cost, field) of one room with the margin `m` (docs/planning.md, "The margin")."""

    def one(world, goal, m):
        free, cost = plan.cell_costs(world, D_C, m, CELLS)
        seeds = plan.goal_cells(free, world.size, goal, D_G)
        res = plan.grid(world.size, CELLS)[0]
        return free, seeds, res, cost, plan.distance_field(free, seeds, res, cost)[0]

    return jax.jit(one)


@pytest.mark.parametrize("name", ["maze", "office"])
def test_the_margins_field_is_dijkstras_with_the_cells_costs(rooms, margin_fields, name):
    world = rooms[name]
    free, seeds, res, cost, field = (np.asarray(a) for a in margin_fields(world, world.goals[0], MARGIN))
    # the costs against float64 clearances: 1 + 4 (1 - (d - D_c) / margin) within the margin, else 1
    ref_free, off = _free_f64(world)
    d = np.where(ref_free, D_C + off, D_C - off)  # each centre's distance, back from |d - D_c|
    ref_cost = 1.0 + plan.MARGIN_COST * np.clip(1.0 - (d - D_C) / MARGIN, 0.0, 1.0)
    np.testing.assert_allclose(cost[free], ref_cost[free], atol=1e-4)
    assert (cost[free] > 1).any() and (cost[free] == 1).any()
    # Dijkstra on the directed graph whose edge a -> b costs its length times cost[a]; run from the
    # goal's cells backwards (b -> a), so each column a is scaled by cost[a]
    g = _graph(free, float(res))
    back = (g + g.T).multiply(cost.ravel()[None, :].astype(np.float64)).tocsr()
    ref = dijkstra(back, directed=True, indices=np.flatnonzero(seeds.ravel()), min_only=True).reshape(free.shape)
    reach = np.isfinite(ref)
    assert (np.isfinite(field) == reach).all()
    np.testing.assert_allclose(field[reach], ref[reach], rtol=2e-6, atol=1e-5)


def test_margin_zero_is_the_plain_field_bit_for_bit(rooms, fields, margin_fields):
    world = rooms["maze"]
    _, _, _, plain, _ = fields(world, world.goals[0])
    _, _, _, cost, field = margin_fields(world, world.goals[0], 0.0)
    assert (np.asarray(cost) == 1.0).all()
    np.testing.assert_array_equal(np.asarray(field), np.asarray(plain))


def _descent(field, cost, res):
    """The cells of the path down `field` from its farthest finite cell (as `plan.waypoint` walks)."""
    f = np.asarray(field)
    y, x = np.unravel_index(np.argmax(np.where(np.isfinite(f), f, -1.0)), f.shape)
    cells = [(y, x)]
    while f[y, x] > 0:
        nb = [(y + dy, x + dx, s) for dy, dx, s in zip(plan._DY, plan._DX, plan._STEP)]
        nb = [(v, w, s) for v, w, s in nb if 0 <= v < f.shape[0] and 0 <= w < f.shape[1]]
        y, x, _ = min(nb, key=lambda c: f[c[0], c[1]] + c[2] * res * cost[y, x])
        cells.append((y, x))
    return cells


def test_the_margin_keeps_the_path_from_the_walls(rooms, margin_fields):
    world = rooms["maze"]
    _, xs, ys = (np.asarray(a) for a in plan.grid(world.size, CELLS))
    clear = {}
    for m in (0.0, MARGIN):
        _, _, res, cost, field = margin_fields(world, world.goals[0], m)
        path = _descent(field, np.asarray(cost), float(res))
        pts = jnp.asarray([[xs[x], ys[y]] for y, x in path], jnp.float32)
        clear[m] = np.asarray(jax.vmap(lambda p: nearest_distance(world.segments, p, world.circles))(pts))
    assert clear[0.0].min() >= D_C - 1e-5 and clear[MARGIN].min() >= D_C - 1e-5
    # the plain path runs along the inflated walls (most of it within D_c + 0.1 m: 77% on this
    # grid of 0.2 m cells); with the margin nearly none of it does, and it keeps 0.15 m more on average
    assert np.mean(clear[0.0] < D_C + 0.1) > 0.5 > 0.1 > np.mean(clear[MARGIN] < D_C + 0.1), clear
    assert clear[MARGIN].mean() > clear[0.0].mean() + 0.15, clear


@pytest.mark.parametrize("name", ["maze", "office"])
def test_the_waypoint_is_down_the_field_and_the_way_to_it_is_clear(rooms, fields, name):
    world = rooms[name]
    goal = world.goals[0]
    _, _, res, field, _ = fields(world, goal)
    res, f = float(res), np.asarray(field)
    look = 1.0
    iy, ix = np.nonzero(np.isfinite(f) & (f > look + 2 * res))
    pick = np.random.default_rng(0).choice(len(iy), 64, replace=False)
    _, xs, ys = (np.asarray(a) for a in plan.grid(world.size, CELLS))
    jitter = np.random.default_rng(1).uniform(-0.4, 0.4, (64, 2)) * res
    xy = np.stack([xs[ix[pick]], ys[iy[pick]]], axis=1) + jitter
    wp = np.asarray(
        jax.jit(jax.vmap(plan.waypoint, in_axes=(None, None, None, 0, None)))(field, world.size, goal, xy, look)
    )
    cell = jax.vmap(lambda p: jnp.stack(plan.cell_of(p, world.size, CELLS)))(jnp.asarray(xy))
    wcell = jax.vmap(lambda p: jnp.stack(plan.cell_of(p, world.size, CELLS)))(jnp.asarray(wp))
    here, there = f[tuple(np.asarray(cell).T)], f[tuple(np.asarray(wcell).T)]
    walked = here - there  # down the field; less than the lookahead where a corner cuts the sight
    assert (walked >= 0).all() and (walked <= look + 1.5 * res + 1e-4).all(), walked
    assert np.mean(walked > 0) > 0.9 and np.mean(walked >= look - 1e-4) > 0.5, walked
    # the straight way from the robot to its waypoint keeps nearly D_c (a cell's diagonal less)
    t = np.linspace(0.0, 1.0, 41)[:, None, None]
    pts = jnp.asarray((xy[None] + t * (wp - xy)[None]).reshape(-1, 2), jnp.float32)
    clear = np.asarray(jax.vmap(lambda p: nearest_distance(world.segments, p, world.circles))(pts))
    assert clear.min() >= D_C - res * np.sqrt(2) / 2 - 1e-4, clear.min()


def test_the_waypoint_is_the_goal_when_near_cut_off_or_started_in_a_wall():
    world = worlds.load("train-2")
    size, goal = world.size, world.goals[0]
    field = plan.goal_field(world, goal, D_C, D_G, CELLS)[0]
    wp = jax.jit(plan.waypoint)
    near = goal + jnp.array([0.6, 0.0])
    assert np.allclose(wp(field, size, goal, near, 1.0), goal)
    cut = jnp.full_like(field, jnp.inf)
    assert np.allclose(wp(cut, size, goal, jnp.array([0.0, 0.0]), 1.0), goal)
    # a robot near the wall x = W/2 (clearance 0.24 m): its cell is not free, the walk starts from a free neighbour
    xy = jnp.array([float(size[0]) / 2 - 0.24, 0.0])
    iy, ix = plan.cell_of(xy, size, CELLS)
    assert not np.isfinite(field[iy, ix])
    got = np.asarray(wp(field, size, goal, xy, 1.0))
    assert np.isfinite(got).all() and not np.allclose(got, goal)
    assert float(nearest_distance(world.segments, jnp.asarray(got), world.circles)) >= D_C
    assert 0.5 < np.linalg.norm(got - np.asarray(xy)) < 1.3


def test_observation_with_the_plan_on():
    env, params = make("Nav-v0", world="eval", plan=True, plan_cells=CELLS, episode_length=8)
    off, _ = make("Nav-v0", world="eval", episode_length=8)
    assert env.obs_size == off.obs_size + 1 == 29
    obs, st = jax.jit(env.reset)(jax.random.key(0), params)
    assert st.plan.field.shape == (CELLS, CELLS) and obs.shape == (29,)
    assert env.observation_space(params).contains(obs)
    assert np.isclose(obs[-1], st.dist)  # the goal's distance, last
    wp = plan.at(st.plan, params, st.goal, st.pose[:2])
    assert np.allclose(wp, st.plan.starts[st.start_index])  # the start's waypoint, kept for respawns
    assert np.isclose(obs[24], np.linalg.norm(np.asarray(wp) - np.asarray(st.pose[:2])), atol=1e-5)
    # a respawn inside the episode keeps the field (learn mode: drive into the wall)
    step = jax.jit(env.step)
    s = st
    for k in range(8):
        _, s, _, _, _, _ = step(jax.random.key(k), s, jnp.array([1.0, 0.0]), params)
    assert all(np.array_equal(a, b) for a, b in zip(jax.tree.leaves(s.plan), jax.tree.leaves(st.plan)))


def test_the_config_turns_it_on_and_off():
    cfg = load_config("thesis/flddpg")
    assert "plan" not in env_settings(cfg, "learn")  # off: the mapless settings as they were
    on = load_config("thesis/flddpg", ["env.plan=true", "env.plan_cells=32", "env.plan_lookahead=0.5"])
    s = env_settings(on, "learn")
    assert s["plan"] is True and s["plan_cells"] == 32


# test_rooms_training's tiny fleet (two thesis rooms), checkpointed every episode, with the plan
TINY = [*ROOMS_TINY, "run.checkpoint_every=1", "env.plan=true", f"env.plan_cells={CELLS}"]


def _cli(argv) -> tuple[int, str]:
    err, out = io.StringIO(), io.StringIO()
    with redirect_stderr(err), redirect_stdout(out):
        try:
            rc = cli.main([str(a) for a in argv])
        except SystemExit as e:
            rc = e.code
    return rc, err.getvalue()


def test_a_tiny_run_with_the_plan_trains_resumes_and_evaluates(tmp_path):
    out = tmp_path / "run"
    sets = [a for s in TINY for a in ("--set", s)]
    rc, err = _cli(["train", "--config", "thesis/flddpg", "--episodes", 2, *sets, "--out", out, "--quiet"])
    assert rc == 0, err[-2000:]
    rc, err = _cli(["train", "--resume", out, "--episodes", 3, "--allow-config-change", "--quiet"])
    assert rc == 0, err[-2000:]
    assert len(pd.read_csv(out / "metrics.csv")) == 3 * 2  # episodes x robots
    rc, err = _cli(["evaluate", out, "--world", "train-2", "--attempts", 1, "--max-steps", 16])
    assert rc == 0, err[-2000:]
    got = json.loads((out / "eval" / "train-2" / "eval.json").read_text())
    assert got and "Traceback" not in err


def test_a_world_whose_start_cannot_reach_its_goal_is_refused_in_one_line(tmp_path):
    walled = tmp_path / "walled.json"
    walled.write_text(
        json.dumps(
            {
                "size": [4.0, 2.0],
                "segments": [[0.0, -1.0, 0.0, 1.0]],  # a wall across the room
                "starts": [[-1.2, 0.0, 0.0]],
                "goals": [[1.2, 0.0]],
            }
        )
    )
    argv = ["train", "--config", "thesis/flddpg", "--episodes", 2, "--out", tmp_path / "run", "--quiet"]
    sets = ["env.episode_length=8", f"env.worlds=[{walled}]", "env.plan=true", "run.chunk_episodes=1"]
    rc, err = _cli(argv + [a for s in sets for a in ("--set", s)])
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert rc == 2 and len(lines) == 1 and lines[0].startswith("error: "), err[-1500:]
    assert "walled.json" in lines[0] and "env.plan" in lines[0] and "start 0" in lines[0]


def test_each_robot_of_a_shared_room_has_its_own_field():
    from fedjax_nav.env import NavEnv, make_params, shared

    env = NavEnv(episode_length=8, plan=True, plan_cells=CELLS)
    fleet = shared.fixed_fleet(worlds.load("eval-crossing"), 2)
    params = jax.vmap(make_params)(fleet)
    keys = jax.random.split(jax.random.key(0), 2)
    obs, st = jax.jit(jax.vmap(env.reset))(keys, params)
    assert obs.shape == (2, 29) and not np.array_equal(np.asarray(st.plan.field[0]), np.asarray(st.plan.field[1]))
    obs, st, *_ = jax.jit(shared.fleet_step(env, np.ones(2, bool), 1))(keys, st, jnp.ones((2, 2)) * 0.5, params)
    assert np.isfinite(np.asarray(obs)).all()


def test_the_gym_adapters_observation_space_comes_from_the_env():
    from fedjax_nav.env.gym_env import NavGymEnv

    """(NavVectorEnv runs the same gym_task; its space is this one's, batched.)"""
    g = NavGymEnv("train-2", plan=True, plan_cells=CELLS, plan_lookahead=0.8, episode_length=4)
    o, _ = g.reset(seed=0)
    assert o.shape == (29,) and g.observation_space.contains(o)
    o, *_ = g.step(np.array([0.5, 0.0], np.float32))
    assert g.observation_space.contains(o)


def test_the_brax_adapter_with_the_plan_on():
    brax_env = pytest.importorskip("fedjax_nav.env.brax_env")
    b = brax_env.BraxNavEnv("train-2", plan=True, plan_cells=CELLS)
    assert b.observation_size == 29
    s = jax.jit(b.reset)(jax.random.key(0))
    s = jax.jit(b.step)(s, jnp.zeros(2))
    assert s.obs.shape == (29,) and np.isfinite(np.asarray(s.obs)).all()


def test_with_the_margin_the_walk_leaves_a_cell_whose_next_cells_are_hidden():
    # a diagonal corridor of free cells (i, i), everything else blocked: from a point of cell (3, 3)
    # off its centre the straight way to (2, 2)'s centre crosses a blocked cell (out of sight)
    cells, size = 5, jnp.array([1.0, 1.0])
    res = 0.2
    diag = np.full((cells, cells), np.inf, np.float32)
    for i in range(cells):
        diag[i, i] = i * res * np.sqrt(2)
    field, goal = jnp.asarray(diag), jnp.array([-0.4, -0.4])
    _, xs, ys = (np.asarray(a) for a in plan.grid(size, cells))
    xy = jnp.array([xs[3] + 0.03, ys[3] - 0.03])
    walk = jax.jit(plan.waypoint)
    stuck = np.asarray(walk(field, size, goal, xy, 0.5, None, False))
    np.testing.assert_allclose(stuck, [xs[3], ys[3]], atol=1e-6)  # its own cell's centre: it would spin
    moved = np.asarray(walk(field, size, goal, xy, 0.5, None, True))
    np.testing.assert_allclose(moved, [xs[2], ys[2]], atol=1e-6)  # one step down, then the sight rule again
    # `plan.at` (what the env's step calls) sets it where the margin is on
    kept = plan.Plan(field, jnp.ones_like(field), jnp.zeros((1, 2)))
    for m, want in ((0.0, stuck), (MARGIN, moved)):
        p = SimpleNamespace(
            world=SimpleNamespace(size=size), plan_lookahead=jnp.float32(0.5), plan_margin=jnp.float32(m)
        )
        np.testing.assert_allclose(np.asarray(plan.at(kept, p, goal, xy)), want, atol=1e-6)


def _open_room(w: float = 6.0, h: float = 3.0):
    """A w x h m room with nothing in it, its field to the goal at (2.5, 0)."""
    from fedjax_nav.worlds.world import from_dict

    world = from_dict({"size": [w, h], "starts": [[-2.0, 0.0, 0.0]], "goals": [[2.5, 0.0]]})[0]
    return world, plan.goal_field(world, world.goals[0], D_C, D_G, CELLS)[0]


def test_keeping_right_moves_the_waypoint_right_only_while_a_robot_is_near_and_ahead():
    world, field = _open_room()
    kr = jax.jit(plan.keep_right)
    xy, wp = jnp.array([0.0, 0.0]), jnp.array([1.0, 0.0])  # driving +x: its right is -y

    def robots(*rows):
        return jnp.array([list(r) for r in rows] + [[9.0, 9.0, 0.0]], jnp.float32)  # and an absent row

    head_on = robots((1.0, 0.0, D_C))
    assert np.allclose(kr(field, world.size, xy, wp, head_on, 0.3, 1.5), [1.0, -0.3])
    # the other robot of the meeting, driving -x from (1, 0): its right is +y, so the two part
    assert np.allclose(kr(field, world.size, jnp.array([1.0, 0.0]), xy, robots((0.0, 0.0, D_C)), 0.3, 1.5), [0.0, 0.3])
    assert np.array_equal(kr(field, world.size, xy, wp, head_on, 0.0, 1.5), wp)  # off: the waypoint bitwise
    for rows in (((-1.0, 0.0, D_C),), ((2.0, 0.0, D_C),), ((1.0, 0.0, 0.0),)):  # behind, too far, absent
        assert np.array_equal(kr(field, world.size, xy, wp, robots(*rows), 0.3, 1.5), wp), rows
    assert np.allclose(kr(field, world.size, xy, wp, robots((2.0, 0.0, D_C)), 0.3, 2.5), [1.0, -0.3])  # reach
    # near the wall y = -1.5 (cells of 0.125 m: the free ones are those above y = -1.25, their centres
    # D_c or more from the wall): 0.3 m right would leave them, 0.15 m does not
    xy, wp = jnp.array([0.0, -1.0]), jnp.array([1.0, -1.0])
    got = np.asarray(kr(field, world.size, xy, wp, robots((1.0, -1.0, D_C)), 0.3, 1.5))
    assert np.allclose(got, [1.0, -1.15])
    # nearer still: not even half fits, the waypoint stays
    xy, wp = jnp.array([0.0, -1.2]), jnp.array([1.0, -1.2])
    assert np.array_equal(kr(field, world.size, xy, wp, robots((1.0, -1.2, D_C)), 0.3, 1.5), wp)


def test_a_shared_rooms_observation_keeps_right_with_the_params():
    from fedjax_nav.env import NavEnv, make_params, shared

    world, _ = _open_room()
    fleet = shared.own(world, jnp.array([-1.0, 0.0, 0.0]), jnp.array([2.5, 0.0]))
    env = NavEnv(episode_length=8, plan=True, plan_cells=CELLS)
    others = jnp.array([[0.0, 0.0, D_C]], jnp.float32)  # 1 m ahead
    obs = {}
    for kr in (0.0, 0.3):
        params = make_params(fleet, plan_lookahead=1.0, plan_keep_right=kr)
        _, st = env.reset(jax.random.key(0), params)
        obs[kr] = np.asarray(env.observe(jax.random.key(1), st, jnp.full(24, 3.5), params, others=others))
    alone = np.asarray(env.observe(jax.random.key(1), st, jnp.full(24, 3.5), params))
    assert np.array_equal(obs[0.0], alone)  # off: as without others
    bearing = obs[0.3][25]  # the waypoint's bearing: to the right of the heading (negative)
    assert bearing < -0.2 and np.isclose(obs[0.3][24], np.hypot(1.0, 0.3), atol=0.1)
