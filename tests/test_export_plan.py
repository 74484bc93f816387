"""Exporting a run trained with the global plan (docs/export.md, "Exporting a plan run"): the
exported policy takes the observation the env builds in plan mode (the waypoint's distance and
bearing, the goal's distance last, in the order of env/plan.py's `layout`, carried by meta.json) and
acts as the trained actor on it; NaN readings stop it as the mapless export does; the waypoint of a
planner's path (`path_waypoint`); and the ROS 2 nodes, run against stand-ins for rclpy and the
message classes: the plan node waits (zero command, logged once) until a path to the goal comes,
then commands the policy's action; the mapless node is byte for byte the one before the plan.
"""

import hashlib
import json
import sys
import types
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_export import HIDDEN, MAX_RANGE, NUM_BEAMS, TOL, _load_template, random_actor_params, write_actor_params

from fedjax_nav import worlds
from fedjax_nav.config import from_dict, save_config
from fedjax_nav.deploy import export as ex
from fedjax_nav.env import NavEnv, make_params
from fedjax_nav.env import plan as gp
from fedjax_nav.evaluation import actor_policy, load_run

DEPTH, LOOKAHEAD, N = 2, 0.8, 2048
OBS = NUM_BEAMS + 5
ROS2 = Path(__file__).resolve().parents[1] / "examples" / "ros2"
# sha256 of examples/ros2/fedjax_nav_policy_node.py before the plan's export: a mapless deployment
# runs exactly the node it ran (the plan's node is another file that imports it)
MAPLESS_NODE_SHA256 = "429f8a0aa66cc88f01e04de59b9b7611e56c35d24fc5b5bd12e8476a414e54cd"


def write_run(root, plan: bool):
    """An IDDPG run directory (one seed, 2 networks), written directly; trained with env.plan: `plan`."""
    root.mkdir()
    env = {"worlds": ["train-0", "train-2"], "num_beams": NUM_BEAMS, "max_range": MAX_RANGE, "plan": plan}
    cfg = from_dict(
        {
            "method": "iddpg",
            "env": {**env, "plan_cells": 16, "plan_lookahead": LOOKAHEAD},
            "offpolicy": {"hidden": HIDDEN, "depth": DEPTH, "activation": "tanh"},
            "run": {"seeds": 1, "seed": 0},
        }
    )
    save_config(cfg, root / "config.yaml")
    size = OBS if plan else OBS - 1
    per = [random_actor_params(k, HIDDEN, DEPTH, "tanh", size) for k in jax.random.split(jax.random.key(7), 2)]
    write_actor_params(root, per, 1)
    return root


@pytest.fixture(scope="module")
def plan_run(tmp_path_factory):
    return write_run(tmp_path_factory.mktemp("planrun") / "iddpg-plan", plan=True)


@pytest.fixture(scope="module")
def env_obs():
    """Random (ranges, pose, goal, waypoint, previous action) and the observation NavEnv(plan=True)
    builds from them (the waypoint given as the plan's, `at`)."""
    rng = np.random.default_rng(3)
    pose = np.column_stack([rng.uniform(-6, 6, (N, 2)), rng.uniform(-np.pi, np.pi, N)]).astype(np.float32)
    goal, way = (rng.uniform(-6, 6, (N, 2)).astype(np.float32) for _ in range(2))
    prev = np.column_stack([rng.uniform(0, 1, N), rng.uniform(-1, 1, N)]).astype(np.float32)
    ranges = rng.uniform(0, MAX_RANGE, (N, NUM_BEAMS)).astype(np.float32)
    env = NavEnv(NUM_BEAMS, MAX_RANGE, plan=True, plan_cells=16)
    params = make_params(worlds.load("train-0"))
    _, base = jax.jit(env.reset)(jax.random.key(0), params)

    def observe(pose, goal, way, prev, ranges):
        state = base.replace(pose=pose, prev_action=prev, goal=goal, dist=jnp.linalg.norm(goal - pose[:2]))
        return env.observe(jax.random.key(0), state, ranges, params, at=way)

    obs = np.asarray(jax.jit(jax.vmap(observe))(pose, goal, way, prev, ranges))
    return (ranges, pose, goal, way, prev), obs


