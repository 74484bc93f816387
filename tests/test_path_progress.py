"""env.path_progress (docs/clutter.md, "Paid along the path"): the progress reward measured along
the shortest safe path on the room's map, the observation unchanged. Checked against float64
geometry: the straight line in an open room, the taut string round a wall's end."""

from __future__ import annotations

import io
from contextlib import redirect_stderr, redirect_stdout

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest
from test_rooms_training import TINY as ROOMS_TINY

from fedjax_nav import cli
from fedjax_nav.config import load_config
from fedjax_nav.config.envs import env_settings
from fedjax_nav.env import nav, plan
from fedjax_nav.env.params import make_params
from fedjax_nav.worlds.world import from_dict

CELLS = 64
D_C, D_G = 0.25, 0.5
GOAL = (2.0, -2.0)
WALL_END = (0.0, 1.5)  # the wall x = 0 runs from the bottom wall up to here; the way round is above it


def _room(wall: bool):
    spec = {"size": [6.0, 6.0], "starts": [[-2.0, -2.0, 0.0]], "goals": [list(GOAL)]}
    if wall:
        spec["segments"] = [[0.0, -3.0, *WALL_END]]
    return from_dict(spec)[0]


def _geodesic_f64(xy, wall: bool) -> float:
    """m from `xy` to the goal's disk in the 6 x 6 room, float64: the straight line, or with the
    wall the taut string from `xy` over the disk of radius D_c about the wall's end (the inflated
    wall's top) to the goal, where the straight line does not clear it."""
    p, g, e = (np.asarray(v, np.float64) for v in (xy, GOAL, WALL_END))
    straight = float(np.linalg.norm(g - p))
    if not wall or (p[0] > 0) == (g[0] > 0):
        return straight - D_G
    a, b = np.linalg.norm(p - e), np.linalg.norm(g - e)
    below = np.arccos(np.dot(p - e, g - e) / a / b)  # the angle at the wall's end on the wall's side
    theta = 2 * np.pi - below - np.arccos(D_C / a) - np.arccos(D_C / b)  # the arc the string wraps
    if theta <= 0:  # the straight line passes over the wall's end
        return straight - D_G
    return float(np.sqrt(a**2 - D_C**2) + np.sqrt(b**2 - D_C**2) + D_C * theta) - D_G


@pytest.fixture(scope="module")
def distances():
    """jit(wall -> path_distance over points) for the 6 x 6 room with and without the wall."""
    out = {}
    for wall in (False, True):
        w = _room(wall)
        field = plan.goal_field(w, w.goals[0], D_C, D_G, CELLS)[0]
        out[wall] = (w, field, jax.jit(jax.vmap(lambda xy, f=field, s=w.size: plan.path_distance(f, s, xy))))
    return out


def _points(world, n: int, seed: int) -> np.ndarray:
    """`n` points of the room that keep 0.3 m from every wall (a robot there is not in collision)."""
    from fedjax_nav.worlds import point_segment_distance_np

    rng = np.random.default_rng(seed)
    pts = rng.uniform(-2.7, 2.7, size=(4 * n, 2))
    segs = np.asarray(world.segments, np.float64)
    d = point_segment_distance_np(pts, segs).min(axis=-1)
    return pts[d > 0.3][:n]


# The 8-connected grid's lengths: at most 8.3 % over the straight line's (a move at 22.5 deg), and
# a cell or two either way where the path leaves the robot's cell and enters the goal's.
OVER, CELLS_OFF = 1.083, 2


@pytest.mark.parametrize("wall", [False, True])
def test_the_path_distance_is_the_float64_geodesic(distances, wall):
    world, _, dist = distances[wall]
    pts = _points(world, 300, seed=int(wall))
    got = np.asarray(dist(jnp.asarray(pts, jnp.float32)), np.float64)
    ref = np.maximum([_geodesic_f64(p, wall) for p in pts], 0.0)  # 0 inside the goal's disk
    slack = CELLS_OFF * 6.0 / CELLS
    assert np.isfinite(got).all()
    assert np.all(got >= ref - slack), (pts[np.argmin(got - ref)], (got - ref).min())
    assert np.all(got <= OVER * ref + slack), (pts[np.argmax(got - OVER * ref)], (got - OVER * ref).max())
    if wall:  # the wall's detour is in it: low left of the wall the path is much longer than the line
        left = (pts[:, 0] < -0.5) & (pts[:, 1] < 0.0)
        line = np.linalg.norm(pts[left] - np.asarray(GOAL), axis=1) - D_G
        assert np.all(got[left] > line + 0.5)


