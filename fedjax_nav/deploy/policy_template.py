"""A fedjax_nav navigation policy, exported for a robot: numpy and the standard library only.

This file is copied into every exported folder by `fedjax-nav export` (it is
`fedjax_nav/deploy/policy_template.py` in the project). It needs no JAX, flax or fedjax_nav:

    from policy import Policy
    policy = Policy("path/to/export")              # reads weights.npz and meta.json beside it
    ranges = policy.scan_ranges(msg.ranges, msg.angle_min, msg.angle_increment,
                                msg.range_min, msg.range_max)          # a sensor_msgs/LaserScan
    policy.follow(path_xy)                          # a plan run only: the planner's path (nav_msgs/Path)
    obs = policy.observation(ranges, (x, y, yaw), (goal_x, goal_y), prev_action)
    action = policy(obs)                            # (v / v_max, omega / omega_max)
    if policy.last_unsafe: ...                      # NaN/inf in obs: action is the stop command (0, 0)
    v, omega = policy.velocity(action)              # m/s, rad/s  -> geometry_msgs/Twist
    policy.reset()                                  # at a new goal (an episode's start)

Safety (docs/export.md, "Unsafe observations"): a wrong-length observation is a ValueError naming
both sizes; a row with a NaN or +-inf in any entry (or whose action is not finite) gets the stop
command `STOP` = (0, 0), is flagged in `policy.last_unsafe` and leaves a recurrent state as it was.

Networks (meta.json's network.kind, one per learner's greedy actor):

- "heads" (DDPG, TD3): depth x (Dense + activation), then two 1-unit heads, sigmoid (v / v_max)
  and tanh (omega / omega_max). `actor_forward`.
- "squashed" (SAC, feed-forward PPO): depth x (Dense + activation), then a 2-unit mean, squashed
  into the box: (0.5 + 0.5 tanh(mean_v), tanh(mean_omega)), the Gaussian's mode. `squashed_forward`.
- "gru" (recurrent PPO): Dense + activation, a GRU cell (flax's GRUCell) on the hidden state h,
  (depth - 1) x (Dense + activation), the 2-unit mean, squashed as above. `gru_forward(weights,
  obs, h) -> (action, h)`. `Policy` keeps h between calls: zeros at the start and after
  `reset()`, which a robot calls at every new goal (the simulator's episode start, where
  training reset it), one state per batch shape. Without a memory `reset()` does nothing.

Observation normalisation (a PPO run with ppo.normalize_obs): weights.npz then also holds
"obs_norm/mean", "obs_norm/std" [obs_size] and "obs_norm/clip" [], the running statistics the
policy was trained and federated with, and every kind's first layer sees
clip((obs - mean) / std, -clip, clip) (`normalize_input`) instead of obs.

The observation's functions (`pool_scan`, `goal_features`, `build_observation`, ...) and their
conventions (beam angles, the observation's entries, scan pooling) are in policy_inputs.py, which
the export writes beside this file; this module loads it by its path and re-exports its names.
The action (the network's output and units): (v / v_max in [0, 1], omega / omega_max in
[-1, 1]); v_max (m/s) and omega_max (rad/s) are the run's, in meta.json.
"""

from __future__ import annotations

import importlib.util
import json
import math
import os

import numpy as np

__all__ = [
    "ACTIVATIONS",
    "STOP",
    "Policy",
    "check_observation",
    "stop_unsafe",
    "actor_forward",
    "squashed_forward",
    "gru_forward",
    "squash",
    "normalize_input",
    "pool_scan",
    "goal_features",
    "build_observation",
    "path_waypoint",
    "MAPLESS_LAYOUT",
    "wrap_angle",
    "yaw_from_quaternion",
    "action_to_velocity",
    "load_weights",
    "load_meta",
]


HERE = os.path.dirname(os.path.abspath(__file__))