def _close(a, b):
    """max |a - b| over the observation, the bearing's difference wrapped (+-pi alike)."""
    d = np.asarray(a, np.float64) - np.asarray(b, np.float64)
    d[..., NUM_BEAMS + 1] = np.arctan2(np.sin(d[..., NUM_BEAMS + 1]), np.cos(d[..., NUM_BEAMS + 1]))
    return float(np.abs(d).max())


def test_the_export_of_a_plan_run_acts_as_the_trained_actor_on_the_envs_observation(plan_run, env_obs, tmp_path):
    (ranges, pose, goal, way, prev), obs = env_obs
    out = tmp_path / "np"
    ex.export_run(plan_run, out, "numpy", agent=1)
    meta = json.loads((out / "meta.json").read_text())
    assert meta["observation_layout"] == list(gp.layout(True)) and meta["network"]["obs_size"] == OBS
    assert meta["plan"]["lookahead"] == LOOKAHEAD and len(meta["observation"]) == 1 + len(gp.PLANNED)
    policy = _load_template(out / "policy.py").Policy(str(out))
    built = policy.observation(ranges, pose, goal, prev, waypoint=way)
    assert built.shape == obs.shape == (N, OBS) and _close(built, obs) <= TOL
    run = load_run(plan_run)
    actor = jax.jit(jax.vmap(actor_policy(HIDDEN, DEPTH, "tanh"), (None, 0)))
    ref = np.asarray(actor(jax.tree.map(lambda a: a[1], run.actor_params), jnp.asarray(obs)))
    got = policy(built)
    diff = float(np.abs(got - ref).max())
    print(f"\nplan export (numpy) vs the JAX actor on NavEnv(plan=True)'s observation: max |diff| = {diff:.3g}")
    assert diff <= TOL and not policy.last_unsafe.any()
    pytest.importorskip("onnxruntime")
    import onnxruntime as ort

    ex.export_run(plan_run, tmp_path / "onnx", "onnx", agent=1)
    sess = ort.InferenceSession(str(tmp_path / "onnx" / "policy.onnx"))
    onnx_diff = float(np.abs(sess.run(["action"], {"obs": built})[0] - ref).max())
    print(f"plan export (ONNX) vs the JAX actor: max |diff| = {onnx_diff:.3g}")
    assert onnx_diff <= TOL


def test_nan_readings_stop_a_plan_policy_as_the_mapless_one(plan_run, env_obs, tmp_path):
    """A NaN in any entry (a beam, the waypoint, the goal's distance last) or in the planner's path
    is the stop command, flagged; the other rows of a batch act as the bare network."""
    (ranges, pose, goal, way, prev), _ = env_obs
    ex.export_run(plan_run, tmp_path, "numpy")
    mod = _load_template(tmp_path / "policy.py")
    policy = mod.Policy(str(tmp_path))
    obs = policy.observation(ranges[:8], pose[:8], goal[:8], prev[:8], waypoint=way[:8])
    bad = obs.copy()
    bad[1, 3], bad[2, NUM_BEAMS], bad[3, NUM_BEAMS + 1], bad[4, OBS - 1] = np.nan, np.nan, np.inf, np.nan
    action = policy(bad)
    assert np.array_equal(policy.last_unsafe, [False, True, True, True, True, False, False, False])
    assert np.all(action[1:5] == mod.STOP)
    bare = mod.actor_forward(policy.weights, obs, "tanh")
    assert np.array_equal(action[[0, 5, 6, 7]], bare[[0, 5, 6, 7]])
    policy.follow([[0.0, 0.0], [np.nan, 1.0], [2.0, 2.0]])
    one = policy.observation(ranges[0], pose[0], goal[0], prev[0])
    assert np.all(policy(one) == mod.STOP) and policy.last_unsafe is True
    with pytest.raises(ValueError, match="has 29 entries .*waypoint distance, waypoint bearing.*got 28"):
        policy(one[:-1])


