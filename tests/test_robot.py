"""The robot model (docs/robot.md): each fidelity feature against a closed form or a hand-computed
case, the pooling against the exported policy's `pool_scan`, the ideal model's program unchanged,
presets and config errors, and a sweep over a traced robot field compiled once."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from fedjax_nav import worlds
from fedjax_nav.config import ConfigError, from_dict, load_config, traced_fields
from fedjax_nav.deploy.policy_template import pool_scan
from fedjax_nav.env import NavEnv, make_params
from fedjax_nav.env import robot as rm
from fedjax_nav.env.geometry import lidar
from fedjax_nav.robots import IDEAL, TURTLEBOT3_BURGER, RobotConfig

# A 10 x 10 m room, the robot at the centre facing +x (walls 5 m away: beyond the 3.5 m range).
OPEN, _ = worlds.from_dict({"size": [10, 10], "starts": [[0, 0, 0]], "goals": [[4.5, 4.5]]})
# The same with a wall across x = 1 (from y = -5 to 5).
WALL, _ = worlds.from_dict(
    {"size": [10, 10], "segments": [[1, -5, 1, 5]], "starts": [[0, 0, 0]], "goals": [[-4.5, 4.5]]}
)


def drive(env, params, actions, key=0):
    """Reset, then step through `actions` [T, 2]; the states after each step."""
    _, s = env.reset(jax.random.key(key), params)
    out = []
    for a in actions:
        _, s, *_ = env.step(jax.random.key(key), s, jnp.asarray(a, jnp.float32), params)
        out.append(s)
    return out


# ----------------------------------------------------------------------------- dynamics


@pytest.mark.parametrize("substeps", [1, 4])
def test_an_acceleration_limited_start_reaches_v_max_at_the_right_step(substeps):
    """From rest at full command: v_k = min(a k dt, v_max); with a = 0.5 m/s^2, dt = 0.1 s,
    v_max = 0.25 m/s that is 0.05 k, v_max first reached at step 5. The distance is the sum of
    the physics steps' v h (h = dt / substeps): 0.075 m after 5 steps with substeps = 1."""
    env = NavEnv(robot=True, substeps=substeps)
    p = make_params(OPEN, accel_lin=0.5, accel_ang=2.0)
    states = drive(env, p, [[1.0, 1.0]] * 7)
    v = np.array([float(s.vel[0]) for s in states])
    w = np.array([float(s.vel[1]) for s in states])
    np.testing.assert_allclose(v, [0.05, 0.1, 0.15, 0.2, 0.25, 0.25, 0.25], atol=1e-6)
    assert v[3] < 0.25 - 1e-3 and abs(v[4] - 0.25) < 1e-6  # reached at step 5, not before
    np.testing.assert_allclose(w, [0.2, 0.4, 0.6, 0.8, 1.0, 1.0, 1.0], atol=1e-6)  # omega_max 1 at step 5
    # braking: a zero command decelerates at the same rate
    v_brake = [float(s.vel[0]) for s in drive(env, p, [[1.0, 0.0]] * 5 + [[0.0, 0.0]] * 2)[5:]]
    np.testing.assert_allclose(v_brake, [0.2, 0.15], atol=1e-6)
    if substeps == 1:  # straight line (omega command 0): x = dt * sum(v_k)
        s = drive(env, p, [[1.0, 0.0]] * 5)[-1]
        np.testing.assert_allclose(float(s.pose[0]), 0.1 * (0.05 + 0.1 + 0.15 + 0.2 + 0.25), atol=1e-6)
    else:  # h = 0.025: v rises by 0.0125 per physics step: x = h * 0.0125 * (1 + ... + 20)
        s = drive(env, p, [[1.0, 0.0]] * 5)[-1]
        np.testing.assert_allclose(float(s.pose[0]), 0.025 * 0.0125 * 210, atol=1e-6)


def test_unlimited_acceleration_and_no_delay_move_like_the_ideal_robot():
    """With every feature at 0 the model reduces to the ideal robot (pose, reward, observation)."""
    w = worlds.load("train-3")
    p = make_params(w)
    acts = np.random.default_rng(0).uniform([0, -1], [1, 1], (40, 2)).astype(np.float32)
    ideal, model = NavEnv(), NavEnv(robot=True)
    for env_a, env_b in [(ideal, model)]:
        oa, sa = env_a.reset(jax.random.key(1), p)
        ob, sb = env_b.reset(jax.random.key(1), p)
        np.testing.assert_array_equal(oa, ob)
        for a in acts:
            oa, sa, ra, *_ = env_a.step(jax.random.key(2), sa, jnp.asarray(a), p)
            ob, sb, rb, *_ = env_b.step(jax.random.key(2), sb, jnp.asarray(a), p)
            np.testing.assert_allclose(sa.pose, sb.pose, atol=1e-6)
            np.testing.assert_allclose(oa, ob, atol=1e-5)
            np.testing.assert_allclose(ra, rb, atol=1e-5)


