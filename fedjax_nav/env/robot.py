"""Robot-model pieces of the simulator (docs/robot.md): acceleration-limited velocities, a delayed
command, and an LDS-like lidar (noise, quantization, minimum range, dropouts, a dense scan pooled
to the policy's beams by sector minimum).

Pure functions for one robot, used by `NavEnv` when its static `robot=True` (the ideal robot of
the thesis never calls them, so its program is the one it always was). The numbers (presets and
their sources) live with `fedjax_nav.robots` (`ROBOT_MODELS`); here they arrive as
traced `EnvParams` fields.

The pooling rule is the exported policy's `pool_scan` (fedjax_nav/deploy/policy_inputs.py,
mode="min", invalid=None), so the simulator and a ROS node build the same observation from the
same scan: sample j of an S-sample scan is at heading + 2 pi j / S; beam i's sector holds the
samples at angles in [2 pi i / n - pi / n, 2 pi i / n + pi / n); a sample that reads 0 (the
LDS's "no valid return": inside the minimum range, or a dropout reported as 0) is left out; a
sector without a valid sample reads `max_range` (tests/test_robot.py checks the two against
each other).
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

DROPOUT_VALUES = ("max", "zero")


def limit_rate(current: jax.Array, target: jax.Array, rate: jax.Array, dt) -> jax.Array:
    """`current` moved towards `target` by at most `rate * dt`; rate 0 = unlimited (= target)."""
    step = rate * dt
    return jnp.where(rate > 0, current + jnp.clip(target - current, -step, step), target)


def delayed(command: jax.Array, queue: jax.Array, delay: jax.Array) -> tuple[jax.Array, jax.Array]:
    """The command issued `delay` steps ago and the queue after this step.

    queue: f32[D, 2], row j = the command issued j + 1 steps ago (zeros before the first: the robot
    stands still). delay: i32 in [0, D] (clipped)."""
    full = jnp.concatenate([command[None], queue])  # row k: issued k steps ago
    return full[jnp.clip(delay, 0, queue.shape[0])], full[:-1]


def sectors(num_samples: int, num_beams: int) -> np.ndarray:
    """Beam index of each sample of a full scan, i64[num_samples] (pool_scan's formula)."""
    width = 2.0 * math.pi / num_beams
    ang = np.arange(num_samples, dtype=np.float64) * (2.0 * math.pi / num_samples)
    shifted = np.mod(ang + 0.5 * width, 2.0 * math.pi)
    return np.floor(shifted / width).astype(np.int64) % num_beams


def _contiguous(sec: np.ndarray, num_beams: int) -> int | None:
    """The roll r such that np.roll(sec, r) is [0]*m + [1]*m + ... (then pooling is a reshape)."""
    s = sec.size
    if s % num_beams:
        return None
    m = s // num_beams
    want = np.repeat(np.arange(num_beams), m)
    for r in range(m):
        if np.array_equal(np.roll(sec, r), want):
            return r
    return None


def pool_min(values: jax.Array, invalid: jax.Array, num_beams: int, max_range: float) -> jax.Array:
    """A full scan f32[S] -> f32[num_beams]: per sector the minimum valid sample, `max_range`
    where a sector has none, clipped to [0, max_range]."""
    sec = sectors(values.shape[-1], num_beams)
    v = jnp.where(invalid, jnp.inf, values)
    roll = _contiguous(sec, num_beams)
    if roll is not None:
        if roll:
            v = jnp.roll(v, roll)
        out = jnp.min(v.reshape(num_beams, -1), axis=1)
    else:  # uneven sectors: a masked minimum over a static [beams, samples] mask
        mask = jnp.asarray(sec[None, :] == np.arange(num_beams)[:, None])
        out = jnp.min(jnp.where(mask, v[None, :], jnp.inf), axis=1)
    return jnp.clip(jnp.where(jnp.isfinite(out), out, max_range), 0.0, max_range)


def measure(
    key: jax.Array, raw: jax.Array, params, max_range: float, noise: bool, dropout_value: str = "max"
) -> tuple[jax.Array, jax.Array]:
    """True ranges f32[S] (max_range = no return) -> what the LDS reports: (ranges, invalid).

    In order: Gaussian noise (std `params.range_noise`; only with `noise`), quantization to
    `params.range_resolution` (0 = none), clipping to [0, max_range]; a return nearer than
    `params.range_min` (or at 0) is invalid (the LDS reports 0); with `noise`, each sample drops
    out with probability `params.dropout` and then reads `max_range` (dropout_value="max": no
    return) or 0 (="zero": invalid). A sample without a return stays at max_range, noiseless."""
    no_return = raw >= max_range
    r = raw
    k_noise, k_drop = jax.random.split(key) if noise else (key, key)
    if noise:
        r = r + params.range_noise * jax.random.normal(k_noise, raw.shape)
    res = params.range_resolution
    r = jnp.where(res > 0, jnp.round(r / jnp.where(res > 0, res, 1.0)) * res, r)
    r = jnp.where(no_return, max_range, jnp.clip(r, 0.0, max_range))
    invalid = ~no_return & ((r <= 0.0) | (r < params.range_min))
    if noise:
        drop = jax.random.uniform(k_drop, raw.shape) < params.dropout
        if dropout_value == "max":
            r = jnp.where(drop, max_range, r)
            invalid = invalid & ~drop
        else:
            invalid = invalid | drop
    return r, invalid


def lidar_pose(pose: jax.Array, offset: jax.Array) -> jax.Array:
    """The lidar's pose: `offset` m ahead of the centre along the heading (negative: behind)."""
    return pose + jnp.stack([offset * jnp.cos(pose[2]), offset * jnp.sin(pose[2]), 0.0 * offset])


def unicycle(pose: jax.Array, v: jax.Array, omega: jax.Array, dt: jax.Array) -> jax.Array:
    """Exact arc integration of x' = v cos th, y' = v sin th, th' = omega over dt."""
    x, y, th = pose[0], pose[1], pose[2]
    th2 = th + omega * dt
    # The arc's chord: length v dt sinc(omega dt / 2) along the midpoint heading. Equal to
    # v / omega (sin th2 - sin th, cos th - cos th2) but without its float32 cancellation, which
    # cost up to 2 mm per 2.5 cm step at omega dt ~ 1e-6..1e-4.
    h = 0.5 * omega * dt
    small = jnp.abs(h) < 1e-3
    sinc = jnp.where(small, 1.0 - h * h / 6.0, jnp.sin(h) / jnp.where(small, 1.0, h))
    chord = v * dt * sinc
    thm = th + h
    x2 = x + chord * jnp.cos(thm)
    y2 = y + chord * jnp.sin(thm)
    th2 = jnp.arctan2(jnp.sin(th2), jnp.cos(th2))
    return jnp.stack([x2, y2, th2])


def move(pose: jax.Array, vel: jax.Array, a_exec: jax.Array, params, substeps: int):
    """A modelled robot's drive (NavEnv's robot=True): `substeps` physics steps of dt / substeps;
    in each the executed velocities move towards the command by at most accel * dt / substeps,
    then the unicycle integrates. Returns (pose, the velocities reached f32[2])."""
    h = params.dt / substeps
    v_cmd, w_cmd = a_exec[0] * params.v_max, a_exec[1] * params.omega_max
    v, w = vel[0], vel[1]
    for _ in range(substeps):
        v = limit_rate(v, v_cmd, params.accel_lin, h)
        w = limit_rate(w, w_cmd, params.accel_ang, h)
        pose = unicycle(pose, v, w, h)
    return pose, jnp.stack([v, w])