def test_a_plan_policy_without_a_waypoint_is_one_line_and_a_mapless_one_takes_no_path(plan_run, tmp_path):
    ex.export_run(plan_run, tmp_path / "plan", "numpy")
    policy = _load_template(tmp_path / "plan" / "policy.py").Policy(str(tmp_path / "plan"))
    with pytest.raises(ValueError, match="waypoint_distance, waypoint_bearing: the policy was trained with the plan"):
        policy.observation(np.zeros(NUM_BEAMS), (0, 0, 0), (1, 1))
    mapless = _load_template(ex.TEMPLATE)
    assert mapless.MAPLESS_LAYOUT == gp.layout(False)  # an export before meta.json carried the layout
    meta = {**policy.meta, "network": {**policy.meta["network"], "obs_size": NUM_BEAMS + 4}}
    del meta["plan"], meta["observation_layout"]
    w = {**policy.weights, "hidden_0/kernel": policy.weights["hidden_0/kernel"][: NUM_BEAMS + 4]}
    old = mapless.Policy(str(tmp_path / "plan"), weights=w, meta=meta)
    assert old.obs_size == NUM_BEAMS + 4 and old.observation(np.zeros(NUM_BEAMS), (0, 0, 0), (1, 1)).shape == (28,)
    with pytest.raises(ValueError, match="a mapless policy"):
        old.follow([[0.0, 0.0]])


def test_the_waypoint_of_a_path_is_the_first_pose_lookahead_along_it_else_its_end():
    wp = _load_template(ex.TEMPLATE).path_waypoint
    line = np.column_stack([np.arange(0.0, 3.01, 0.1), np.zeros(31)])  # 3 m along x, poses 0.1 m apart
    np.testing.assert_allclose(wp(line, (0.0, 0.0, 0.0), 0.95), [1.0, 0.0], atol=1e-6)
    np.testing.assert_allclose(wp(line, (0.52, 0.3), 0.95), [1.5, 0.0], atol=1e-6)  # from the nearest pose
    np.testing.assert_allclose(wp(line, (1.8, 0.0), 0.95), [2.8, 0.0], atol=1e-6)
    np.testing.assert_allclose(wp(line, (1.8, 0.0), 1.5), [3.0, 0.0])  # less than 1.5 m left: the end
    corner = np.array([[0.0, 0.0], [0.4, 0.0], [0.4, 0.4], [0.4, 0.8]])  # along the path, not straight
    np.testing.assert_allclose(wp(corner, (0.0, 0.0), 0.75), [0.4, 0.4])
    fold = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [2.0, 1.0], [0.1, 1.0], [0.1, 3.0]])
    np.testing.assert_allclose(wp(fold, (0.1, 0.6), 1.0), [1.0, 0.0])  # the fold's far side is not the start
    np.testing.assert_allclose(wp(fold, (0.1, 0.6), 1.0, search=10.0), [0.1, 3.0])  # ... unless searched
    assert wp(np.zeros((0, 2)), (0.0, 0.0), 1.0) is None
    assert np.all(np.isnan(wp([[0.0, 0.0], [np.inf, 0.0]], (0.0, 0.0), 1.0)))


# ----------------------------------------------------------------------------- the ROS 2 nodes


def _descent(field: np.ndarray, iy: int, ix: int, res) -> list[tuple[int, int]]:
    """The cells of the shortest path from (iy, ix) down `field` to a goal cell, stepped as the
    simulator's walk steps (least value + edge, float32, the first of ties): what a grid planner
    publishes for this map, cell centre by cell centre."""
    f, res = field.astype(np.float32), np.float32(res)
    out = [(iy, ix)]
    while f[iy, ix] > 0:
        ny, nx = iy + np.array(gp._DY), ix + np.array(gp._DX)
        on = (ny >= 0) & (ny < f.shape[0]) & (nx >= 0) & (nx < f.shape[1])
        vals = np.where(on, f[np.clip(ny, 0, f.shape[0] - 1), np.clip(nx, 0, f.shape[1] - 1)], np.inf)
        j = int(np.argmin(vals.astype(np.float32) + np.array(gp._STEP, np.float32) * res))
        iy, ix = int(ny[j]), int(nx[j])
        out.append((iy, ix))
    return out