def test_a_delayed_command_acts_k_steps_later():
    """delay_steps = k: the velocity executed at step t is the command of step t - k (zeros
    before the first), with unlimited acceleration; the observation keeps the command itself."""
    env = NavEnv(robot=True, max_delay=3)
    cmds = np.array([[0.2, 0.1], [0.4, -0.3], [0.6, 0.5], [0.8, -0.7], [1.0, 0.9], [0.1, 0.0]], np.float32)
    for k in range(4):
        p = make_params(OPEN, delay_steps=k)
        states = drive(env, p, cmds)
        vel = np.array([np.asarray(s.vel) for s in states])
        want = np.concatenate([np.zeros((k, 2)), cmds[: len(cmds) - k]]) * [0.25, 1.0]
        np.testing.assert_allclose(vel, want, atol=1e-7)
        np.testing.assert_array_equal(np.asarray(states[-1].prev_action), cmds[-1])
    # no ring (max_delay 0): no delay, whatever delay_steps says
    np.testing.assert_allclose(
        drive(NavEnv(robot=True), make_params(OPEN, delay_steps=2), cmds[:1])[0].vel, cmds[0] * [0.25, 1.0], atol=1e-7
    )


def test_the_ring_starts_empty_after_a_reset_in_learn_mode():
    """A terminal step (here a goal) restarts at a start: the queue and the velocity are zeros."""
    w, _ = worlds.from_dict({"size": [10, 10], "starts": [[0, 0, 0]], "goals": [[0.6, 0]]})
    env = NavEnv(robot=True, max_delay=2)
    p = make_params(w, delay_steps=1, goal_radius=0.5)
    _, s = env.reset(jax.random.key(0), p)
    _, s, _, term, *_ = env.step(jax.random.key(0), s, jnp.array([1.0, 0.0]), p)
    assert not bool(term) and float(s.vel[0]) == 0.0  # the first command is still in the ring
    _, s, _, term, *_ = env.step(jax.random.key(0), s, jnp.array([1.0, 0.0]), p)
    assert not bool(term)
    for _ in range(20):
        _, s, _, term, *_ = env.step(jax.random.key(0), s, jnp.array([1.0, 0.0]), p)
        if bool(term):
            break
    assert bool(term) and not np.asarray(s.cmd_queue).any() and not np.asarray(s.vel).any()


# ----------------------------------------------------------------------------- the lidar


def test_pooled_dense_scan_equals_the_min_over_sectors_and_the_exported_pool_scan():
    rng = np.random.default_rng(0)
    for samples, beams in [(360, 24), (24, 24), (100, 24), (500, 7)]:
        vals = rng.uniform(0.05, 3.5, samples).astype(np.float32)
        vals[rng.uniform(size=samples) < 0.2] = 0.0  # invalid samples (LDS zeros)
        vals[rng.uniform(size=samples) < 0.1] = 3.5  # no return
        invalid = vals <= 0.0
        got = np.asarray(rm.pool_min(jnp.asarray(vals), jnp.asarray(invalid), beams, 3.5))
        # pool_scan reads a LaserScan (no return = inf, invalid = 0) from angle 0 in steps 2 pi / S
        scan = np.where(vals >= 3.5, np.inf, vals)
        want = pool_scan(scan, 0.0, 2 * math.pi / samples, beams, 3.5, range_min=0.0, range_max=3.5)
        np.testing.assert_array_equal(got, want)
        # and by hand: the min over each sector [2 pi i / n - pi / n, 2 pi i / n + pi / n)
        ang = np.arange(samples) * 2 * np.pi / samples
        for i in range(beams):
            d = np.mod(ang - 2 * np.pi * i / beams + np.pi / beams, 2 * np.pi)
            sel = (d < 2 * np.pi / beams) & ~invalid
            assert got[i] == pytest.approx(vals[sel].min() if sel.any() else 3.5, abs=1e-6)
    # 360 samples, 24 beams: beam 0 is samples 353..359 and 0..7 (15 per sector)
    sec = rm.sectors(360, 24)
    assert list(np.flatnonzero(sec == 0)) == list(range(8)) + list(range(353, 360))