def test_a_step_round_the_wall_is_paid_though_it_moves_away_from_the_goal(distances):
    world, field, _ = distances[True]
    before, after = jnp.array([-0.6, 0.0]), jnp.array([-0.6, 0.025])  # up the wall, towards its end
    straight = jnp.linalg.norm(jnp.asarray(GOAL) - before) - jnp.linalg.norm(jnp.asarray(GOAL) - after)
    assert straight < 0  # the straight line's progress punishes it
    got = float(plan.path_progress(field, world.size, before, after, straight))
    assert 0.02 < got < 0.03  # the path's pays about its 2.5 cm


def test_a_goal_cut_off_on_the_grid_is_paid_as_the_straight_line():
    walled = from_dict(
        {
            "size": [6.0, 6.0],
            "starts": [[-2.0, -2.0, 0.0]],
            "goals": [[2.0, 2.0]],
            "boxes": [[2.0, 0.9, 1.6, 0.2, 0.0], [2.0, 3.1, 1.6, 0.2, 0.0], [0.9, 2.0, 0.2, 1.6, 0.0]],
        }
    )[0]
    field = plan.goal_field(walled, walled.goals[0], D_C, D_G, CELLS)[0]
    before, after, straight = jnp.array([-2.0, -2.0]), jnp.array([-1.98, -1.98]), jnp.float32(0.0283)
    assert not np.isfinite(float(plan.path_distance(field, walled.size, before)))
    assert float(plan.path_progress(field, walled.size, before, after, straight)) == float(straight)


def test_the_env_pays_along_the_path_and_observes_as_without():
    """The same drive with and without env.path_progress: the observations, poses and ends bit for
    bit equal; the rewards differ by the progress term only, each step's the path's."""
    world = _room(True)
    params = make_params(world)
    on = nav.NavEnv(episode_length=96, path_progress=True, plan_cells=CELLS)
    off = nav.NavEnv(episode_length=96)
    assert on.obs_size == off.obs_size  # mapless: the observation is the goal's

    def drive(env):
        obs, st = env.reset(jax.random.key(0), params)
        act = jnp.array([1.0, 0.0])

        def one(st, k):
            obs, st2, r, term, trunc, info = env.step(k, st, act, params)
            return st2, (obs, st2.pose, r, term, info["pose"], st.pose)

        return obs, st, jax.lax.scan(one, st, jax.random.split(jax.random.key(1), 96))[1]

    obs_on, st_on, (o_on, p_on, r_on, t_on, reached, before) = jax.jit(lambda: drive(on))()
    obs_off, _, (o_off, p_off, r_off, t_off, _, _) = jax.jit(lambda: drive(off))()
    assert np.array_equal(obs_on, obs_off) and np.array_equal(o_on, o_off)
    assert np.array_equal(p_on, p_off) and np.array_equal(t_on, t_off)
    assert t_on.any()  # it drove into the wall and was put back at the start: a respawn inside the episode
    field = st_on.plan.field
    want = jax.vmap(lambda a, b: plan.path_distance(field, world.size, a) - plan.path_distance(field, world.size, b))(
        before[:, :2], reached[:, :2]
    )
    crash = np.asarray(t_on)
    paid = np.asarray(r_on) - np.where(crash, float(params.reward_collision), 0.0)
    assert np.allclose(paid, float(params.progress_scale) * np.asarray(want), atol=1e-4)
    assert not np.allclose(r_on, r_off)


def test_the_config_turns_it_on_and_off():
    assert "path_progress" not in env_settings(load_config("thesis/flddpg"), "learn")
    on = load_config("thesis/flddpg", ["env.path_progress=true", "env.plan_cells=32"])
    s = env_settings(on, "learn")
    assert s["path_progress"] is True and s["plan_cells"] == 32 and "plan" not in s
    assert "path_progress" not in env_settings(on, "eval")  # an evaluation reads no reward: no field computed


def test_a_tiny_run_paid_along_the_path_trains(tmp_path):
    out = tmp_path / "run"
    sets = [a for s in [*ROOMS_TINY, "env.path_progress=true", f"env.plan_cells={CELLS // 2}"] for a in ("--set", s)]
    err = io.StringIO()
    with redirect_stderr(err), redirect_stdout(io.StringIO()):
        rc = cli.main(["train", "--config", "thesis/flddpg", *sets, "--out", str(out), "--quiet"])
    assert rc == 0, err.getvalue()[-2000:]
    metrics = pd.read_csv(out / "metrics.csv")
    assert len(metrics) == 2 * 2 and np.isfinite(metrics.select_dtypes("number").to_numpy()).all()