def _beside(name: str):
    """The module `name`.py in this file's folder, loaded by its path: the export's folder need not
    be on sys.path (a ROS node loads policy.py by its path)."""
    spec = importlib.util.spec_from_file_location(f"fedjax_nav_export_{name}", os.path.join(HERE, f"{name}.py"))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


_inputs = _beside("policy_inputs")  # the observation's functions (policy_inputs.py)
pool_scan, wrap_angle, goal_features = _inputs.pool_scan, _inputs.wrap_angle, _inputs.goal_features
build_observation, yaw_from_quaternion = _inputs.build_observation, _inputs.yaw_from_quaternion
path_waypoint, MAPLESS_LAYOUT = _inputs.path_waypoint, _inputs.MAPLESS_LAYOUT


# ----------------------------------------------------------------------------- the actor


def _sigmoid(x):
    # stable for large |x| (no overflow in exp)
    e = np.exp(-np.abs(x))
    return np.where(x >= 0, 1.0 / (1.0 + e), e / (1.0 + e)).astype(x.dtype)


def _relu(x):
    return np.maximum(x, 0.0).astype(x.dtype)


def _elu(x):
    return np.where(x > 0, x, np.expm1(np.minimum(x, 0.0))).astype(x.dtype)


def _gelu(x):
    # flax.linen.gelu = jax.nn.gelu(approximate=True): the tanh approximation
    c = np.asarray(math.sqrt(2.0 / math.pi), x.dtype)
    return (x * (0.5 * (1.0 + np.tanh(c * (x + 0.044715 * (x**3)))))).astype(x.dtype)


def _silu(x):
    return (x * _sigmoid(x)).astype(x.dtype)


ACTIVATIONS = {"relu": _relu, "tanh": np.tanh, "elu": _elu, "gelu": _gelu, "silu": _silu}


def normalize_input(weights: dict, obs) -> np.ndarray:
    """The observation as the first layer sees it: clip((obs - mean) / std, -clip, clip) when the
    weights hold an observation normaliser ("obs_norm/mean", "obs_norm/std", "obs_norm/clip"),
    else obs itself; float32[..., obs_size]."""
    x = np.asarray(obs, np.float32)
    if "obs_norm/mean" not in weights:
        return x
    c = weights["obs_norm/clip"]
    return np.clip((x - weights["obs_norm/mean"]) / weights["obs_norm/std"], -c, c).astype(np.float32)


def actor_forward(weights: dict, obs, activation: str = "relu") -> np.ndarray:
    """The flax Actor's forward pass: depth x (Dense(hidden) + activation), then two 1-unit heads,
    sigmoid (v / v_max) and tanh (omega / omega_max). obs: [..., obs_size]; returns float32[..., 2].

    weights: "hidden_{i}/kernel" [in, hidden], "hidden_{i}/bias" [hidden] for i < depth, and
    "v_head/kernel" [hidden, 1], "v_head/bias" [1], "omega_head/kernel", "omega_head/bias".
    """
    x = _trunk(weights, normalize_input(weights, obs), _activation(activation))
    v = _sigmoid(x @ weights["v_head/kernel"] + weights["v_head/bias"])
    w = np.tanh(x @ weights["omega_head/kernel"] + weights["omega_head/bias"])
    return np.concatenate([v, w], axis=-1).astype(np.float32)


def _trunk(weights: dict, x, act, prefix: str = "hidden_") -> np.ndarray:
    """Every `{prefix}{i}` Dense layer in order, each followed by the activation."""
    depth = sum(1 for k in weights if k.startswith(prefix) and k.endswith("/kernel"))
    for i in range(depth):
        x = act(x @ weights[f"{prefix}{i}/kernel"] + weights[f"{prefix}{i}/bias"])
    return x


def _activation(activation: str):
    if activation not in ACTIVATIONS:
        raise ValueError(f"unknown activation {activation!r} (known: {', '.join(ACTIVATIONS)})")
    return ACTIVATIONS[activation]