@pytest.mark.parametrize("name, key", [("maze", 3), ("office", 5)])
def test_the_deployed_waypoint_is_the_simulators_or_further_down_the_same_path(name, key):
    """path_waypoint on a grid planner's path against env/plan.py's walk on the same map: the
    simulator's waypoint is always a pose of that path at or before the deployed one; they differ
    only where the walk stops early because the way leaves the robot's sight, a rule the robot's
    node cannot apply without the map (docs/export.md, "Exporting a plan run")."""
    from fedjax_nav.worlds.procedural import generate
    from fedjax_nav.worlds.rooms import make_spec

    cells, look = 48, 1.0
    world = generate(jax.random.key(key), make_spec(name))
    goal = world.goals[0]
    free = gp.free_cells(world, 0.25, cells)
    res = gp.grid(world.size, cells)[0]
    field = np.asarray(gp.distance_field(free, gp.goal_cells(free, world.size, goal, 0.5), res)[0])
    _, xs, ys = (np.asarray(a) for a in gp.grid(world.size, cells))
    iy, ix = np.nonzero(np.isfinite(field) & (field > look + 2 * float(res)))
    pick = np.random.default_rng(0).choice(len(iy), 64, replace=False)
    xy = np.stack([xs[ix[pick]], ys[iy[pick]]], axis=1)  # robots at cell centres
    walk = jax.vmap(gp.waypoint, in_axes=(None, None, None, 0, None))
    sim = np.asarray(walk(jnp.asarray(field), world.size, goal, jnp.asarray(xy, jnp.float32), look))
    equal = []
    for k, p in enumerate(pick):
        path = np.array([(xs[c], ys[r]) for r, c in _descent(field, iy[p], ix[p], res)] + [tuple(np.asarray(goal))])
        deployed = _load_template(ex.TEMPLATE).path_waypoint(path, xy[k], look)
        i_sim = np.flatnonzero(np.hypot(*(path - sim[k]).T) < 1e-5)
        i_dep = np.flatnonzero(np.hypot(*(path - deployed).T) < 1e-5)
        assert i_sim.size and i_dep.size and i_sim[0] <= i_dep[0], (k, sim[k], deployed)
        equal.append(i_sim[0] == i_dep[0])
    assert np.mean(equal) >= 0.6, np.mean(equal)  # measured: 0.72 (maze), 0.88 (office)


def test_the_mapless_node_is_the_one_before_the_plan():
    assert hashlib.sha256((ROS2 / "fedjax_nav_policy_node.py").read_bytes()).hexdigest() == MAPLESS_NODE_SHA256


def _msg(**fields):
    return types.SimpleNamespace(**fields)


def _point(x=0.0, y=0.0, z=0.0, w=1.0):
    return _msg(x=x, y=y, z=z, w=w)


class _Node:
    """rclpy.node.Node as the nodes use it: parameters from `_Node.params`, subscriptions and
    publications recorded, a clock the test sets (`_Node.t`), logs kept (`_Node.logs`)."""

    params, t, logs = {}, 0.0, []

    def __init__(self, name):
        self.subs, self.published = {}, []

    def declare_parameter(self, name, default):
        return _msg(value=self.params.get(name, default))

    def create_subscription(self, kind, topic, callback, qos):
        self.subs[topic] = callback

    def create_publisher(self, kind, topic, qos):
        return _msg(publish=self.published.append)

    def create_timer(self, period, callback):
        return None

    def get_logger(self):
        def log(level):
            return lambda text, **kw: _Node.logs.append((level, text))

        return _msg(info=log("info"), warn=log("warn"))

    def get_clock(self):
        return _msg(now=lambda: _msg(nanoseconds=int(_Node.t * 1e9), to_msg=lambda: None))


def _twist():
    return _msg(linear=_point(), angular=_point())


