"""The navigation task for one robot: pure `reset` / `step` over `flax.struct` state and params.

gymnax style: `NavEnv` holds only static, shape-fixing settings (beam count, mode, collision
test); what a user may vary per robot or sweep (the playground, the goal, speeds, noise, reward
constants) is data in `EnvParams` (env/params.py). Batch with `jax.vmap` over (state, params) for robots in
different playgrounds, and again over seeds.

Observation, f32[num_beams + 4]: the ranges (clipped at `max_range`), the goal distance `d` (m),
the goal bearing relative to the heading (rad, in [-pi, pi]), and the previous action in the
network's units (v / v_max in [0, 1], omega / omega_max in [-1, 1]). With `NavEnv(plan=True)`
(docs/planning.md) the distance and bearing are the plan's waypoint's, and the goal's distance
follows as one more entry: f32[num_beams + 5].

Actions are given in those same units: `a = (v / v_max, omega / omega_max)`, clipped to the box.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from fedjax_nav.env import plan as gp
from fedjax_nav.env import robot as rm
from fedjax_nav.env.geometry import lidar, nearest_distance
from fedjax_nav.env.params import EnvParams, default_world, make_params  # the task's data; also from here
from fedjax_nav.env.robot import unicycle  # the motion; also `fedjax_nav.env.nav.unicycle`
from fedjax_nav.env.spaces import Box

MODES = ("learn", "eval")
NO_SEGMENTS = np.zeros((1, 4), np.float32)  # one zero-length row (never hit): a cast against circles only
COLLISION_TESTS = ("exact", "lidar")


@struct.dataclass
class EnvState:
    pose: jax.Array  # f32[3] (x, y, theta)
    prev_action: jax.Array  # f32[2] network units
    goal: jax.Array  # f32[2]
    dist: jax.Array  # f32[] goal distance at this pose
    start_index: jax.Array  # i32[] start used at the last reset
    t: jax.Array  # i32[] steps taken in this episode
    start_ranges: jax.Array  # f32[starts, beams] the noiseless scan at each start row, cast at reset
    # (robot=True: [starts, scan_samples], the true dense scan from the lidar's position)
    vel: jax.Array | None = None  # f32[2] executed (v, omega) in m/s, rad/s; robot=True only
    cmd_queue: jax.Array | None = None  # f32[max_delay, 2] past commands, newest first; max_delay > 0 only
    plan: gp.Plan | None = None  # the field to the goal and the starts' waypoints (env/plan.py), at reset; plan only


class NavEnv:
    """Static settings only (they fix shapes or the program; everything else is in EnvParams).

    mode="learn": on goal or collision (`terminated`) the robot is put back at a start and goes
    on within the same episode; at `episode_length` steps `truncated` is set and the caller starts
    the next episode with `reset` (so the observation returned at truncation is the true last one,
    the one a learner bootstraps from). mode="eval": nothing is reset; the episode is over at the
    first `terminated` or `truncated` (the caller stops there).

    noise=True draws Gaussian noise on ranges and executed actions with the stds in EnvParams
    (and, with robot=True, the lidar's dropouts); noise=False (the default for training with the
    ideal robot) draws nothing, which keeps the step cheap.

    robot=True switches the robot model on (docs/robot.md): acceleration limits, a footprint,
    the lidar's offset, quantization and minimum range, read from EnvParams (0 = off for each);
    `substeps` physics steps per control step; `max_delay` > 0 keeps a ring of past commands so
    that `EnvParams.delay_steps` (traced, <= max_delay) delays them; `scan_samples` > 0 casts a
    dense scan pooled to `num_beams` by sector minimum; `dropout_value` ("max" or "zero") is what a
    dropped sample reads. robot=False (the default) is the thesis's ideal robot, and its program
    is exactly the one before the robot model existed.

    plan=True gives the policy a global plan on the known map (docs/planning.md): at `reset` the
    distance field to the goal on a `plan_cells` x `plan_cells` grid of the room inflated by the
    collision radius (`env/plan.py`), kept in the state for the episode; `observe` gives the
    distance and bearing of the waypoint `EnvParams.plan_lookahead` m down the field in place of
    the goal's, and the goal's distance as one more entry. plan=False (the default) is the
    mapless program as it was.

    path_progress=True pays the progress reward along the shortest safe path to the goal (the
    same field, computed at reset, read by `plan.path_progress`) in place of the straight line,
    so that a detour that moves away from the goal round a wall is paid as it nears the goal by
    the path; the observation is unchanged (mapless, unless plan=True): the map shapes the
    reward in training only (docs/clutter.md, "Paid along the path"). False (the default) is
    the straight-line reward as it was.
    """

    def __init__(
        self,
        num_beams: int = 24,
        max_range: float = 3.5,
        episode_length: int = 1024,
        mode: str = "learn",
        collision_test: str = "exact",
        noise: bool = False,
        robot: bool = False,
        substeps: int = 1,
        max_delay: int = 0,
        scan_samples: int = 0,
        dropout_value: str = "max",
        plan: bool = False,
        plan_cells: int = 64,
        path_progress: bool = False,
    ):
        if mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
        if collision_test not in COLLISION_TESTS:
            raise ValueError(f"collision_test must be one of {COLLISION_TESTS}, got {collision_test!r}")
        self.num_beams = int(num_beams)
        self.max_range = float(max_range)
        self.episode_length = int(episode_length)
        self.mode = mode
        self.collision_test = collision_test
        self.noise = bool(noise)
        if dropout_value not in rm.DROPOUT_VALUES:
            raise ValueError(f"dropout_value must be one of {rm.DROPOUT_VALUES}, got {dropout_value!r}")
        if not robot and (substeps != 1 or scan_samples):
            raise ValueError("substeps and scan_samples need robot=True")
        self.robot = bool(robot)
        self.substeps = int(substeps)
        self.max_delay = int(max_delay)
        self.scan_samples = int(scan_samples) or self.num_beams
        self.dropout_value = dropout_value
        if int(plan_cells) < 2:
            raise ValueError(f"plan_cells must be >= 2, got {plan_cells!r}")
        self.plan = bool(plan)
        self.plan_cells = int(plan_cells)
        self.path_progress = bool(path_progress)

    @property
    def obs_size(self) -> int:
        return self.num_beams + len(gp.layout(self.plan))

    action_size = 2

    # ------------------------------------------------------------------ pieces

    def ranges(self, pose: jax.Array, params: EnvParams, others: jax.Array | None = None) -> jax.Array:
        """The true scan at `pose`: f32[num_beams], or with robot=True f32[scan_samples] cast from
        the lidar's position (`observe` turns it into the observation's beams). `others`: the other
        robots of a shared room as circles f32[K, 3] (r = 0 rows: no robot), cast apart and
        merged by the minimum (the room's own cast is unchanged)."""
        w = params.world
        scan = self._cast(w.segments, w.circles, pose, params)
        if others is not None:
            scan = jnp.minimum(scan, self._cast(NO_SEGMENTS, others, pose, params))
        return scan

    def _cast(self, segments: jax.Array, circles: jax.Array, pose: jax.Array, params: EnvParams) -> jax.Array:
        if self.robot:
            return lidar(segments, rm.lidar_pose(pose, params.lidar_offset), self.scan_samples, self.max_range, circles)
        return lidar(segments, pose, self.num_beams, self.max_range, circles)

    def radius(self, params: EnvParams) -> jax.Array:
        """The robot's collision radius: the footprint when the robot model sets one, else D_c;
        in a shared room the other robots are discs of this radius."""
        if self.robot:
            return jnp.where(params.footprint > 0, params.footprint, params.collision_distance)
        return params.collision_distance

    def observe(
        self, key: jax.Array, state: EnvState, ranges: jax.Array, params: EnvParams, at=None, others=None
    ) -> jax.Array:
        """The observation at `state` from the true scan `ranges`; `at`: the plan's waypoint when
        known (a start row's, kept in the plan), else computed here; `others` (a shared room): the
        other robots, which move the waypoint right by `EnvParams.plan_keep_right` (`plan.keep_right`)."""
        if self.robot:
            values, invalid = rm.measure(key, ranges, params, self.max_range, self.noise, self.dropout_value)
            ranges = rm.pool_min(values, invalid, self.num_beams, self.max_range)
        elif self.noise:
            ranges = ranges + params.range_noise * jax.random.normal(key, ranges.shape)
            ranges = jnp.clip(ranges, 0.0, self.max_range)
        target, dist = state.goal, state.dist
        if self.plan:  # the waypoint in place of the goal; the goal's distance as the last entry
            target = at if at is not None else gp.at(state.plan, params, state.goal, state.pose[:2])
            if others is not None:
                keep = (params.plan_keep_right, params.plan_keep_right_reach)
                target = gp.keep_right(state.plan.field, params.world.size, state.pose[:2], target, others, *keep)
            dist = jnp.linalg.norm(target - state.pose[:2])
        rel = target - state.pose[:2]
        bearing = jnp.arctan2(rel[1], rel[0]) - state.pose[2]
        bearing = jnp.arctan2(jnp.sin(bearing), jnp.cos(bearing))
        near = "waypoint" if self.plan else "goal"  # the entries in the order of gp.layout (the export's too)
        v, omega = state.prev_action
        entries = {f"{near}_distance": dist, f"{near}_bearing": bearing, "previous_v": v, "previous_omega": omega}
        entries = {"goal_distance": state.dist, **entries}
        return jnp.concatenate([ranges, jnp.stack([entries[k] for k in gp.layout(self.plan)])])

    def _start(self, key: jax.Array, params: EnvParams, t: jax.Array, start_ranges: jax.Array, plan=None) -> EnvState:
        w = params.world
        idx = jnp.where(params.random_starts, jax.random.randint(key, (), 0, w.num_starts), 0)
        pose = w.starts[idx]
        goal = w.goals[jnp.clip(params.goal_index, 0, w.num_goals - 1)]
        return EnvState(
            pose=pose,
            prev_action=jnp.zeros(2, jnp.float32),
            goal=goal,
            dist=jnp.linalg.norm(goal - pose[:2]),
            start_index=idx.astype(jnp.int32),
            t=t,
            start_ranges=start_ranges,
            vel=jnp.zeros(2, jnp.float32) if self.robot else None,
            cmd_queue=jnp.zeros((self.max_delay, 2), jnp.float32) if self.max_delay else None,
            plan=plan,
        )

    # ------------------------------------------------------------------ API

    def reset(self, key: jax.Array, params: EnvParams) -> tuple[jax.Array, EnvState]:
        """Start an episode. The scans at every start row are cast here, once per episode, so
        that a reset inside the episode (learn mode) needs no second cast in `step`."""
        k_start, k_obs = jax.random.split(key)
        start_ranges = jax.vmap(self.ranges, in_axes=(0, None))(params.world.starts, params)
        state = self._start(k_start, params, jnp.int32(0), start_ranges)
        if self.plan or self.path_progress:  # the goal is the episode's: a respawn inside it keeps the plan
            state = state.replace(plan=gp.make(params, state.goal, self.radius(params), self.plan_cells, self.plan))
        at = state.plan.starts[state.start_index] if self.plan else None
        return self.observe(k_obs, state, start_ranges[state.start_index], params, at), state

    def step(
        self, key: jax.Array, state: EnvState, action: jax.Array, params: EnvParams, others: jax.Array | None = None
    ) -> tuple[jax.Array, EnvState, jax.Array, jax.Array, jax.Array, dict[str, Any]]:
        """One control step: `(obs, state, reward, terminated, truncated, info)`.

        `action` = (v / v_max, omega / omega_max), clipped to [0, 1] x [-1, 1].
        `terminated`: goal or collision (a learner cuts the bootstrap); `truncated`: the time limit
        (a learner keeps it). In learn mode the obs after a terminal step is at the new start, and
        `info["final_obs"]` is the true observation at the pose the robot reached (the `s'` of the
        transition; equal to `obs` on every other step).
        info: `goal`, `collision` (bool), `pose` (after the move, before any reset),
        `clearance` (m to the nearest obstacle, or the shortest beam with collision_test="lidar"),
        `final_obs`; with `others`, also `robot_collision` (bool).

        One lidar cast per step: at the pose reached. After a reset the start's scan comes from
        `state.start_ranges`, cast once at `reset` (docs/decisions.md, "Terminal observations").

        `others` (a shared room, docs/shared_rooms.md): the other robots at the poses they reached
        this step, as circles f32[K, 3] (r = 0: no robot). `step` is `settle(move(...))`; a
        shared room calls the two apart, gathering every robot's reached pose in between.
        """
        return self.settle(key, state, self.move(key, state, action, params), params, others)

    def move(self, key: jax.Array, state: EnvState, action: jax.Array, params: EnvParams) -> EnvState:
        """The first half of `step`: the robot drives; the state at the pose reached (nothing
        sensed, nothing reset)."""
        # Without noise the key only draws the start after a reset: no split (it costs here).
        k_act = jax.random.split(key, 3)[0] if self.noise else key
        lo, hi = jnp.array([0.0, -1.0]), jnp.array([1.0, 1.0])
        a = jnp.clip(action, lo, hi)
        a_exec, queue = a, state.cmd_queue
        if self.max_delay:
            a_exec, queue = rm.delayed(a, queue, params.delay_steps)
        if self.noise:
            a_exec = jnp.clip(a_exec + params.action_noise * jax.random.normal(k_act, (2,)), lo, hi)
        if self.robot:
            pose, vel = rm.move(state.pose, state.vel, a_exec, params, self.substeps)
        else:
            pose, vel = unicycle(state.pose, a_exec[0] * params.v_max, a_exec[1] * params.omega_max, params.dt), None
        dist = jnp.linalg.norm(state.goal - pose[:2])
        return state.replace(pose=pose, prev_action=a, dist=dist, t=state.t + 1, vel=vel, cmd_queue=queue)

    def settle(
        self, key: jax.Array, state: EnvState, moved: EnvState, params: EnvParams, others: jax.Array | None = None
    ) -> tuple[jax.Array, EnvState, jax.Array, jax.Array, jax.Array, dict[str, Any]]:
        """The second half of `step` (the same `key`): sense at the pose reached, the goal, the
        collision (with `others`: also two robots closer than twice `radius`), the reward, the
        reset of learn mode. `state` is the state before `move`."""
        _, k_obs, k_reset = jax.random.split(key, 3) if self.noise else (key, key, key)
        pose, dist = moved.pose, moved.dist
        w = params.world
        goal = dist < params.goal_radius
        truncated = moved.t >= self.episode_length
        ranges = self.ranges(pose, params, others)
        if self.collision_test == "exact":
            clearance = nearest_distance(w.segments, pose[:2], w.circles)
        else:  # the thesis's test: the shortest beam at the new pose
            clearance = jnp.min(ranges)
        collision = clearance < self.radius(params)
        info, near = {}, None
        if others is not None:  # robot i's disc and robot j's touch: |p_i - p_j| < 2 radius, the same for both
            to_other = nearest_distance(NO_SEGMENTS, pose[:2], others)  # to the nearest other disc's edge
            info["robot_collision"] = to_other < self.radius(params)
            collision = collision | info["robot_collision"]
            near = to_other < self.radius(params) + params.robot_clearance
        terminated = goal | collision
        final_obs = self.observe(k_obs, moved, ranges, params, others=others)
        obs = final_obs
        if self.mode == "learn":
            start = self._start(k_reset, params, moved.t, state.start_ranges, state.plan)
            moved = jax.tree.map(lambda r, s: jnp.where(terminated, r, s), start, moved)
            scan = state.start_ranges[start.start_index]
            if others is not None:  # the start's cached scan, with the robots where they are now
                scan = jnp.minimum(scan, self._cast(NO_SEGMENTS, others, start.pose, params))
            at = state.plan.starts[start.start_index] if self.plan else None
            obs = jnp.where(terminated, self.observe(k_obs, moved, scan, params, at, others), obs)
        progress = state.dist - dist
        if self.path_progress:  # along the path; the straight line where the field has no value
            progress = gp.path_progress(state.plan.field, w.size, state.pose[:2], pose[:2], progress)
        reward = (
            params.progress_scale * progress
            + jnp.where(goal, params.reward_goal, 0.0)
            + jnp.where(collision, params.reward_collision, 0.0)
        )
        if near is not None:  # +0.0 when off: the sum above is never -0.0, so a reward bitwise unchanged
            reward = reward + jnp.where(near, params.reward_robot_near, 0.0)
        if self.mode == "eval":
            truncated = truncated & ~terminated
        info = {
            "goal": goal,
            "collision": collision,
            "pose": pose,
            "clearance": clearance,
            "final_obs": final_obs,
        } | info
        return obs, moved, reward, terminated, truncated, info

    # ------------------------------------------------------------------ gymnax conventions
    #
    # What JAX-native code written for gymnax expects of an env: `env.default_params`,
    # `env.observation_space(params)`, `env.action_space(params)` (and the module's `make`).
    # Additions only: `__init__`, `reset`, `step`, `EnvParams` and `EnvState` are untouched. One
    # difference from gymnax stays on purpose: `step` returns `terminated` and `truncated` apart
    # (gymnax has one `done`), so that off-policy learners bootstrap on a time-out.

    name = "Nav-v0"
    num_actions = 2

    @property
    def default_params(self) -> EnvParams:
        """EnvParams of `DEFAULT_WORLD` ("train-0") with every field at its default (gymnax's
        `env.default_params`; there is no world-free default: the playground is part of the params)."""
        return make_params(default_world())

    def observation_space(self, params: EnvParams | None = None) -> Box:
        """Box f32[obs_size]: ranges in [0, max_range] m, goal (plan: waypoint) distance in
        [0, dmax] m, bearing in [-pi, pi] rad, previous action in [0, 1] x [-1, 1] (plan: then the
        goal's distance in [0, dmax] m). dmax = the room's diagonal plus the longest drive of an
        episode (v_max dt episode_length); for a stacked World the
        largest over its playgrounds. The bounds are jnp arrays (traced params work too)."""
        params = self.default_params if params is None else params
        size = jnp.asarray(params.world.size, jnp.float32)
        diag = jnp.max(jnp.hypot(size[..., 0], size[..., 1]))
        dmax = (diag + jnp.max(params.v_max * params.dt) * self.episode_length).astype(jnp.float32)
        pi = jnp.float32(jnp.pi)
        zero, one = jnp.float32(0.0), jnp.float32(1.0)
        low, high = [zero, -pi, zero, -one, zero], [dmax, pi, one, one, dmax]  # plan: the goal's distance last
        low = jnp.concatenate([jnp.zeros(self.num_beams, jnp.float32), jnp.stack(low[: 4 + self.plan])])
        high = jnp.concatenate(
            [jnp.full(self.num_beams, self.max_range, jnp.float32), jnp.stack(high[: 4 + self.plan])]
        )
        return Box(low, high, (self.obs_size,), jnp.float32)

    def action_space(self, params: EnvParams | None = None) -> Box:
        """Box f32[2]: (v / v_max, omega / omega_max) in [0, 1] x [-1, 1], what `step` clips to."""
        return Box(jnp.array([0.0, -1.0], jnp.float32), jnp.array([1.0, 1.0], jnp.float32), (2,), jnp.float32)