# the action box [0, 1] x [-1, 1] as loc + scale * [-1, 1]
BOX_LOC = np.array([0.5, 0.0], np.float32)
BOX_SCALE = np.array([0.5, 1.0], np.float32)


def squash(mean) -> np.ndarray:
    """A raw Gaussian mean [..., 2] -> the box: loc + scale * tanh(mean) (the squashed mode)."""
    return (BOX_LOC + BOX_SCALE * np.tanh(np.asarray(mean, np.float32))).astype(np.float32)


def squashed_forward(weights: dict, obs, activation: str = "relu") -> np.ndarray:
    """A squashed-Gaussian policy's greedy action (SAC's actor, feed-forward PPO's mean net):
    depth x (Dense(hidden) + activation), then "mean" [hidden, 2], squashed into the box.
    obs: [..., obs_size]; returns float32[..., 2]."""
    x = _trunk(weights, normalize_input(weights, obs), _activation(activation))
    return squash(x @ weights["mean/kernel"] + weights["mean/bias"])


def gru_cell(weights: dict, x, h) -> np.ndarray:
    """flax's GRUCell: r = sigmoid(x W_ir + b_ir + h W_hr), z = sigmoid(x W_iz + b_iz + h W_hz),
    n = tanh(x W_in + b_in + r (h W_hn + b_hn)), h' = (1 - z) n + z h."""
    w = weights
    r = _sigmoid(x @ w["gru/ir/kernel"] + w["gru/ir/bias"] + h @ w["gru/hr/kernel"])
    z = _sigmoid(x @ w["gru/iz/kernel"] + w["gru/iz/bias"] + h @ w["gru/hz/kernel"])
    n = np.tanh(x @ w["gru/in/kernel"] + w["gru/in/bias"] + r * (h @ w["gru/hn/kernel"] + w["gru/hn/bias"]))
    return ((1.0 - z) * n + z * h).astype(np.float32)


def gru_forward(weights: dict, obs, h, activation: str = "tanh") -> tuple[np.ndarray, np.ndarray]:
    """One step of the recurrent policy: (action float32[..., 2], h' float32[..., gru]) for obs
    [..., obs_size] and the hidden state h [..., gru] before the step (zeros at an episode's start).
    Layers: "embed" + activation, the GRU ("gru/*"), "hidden_{i}" + activation, "head" [hidden, 2]."""
    act = _activation(activation)
    x = act(normalize_input(weights, obs) @ weights["embed/kernel"] + weights["embed/bias"])
    h = gru_cell(weights, x, np.asarray(h, np.float32))
    y = _trunk(weights, h, act)
    return squash(y @ weights["head/kernel"] + weights["head/bias"]), h


# the first layer (its kernel's rows are the observation) of each network kind
INPUT_LAYER = {"heads": "hidden_0", "squashed": "hidden_0", "gru": "embed"}


# ----------------------------------------------------------------------------- unsafe observations

STOP = np.zeros(2, np.float32)  # the command for an observation that cannot be trusted: v = omega = 0


def check_observation(obs, obs_size: int, layout=MAPLESS_LAYOUT) -> tuple[np.ndarray, np.ndarray]:
    """(obs float32[..., obs_size] with its unsafe rows zeroed, so that a batch's pass stays finite;
    unsafe bool[...]: a NaN or +-inf, float32's, in the row). Another length: a ValueError naming
    the entries (`layout`: the names after the ranges, meta.json's "observation_layout")."""
    with np.errstate(over="ignore"):  # a float64 beyond float32 becomes inf: unsafe
        x = np.asarray(obs, np.float32)
    if x.ndim == 0 or x.shape[-1] != obs_size:
        got = "a scalar" if x.ndim == 0 else f"{x.shape[-1]} entries (shape {list(x.shape)})"
        what = ", ".join(["num_beams ranges", *(name.replace("_", " ") for name in layout)])
        raise ValueError(f"an observation has {obs_size} entries ({what}); got {got}")
    unsafe = ~np.all(np.isfinite(x), axis=-1)
    return np.where(unsafe[..., None], np.float32(0.0), x), unsafe