@pytest.fixture
def fake_ros(monkeypatch):
    """rclpy and the message packages as stand-ins, and examples/ros2 importable."""
    mods = {
        "rclpy": _msg(init=lambda **k: None, ok=lambda: False, shutdown=lambda: None),
        "rclpy.node": _msg(Node=_Node),
        "rclpy.qos": _msg(qos_profile_sensor_data=None),
        "geometry_msgs.msg": _msg(PoseStamped=object, Twist=_twist, TwistStamped=_twist),
        "nav_msgs.msg": _msg(Odometry=object, Path=object),
        "sensor_msgs.msg": _msg(LaserScan=object),
    }
    mods |= {name.split(".")[0]: _msg(msg=mods[name]) for name in list(mods) if name.endswith(".msg")}
    for name, mod in mods.items():
        monkeypatch.setitem(sys.modules, name, mod)
    for name in ("fedjax_nav_policy_node", "fedjax_nav_plan_node"):
        monkeypatch.delitem(sys.modules, name, raising=False)
    monkeypatch.syspath_prepend(str(ROS2))
    _Node.logs.clear()
    import fedjax_nav_plan_node

    return fedjax_nav_plan_node


def _drive(node, goal, path=None):
    """A scan, an odometry pose and a goal in; a timer tick; the command published."""
    node.subs["/scan"](_msg(ranges=[2.0] * 360, angle_min=0.0, angle_increment=np.pi / 180, range_min=0.1, range_max=8))
    pose = _msg(position=_point(0.5, -0.2), orientation=_point(0.0, 0.0, np.sin(0.15), np.cos(0.15)))
    node.subs["/odom"](_msg(pose=_msg(pose=pose), header=_msg(frame_id="odom")))
    if goal is not None:
        node.subs["/goal_pose"](_msg(pose=_msg(position=_point(*goal)), header=_msg(frame_id="odom")))
    if path is not None:
        poses = [_msg(pose=_msg(position=_point(x, y))) for x, y in path]
        node.subs["/plan"](_msg(poses=poses, header=_msg(frame_id="map")))
    node.on_timer()
    cmd = node.published[-1]
    return cmd.linear.x, cmd.angular.z


def test_the_plan_node_waits_for_a_path_to_the_goal_then_drives_by_its_waypoint(fake_ros, plan_run, tmp_path):
    ex.export_run(plan_run, tmp_path, "numpy")
    _Node.params = {"policy_dir": str(tmp_path), "max_linear": 10.0, "max_angular": 10.0}
    node = fake_ros.PlanNode()
    goal, path = (3.0, 1.0), [(0.5, -0.2), (1.0, 0.0), (1.5, 0.3), (2.0, 0.6), (2.5, 0.8), (3.0, 1.0)]
    for _ in range(3):  # no path yet: a zero command, logged once
        assert _drive(node, goal) == (0.0, 0.0)
    assert sum("no path to the goal yet" in text for _, text in _Node.logs) == 1
    assert _drive(node, (-3.0, 0.0), path) == (0.0, 0.0)  # a path that ends elsewhere: to another goal
    cmd = _drive(node, goal, path)
    policy = node.mod.Policy(str(tmp_path))
    ranges = policy.scan_ranges([2.0] * 360, 0.0, np.pi / 180, 0.1, 8)
    obs = policy.observation(ranges, node.pose, goal, (0, 0), waypoint=(1.5, 0.3))  # the first pose 0.8 m on
    assert cmd == pytest.approx(policy.velocity(policy(obs)), abs=1e-6) and cmd != (0.0, 0.0)
    assert sum("frame 'map'" in text for _, text in _Node.logs) == 1  # the frame warning, once


def test_the_plan_node_refuses_a_mapless_export(fake_ros, tmp_path):
    ex.export_run(write_run(tmp_path / "run", plan=False), tmp_path / "out", "numpy")
    _Node.params = {"policy_dir": str(tmp_path / "out")}
    with pytest.raises(SystemExit, match="a mapless export"):
        fake_ros.PlanNode()