def test_the_env_observation_is_the_sector_minimum_of_a_dense_scan_from_the_lidar():
    w = worlds.load("train-3")
    p = make_params(w, lidar_offset=-0.032)
    env = NavEnv(robot=True, scan_samples=360)
    obs, s = env.reset(jax.random.key(0), p)
    pose = np.asarray(s.pose)
    lp = pose + [-0.032 * math.cos(pose[2]), -0.032 * math.sin(pose[2]), 0.0]
    dense = np.asarray(lidar(w.segments, jnp.asarray(lp, jnp.float32), 360, 3.5, w.circles))
    want = pool_scan(np.where(dense >= 3.5, np.inf, dense), 0.0, 2 * math.pi / 360, 24, 3.5)
    np.testing.assert_allclose(np.asarray(obs[:24]), want, atol=1e-6)
    # a dense scan's sector minimum is never longer than the exact beam at the sector's centre
    exact = np.asarray(lidar(w.segments, jnp.asarray(lp, jnp.float32), 24, 3.5, w.circles))
    assert np.all(np.asarray(obs[:24]) <= exact + 1e-5)


def test_lidar_offset_moves_the_scan_origin():
    """A wall across x = 1: the forward beam reads 1 - offset, the backward one sees nothing."""
    env = NavEnv(robot=True)
    for off in (0.0, -0.032, 0.1):
        obs, _ = env.reset(jax.random.key(0), make_params(WALL, lidar_offset=off))
        assert float(obs[0]) == pytest.approx(1.0 - off, abs=1e-6)
        assert float(obs[12]) == pytest.approx(3.5)


def test_quantization_and_minimum_range_by_hand():
    p = make_params(OPEN, range_resolution=0.015, range_min=0.12)
    raw = jnp.array([1.0, 0.1, 0.13, 0.119, 3.5, 2.0034], jnp.float32)
    r, invalid = rm.measure(jax.random.key(0), raw, p, 3.5, noise=False)
    # 1.0 / 0.015 = 66.67 -> 67 * 0.015 = 1.005; 0.13 -> 9 * 0.015 = 0.135; 0.119 -> 8 * 0.015 = 0.12
    # (not below the minimum once quantized); 0.1 -> 0.105 < 0.12: invalid; 3.5: no return, kept;
    # 2.0034 -> 134 * 0.015 = 2.01
    np.testing.assert_allclose(np.asarray(r), [1.005, 0.105, 0.135, 0.12, 3.5, 2.01], atol=1e-6)
    np.testing.assert_array_equal(np.asarray(invalid), [False, True, False, False, False, False])
    # the invalid sample is left out: on exact beams its beam reads max range (pool_scan's rule)
    pooled = rm.pool_min(r, invalid, 6, 3.5)
    np.testing.assert_allclose(np.asarray(pooled), [1.005, 3.5, 0.135, 0.12, 3.5, 2.01], atol=1e-6)
    # in the env: the forward beam at 1 m reads 1.005; from 0.1 m away the wall is not seen
    env = NavEnv(robot=True)
    obs, _ = env.reset(jax.random.key(0), p.replace(world=WALL))
    assert float(obs[0]) == pytest.approx(1.005, abs=1e-6)
    obs, _ = env.reset(jax.random.key(0), p.replace(world=WALL, lidar_offset=jnp.float32(0.9)))
    assert float(obs[0]) == pytest.approx(3.5)


@pytest.mark.parametrize("value", ["max", "zero"])
def test_dropouts(value):
    p = make_params(OPEN, dropout=1.0)
    raw = jnp.full((360,), 1.0)
    r, invalid = rm.measure(jax.random.key(0), raw, p, 3.5, noise=True, dropout_value=value)
    if value == "max":
        assert np.all(np.asarray(r) == 3.5) and not np.asarray(invalid).any()
    else:
        assert np.asarray(invalid).all()
    assert np.all(np.asarray(rm.pool_min(r, invalid, 24, 3.5)) == 3.5)  # either way: nothing seen
    # a probability: about that fraction drops; without noise nothing is drawn
    r, invalid = rm.measure(
        jax.random.key(1),
        jnp.full((20000,), 1.0),
        p.replace(dropout=jnp.float32(0.3)),
        3.5,
        noise=True,
        dropout_value="zero",
    )
    assert abs(float(jnp.mean(invalid)) - 0.3) < 0.02
    r, invalid = rm.measure(jax.random.key(1), raw, p, 3.5, noise=False, dropout_value=value)
    assert np.all(np.asarray(r) == 1.0) and not np.asarray(invalid).any()