def stop_unsafe(action, unsafe) -> tuple[np.ndarray, np.ndarray]:
    """(action float32[..., 2] with `STOP` in each unsafe row and each row not finite, the rows stopped)."""
    a = np.asarray(action, np.float32)
    stopped = np.asarray(unsafe, bool) | ~np.all(np.isfinite(a), axis=-1)
    return np.where(stopped[..., None], STOP, a), stopped


# ----------------------------------------------------------------------------- actions


def action_to_velocity(action, v_max: float, omega_max: float) -> tuple[float, float]:
    """Network units -> (v m/s, omega rad/s), after clipping to the box as the simulator does; an
    action with a NaN or an infinity is no command: (0.0, 0.0)."""
    a = np.asarray(action, np.float64).reshape(-1)[:2]
    if not np.all(np.isfinite(a)):
        return 0.0, 0.0
    a = np.clip(a, [0.0, -1.0], [1.0, 1.0])
    return float(a[0] * v_max), float(a[1] * omega_max)


# ----------------------------------------------------------------------------- loading


def load_meta(folder: str | None = None) -> dict:
    with open(os.path.join(folder or HERE, "meta.json")) as f:
        return json.load(f)


def load_weights(folder: str | None = None) -> dict:
    with np.load(os.path.join(folder or HERE, "weights.npz"), allow_pickle=False) as z:
        return {k: np.asarray(z[k], np.float32) for k in z.files}