def test_range_noise_has_the_configured_std():
    p = make_params(OPEN, range_noise=0.01)
    r, _ = rm.measure(jax.random.key(0), jnp.full((20000,), 1.0), p, 3.5, noise=True)
    assert abs(float(jnp.std(r)) - 0.01) < 5e-4 and abs(float(jnp.mean(r)) - 1.0) < 5e-4


def test_footprint_replaces_the_collision_distance():
    """0.3 m from a wall, 0.1 m forward: 0.2 m away, a collision at D_c = 0.25 m, none with a
    0.105 m footprint."""
    w, _ = worlds.from_dict(
        {"size": [10, 10], "segments": [[0.3, -5, 0.3, 5]], "starts": [[0, 0, 0]], "goals": [[-4.5, 4.5]]}
    )
    for robot, footprint, hit in [(False, 0.0, True), (True, 0.0, True), (True, 0.105, False), (True, 0.21, True)]:
        env = NavEnv(robot=robot)
        p = make_params(w, footprint=footprint, v_max=1.0)
        _, s = env.reset(jax.random.key(0), p)
        _, _, _, term, _, info = env.step(jax.random.key(0), s, jnp.array([1.0, 0.0]), p)
        assert float(info["clearance"]) == pytest.approx(0.2, abs=1e-6)
        assert bool(info["collision"]) == hit, (robot, footprint)


# ----------------------------------------------------------------------------- config


def test_presets_fill_the_fields_not_given_and_ideal_is_the_default():
    assert RobotConfig() == load_config(None).robot and not RobotConfig().enabled
    assert {k: getattr(RobotConfig(), k) for k in IDEAL} == IDEAL
    tb = from_dict({"robot": {"model": "turtlebot3_burger", "delay_steps": 0, "dropout": 0.0}}).robot
    assert tb.model == "turtlebot3_burger" and tb.delay_steps == 0 and tb.dropout == 0.0
    assert all(getattr(tb, k) == v for k, v in TURTLEBOT3_BURGER.items() if k not in ("delay_steps", "dropout"))
    # a non-ideal value under "ideal" switches the model code on ("custom")
    c = load_config(None, ["robot.accel_lin=0.5"]).robot
    assert c.model == "custom" and c.enabled and c.accel_lin == 0.5 and c.substeps == 1
    # a saved config loads back equal
    assert from_dict({"robot": {**TURTLEBOT3_BURGER, "model": "turtlebot3_burger"}}).robot == RobotConfig(
        model="turtlebot3_burger"
    )
    # pooled_360: the ideal robot but for the 360-sample scan pooled to the beams, nothing else
    pooled = load_config(None, ["robot.model=pooled_360"]).robot
    assert pooled.enabled and {k: getattr(pooled, k) for k in IDEAL} == IDEAL | {"scan_samples": 360}
    assert {f"robot.{k}" for k in ("accel_lin", "delay_steps", "range_noise", "footprint")} <= set(traced_fields())
    assert not {f"robot.{k}" for k in ("substeps", "scan_samples", "max_delay", "dropout_value")} & set(traced_fields())


@pytest.mark.parametrize(
    "robot, needle",
    [
        ({"model": "gazebo"}, "robot.model"),
        ({"dropout": 1.5}, "robot.dropout"),
        ({"accel_lin": -1}, "robot.accel_lin"),
        ({"substeps": 0}, "robot.substeps"),
        ({"dropout_value": "nan"}, "robot.dropout_value"),
        ({"delay_steps": 2, "max_delay": 1}, "robot.delay_steps"),
        ({"scan_samples": 10}, "robot.scan_samples"),
        ({"lidar": 1}, "robot.lidar"),
    ],
)
def test_config_errors_name_the_field(robot, needle):
    with pytest.raises(ConfigError, match=needle.replace(".", r"\.")):
        from_dict({"robot": robot}, "f.yaml")


def test_the_trainer_builds_the_ideal_env_by_default_and_the_model_on_request():
    from fedjax_nav.training.trainer import Trainer

    tr = Trainer(load_config(None))
    assert not tr.env.robot and not tr.env.noise and tr.env.max_delay == 0
    tr = Trainer(load_config(None, ["robot.model=turtlebot3_burger"]))
    assert tr.env.robot and tr.env.noise and (tr.env.substeps, tr.env.max_delay, tr.env.scan_samples) == (3, 2, 360)


def test_the_probe_drives_the_runs_robot_model_without_noise():
    """The periodic held-out probe builds its env from the run's config like the trainer does
    (config.envs): the TurtleBot3 run is probed under the TurtleBot3 model, noiseless; it used
    to probe the ideal robot whatever `robot:` said."""
    from fedjax_nav.training.trainer import Trainer

    tr = Trainer(load_config(None, ["robot.model=turtlebot3_burger", "run.eval_every=5"]))
    p = tr.probe.env
    assert p.robot and not p.noise and p.mode == "eval"
    assert (p.substeps, p.max_delay, p.scan_samples) == (tr.env.substeps, tr.env.max_delay, tr.env.scan_samples)
    ideal = Trainer(load_config(None, ["run.eval_every=5"])).probe.env
    assert not ideal.robot and not ideal.noise


@pytest.mark.slow
def test_a_sweep_over_a_traced_robot_field_compiles_once(tmp_path):
    """robot.* fields marked traced are HParams: one group, one trace, the value reaches the env."""
    import pandas as pd
    import yaml

    from fedjax_nav.config.sweepfile import load_sweep
    from fedjax_nav.experiments.sweeps import run_sweep
    from fedjax_nav.training import sweep as sw

    tiny = [
        "env.episode_length=16",
        "run.chunk_episodes=1",
        "offpolicy.batch_size=8",
        "offpolicy.hidden=16",
        "run.checkpoint_every=0",
        "run.episodes=2",
        "fed.period=1",
        "robot.model=turtlebot3_burger",
        "robot.scan_samples=48",
        "env.worlds=[train-0,train-0,train-0,train-0,train-0]",  # the smallest room: compiles fastest
    ]
    from fedjax_nav.configs import resolve

    spec = {
        "name": "robot",
        "base": str(resolve("thesis/flddpg")),
        "seeds": 1,
        "set": tiny,
        "grid": {"robot.accel_lin": [0.05, 0.0]},
    }
    path = tmp_path / "robot.yaml"
    path.write_text(yaml.safe_dump(spec, sort_keys=False))
    sweep = load_sweep(path)
    assert len(sw.plan(sw.merge_jobs(sweep.points), budget=2**40)) == 1
    _, stats = run_sweep(sweep, tmp_path / "out", progress=False, echo=lambda s: None)
    assert [g["traces"] for g in stats["groups"]] == [1]
    frames = [pd.read_csv(tmp_path / "out" / "points" / p.id / "metrics.csv") for p in sweep.points]
    assert not np.allclose(frames[0]["reward"], frames[1]["reward"])


@pytest.mark.slow
def test_evaluate_a_run_under_another_robot_model(tmp_path):
    """`fedjax-nav evaluate RUN --robot turtlebot3_burger`: the run's agents in the model's
    simulator, kept beside the run's own evaluation."""
    from fedjax_nav import cli
    from fedjax_nav.evaluation.runs import evaluate_run
    from fedjax_nav.training.run import train

    cfg = load_config(
        "thesis/iddpg",
        [
            "env.episode_length=16",
            "run.chunk_episodes=1",
            "offpolicy.batch_size=8",
            "offpolicy.hidden=16",
            "offpolicy.buffer_size=64",
            "run.checkpoint_every=0",
            "run.episodes=1",
            "env.worlds=[train-0]",
        ],
    )
    train(cfg, tmp_path / "run", progress=False)
    # evaluated in the smallest shipped room, not the thesis arena (57 obstacles): the evaluation's
    # lidar and collision tests are unrolled over the obstacles, and each robot model compiles its own
    world = "train-0"
    own = evaluate_run(tmp_path / "run", world, attempts=1, max_steps=8)
    assert own.summary["robot"]["model"] == "ideal" and own.eval_dir.name == world
    tb3 = evaluate_run(tmp_path / "run", world, attempts=1, max_steps=8, robot=RobotConfig(model="turtlebot3_burger"))
    assert tb3.summary["robot"] == {"model": "turtlebot3_burger", **TURTLEBOT3_BURGER}
    assert tb3.summary["noise"]["range_noise"] == 0.01 and tb3.eval_dir.name == f"{world}-robot-turtlebot3_burger"
    assert not np.array_equal(own.result.poses, tb3.result.poses)
    assert (
        cli.main(
            [
                "evaluate",
                str(tmp_path / "run"),
                "--world",
                world,
                "--robot",
                "turtlebot3_burger",
                "--attempts",
                "1",
                "--max-steps",
                "8",
                "--no-figures",
            ]
        )
        == 0
    )
    assert (tmp_path / "run" / "eval" / f"{world}-robot-turtlebot3_burger" / "eval.json").exists()
    assert cli.main(["evaluate", str(tmp_path / "run"), "--robot", "gazebo"]) == 2