class Policy:
    """The exported actor with the run's settings (meta.json) and its observation helpers.

    A recurrent policy ("gru") keeps a hidden state per batch shape (`h`: the last call's), zeros at
    the start and after `reset()` (at every new goal; a no-op for the other kinds). An unsafe row
    (NaN, +-inf) gets `STOP`, keeps its state and is flagged in `last_unsafe`."""

    def __init__(self, folder: str | None = None, weights: dict | None = None, meta: dict | None = None):
        self.folder = folder or HERE
        self.meta = meta if meta is not None else load_meta(self.folder)
        self.weights = weights if weights is not None else load_weights(self.folder)
        net = self.meta["network"]
        self.kind = net.get("kind", "heads")  # exports before other learners: DDPG's actor
        if self.kind not in INPUT_LAYER:
            raise ValueError(f"{self.folder}: unknown network kind {self.kind!r} (known: {', '.join(INPUT_LAYER)})")
        self.activation = net["activation"]
        if self.activation not in ACTIVATIONS:
            raise ValueError(f"{self.folder}: unknown activation {self.activation!r}")
        self.num_beams = int(self.meta["num_beams"])
        self.max_range = float(self.meta["max_range"])
        self.v_max = float(self.meta["v_max"])
        self.omega_max = float(self.meta["omega_max"])
        self.dt = float(self.meta.get("dt", 0.1))
        self.goal_radius = float(self.meta.get("goal_radius", 0.5))
        self.layout = tuple(self.meta.get("observation_layout", MAPLESS_LAYOUT))  # the entries after the ranges
        plan = self.meta.get("plan")  # a run with env.plan: true (docs/export.md, "Exporting a plan run")
        self.lookahead = float(plan["lookahead"]) if plan else None  # m down the path to the waypoint
        self.path = None  # the planner's path (`follow`)
        self.obs_size = self.num_beams + len(self.layout)
        k = self.weights[f"{INPUT_LAYER[self.kind]}/kernel"]
        if k.shape[0] != self.obs_size:
            raise ValueError(
                f"{self.folder}: weights take {k.shape[0]} inputs, meta.json says "
                f"num_beams={self.num_beams} and {len(self.layout)} more entries (obs size {self.obs_size})"
            )
        self.memory_size = int(self.weights["gru/hn/kernel"].shape[0]) if self.kind == "gru" else 0  # 0: none
        self.reset()

    def reset(self) -> None:
        """An episode's start (a new goal): every hidden state back to zeros (no-op without one)."""
        self.states = {}  # the batch's leading shape -> its hidden state float32[*shape, memory_size]
        self.h = np.zeros(self.memory_size, np.float32)
        self.last_unsafe = False

    def __call__(self, obs) -> np.ndarray:
        """obs float32[..., obs_size] -> action float32[..., 2] in network units (the class docstring
        for the state and unsafe rows); another length is a ValueError (`check_observation`)."""
        x, unsafe = check_observation(obs, self.obs_size, self.layout)
        lead = x.shape[:-1]
        h = self.states.get(lead, np.zeros((*lead, self.memory_size), np.float32))
        with np.errstate(over="ignore", invalid="ignore"):  # a huge input may overflow: stopped below
            if self.kind == "gru":
                action, h_next = gru_forward(self.weights, x, h, self.activation)
                unsafe = unsafe | ~np.all(np.isfinite(h_next), axis=-1)
            else:
                forward = squashed_forward if self.kind == "squashed" else actor_forward
                action, h_next = forward(self.weights, x, self.activation), h
        action, stopped = stop_unsafe(action, unsafe)
        self.h = self.states[lead] = np.where(stopped[..., None], h, h_next)  # a stopped row keeps its state
        self.last_unsafe = bool(stopped) if stopped.ndim == 0 else stopped
        return action

    act = __call__

    def scan_ranges(
        self,
        ranges,
        angle_min,
        angle_increment,
        range_min=0.0,
        range_max=math.inf,
        angle_offset=0.0,
        invalid=None,
        mode="min",
    ) -> np.ndarray:
        """`pool_scan` with this policy's num_beams and max_range."""
        return pool_scan(
            ranges,
            angle_min,
            angle_increment,
            self.num_beams,
            self.max_range,
            range_min,
            range_max,
            angle_offset,
            invalid,
            mode,
        )

    def follow(self, path) -> None:
        """A policy trained with the plan: the planner's path float[n, 2] (x, y in the pose's frame;
        None: none), whose waypoint (`path_waypoint`, the run's lookahead) `observation` then takes."""
        if self.lookahead is None:
            raise ValueError(f"{self.folder}: follow: a mapless policy (meta.json has no plan) takes no path")
        self.path = None if path is None else np.asarray(path, np.float64).reshape(-1, 2)

    def observation(self, ranges, pose, goal, prev_action=(0.0, 0.0), waypoint=None) -> np.ndarray:
        """`build_observation` with this policy's layout; a plan policy's waypoint is `waypoint`,
        else the one of the path given to `follow` at `pose` (one robot)."""
        ranges = np.asarray(ranges, np.float32)
        if ranges.shape[-1] != self.num_beams:
            raise ValueError(f"expected {self.num_beams} ranges, got {ranges.shape[-1]} (pool the scan first)")
        if waypoint is None and self.path is not None:
            waypoint = path_waypoint(self.path, pose, self.lookahead)
        return build_observation(ranges, pose, goal, prev_action, waypoint, self.layout)

    def velocity(self, action) -> tuple[float, float]:
        return action_to_velocity(action, self.v_max, self.omega_max)

    def at_goal(self, pose, goal) -> bool:
        """Whether the robot is within the run's goal radius (where a simulated episode ends)."""
        return bool(goal_features(pose, goal)[0] < self.goal_radius)


if __name__ == "__main__":  # a smoke test: python policy.py
    p = Policy()
    obs = p.observation(np.full(p.num_beams, p.max_range), (0.0, 0.0, 0.0), (1.0, 0.5), waypoint=(0.5, 0.25))
    print(json.dumps({"obs": [round(float(v), 4) for v in obs], "action": [float(v) for v in p(obs)]}))
