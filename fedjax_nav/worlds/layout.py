"""What the dense families (fedjax_nav/worlds/forest.py, warehouse.py, maze.py, cave.py) share:
starts and goals with their connectors, the trail network, thinning for the density knob, runs of
grid walls as segments, and the World's padded layout.

Each dense family builds a *clear network* first: a connected set of segments that keeps at least
``c = D_c + clearance_margin`` from every obstacle the family will draw (trails kept free, aisles,
maze passages). Every start and goal is drawn with an *anchor* on that network and a straight
*connector* to it that also keeps ``c``; so start -> connector -> network -> connector -> goal is a
path of clearance ``>= c`` for every start and goal. The density knob only removes obstacles,
which cannot make a clearance smaller.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from fedjax_nav.worlds.rooms import _START_TRIES, RoomSpec
from fedjax_nav.worlds.sampling import Uniforms, first_true, take_rows
from fedjax_nav.worlds.shapes import padded_shape
from fedjax_nav.worlds.world import World


class Endpoints(NamedTuple):
    """Starts and goals of a dense room; rows beyond the counts are drawn but unused."""

    starts: jax.Array  # f32[S, 2]
    start_anchor: jax.Array  # f32[S, 2]: the connector's end on the clear network
    yaw: jax.Array  # f32[S]
    goals: jax.Array  # f32[G, 2]
    goal_anchor: jax.Array  # f32[G, 2]
    num_starts: jax.Array  # i32[]
    num_goals: jax.Array  # i32[]
    distance_ok: jax.Array  # bool[]: every start at least min_start_goal_distance from every goal

    @property
    def start_on(self):
        return jnp.arange(self.starts.shape[0]) < self.num_starts

    @property
    def goal_on(self):
        return jnp.arange(self.goals.shape[0]) < self.num_goals

    def connectors(self):
        """(a, b, on) of the start and goal connectors: f32[S+G, 2] twice, bool[S+G]."""
        a = jnp.concatenate([self.starts, self.goals])
        b = jnp.concatenate([self.start_anchor, self.goal_anchor])
        return a, b, jnp.concatenate([self.start_on, self.goal_on])


def endpoints(rng: Uniforms, spec: RoomSpec, sample, k: int) -> Endpoints:
    """Goals, then starts by the rule of the base families: of 64 candidates per start the first
    at least `min_start_goal_distance` from every goal (else the farthest). `sample(u)` maps
    uniforms f32[..., k] to (points f32[..., 2], anchors f32[..., 2]) whose connectors are clear."""
    S, G = spec.starts_max, spec.goals_max
    n_starts = rng.randint(spec.starts_min, spec.starts_max)
    n_goals = rng.randint(spec.goals_min, spec.goals_max)
    goals, g_anchor = sample(rng.u((G, k)))
    cand, cand_anchor = sample(rng.u((S, _START_TRIES, k)))
    gd = jnp.sqrt(jnp.sum((cand[:, :, None] - goals[None, None]) ** 2, -1))  # [S, T, G]
    gd = jnp.min(jnp.where(jnp.arange(G) < n_goals, gd, jnp.inf), -1)
    first, any_ok = first_true(gd >= spec.min_start_goal_distance)
    pick = jnp.where(any_ok, first, jnp.argmax(gd, -1))
    yaw = rng.uniform((S,), -jnp.pi, jnp.pi)
    return Endpoints(
        starts=take_rows(cand, pick),
        start_anchor=take_rows(cand_anchor, pick),
        yaw=yaw,
        goals=goals,
        goal_anchor=g_anchor,
        num_starts=n_starts,
        num_goals=n_goals,
        distance_ok=jnp.all((jnp.arange(S) >= n_starts) | any_ok),
    )


def room_size(rng: Uniforms, spec: RoomSpec):
    """W, H: the first two draws of every family (one seed, one size in every family)."""
    return rng.uniform((), spec.width_min, spec.width_max), rng.uniform((), spec.height_min, spec.height_max)


def in_core(u, W, H, c):
    """Points uniform in the room shrunk by c, from uniforms u [..., 2]."""
    half = jnp.stack([W, H]) / 2 - c
    return -half + u * 2 * half


def trail_network(rng: Uniforms, W, H, c: float, k: int):
    """`k` waypoints uniform in the room shrunk by c, each joined to the nearest earlier one: a
    random tree inside a convex region that keeps c from the outer walls. Returns the waypoints
    f32[k, 2] and the trail segments (a, b) f32[k-1, 2] each."""
    pts = in_core(rng.u((k, 2)), W, H, c)
    d = jnp.sum((pts[:, None] - pts[None]) ** 2, -1)
    earlier = jnp.arange(k)[None, :] < jnp.arange(k)[:, None]
    parent = jnp.argmin(jnp.where(earlier, d, jnp.inf), -1)
    return pts, pts[1:], pts[parent[1:]]


def nearest(p, pts):
    """The row of pts [k, 2] nearest to each point p [..., 2]."""
    return pts[jnp.argmin(jnp.sum((p[..., None, :] - pts) ** 2, -1), -1)]


def trails(rng: Uniforms, spec: RoomSpec, W, H, c: float):
    """The clear network of the forest and cave families: the trail network (`trail_network` of
    `spec.trail_points` waypoints), then the goals and starts uniform in the room shrunk by c, each
    with a connector to its nearest waypoint (`endpoints`). Returns (waypoints f32[k, 2], the
    Endpoints, the network's segments a, b f32[n, 2] and on bool[n]: the trails, then the connectors)."""
    pts, ta, tb = trail_network(rng, W, H, c, spec.trail_points)

    def sample(u):
        p = in_core(u, W, H, c)
        return p, nearest(p, pts)

    ep = endpoints(rng, spec, sample, 2)
    ca, cb, con = ep.connectors()
    res_a, res_b = jnp.concatenate([ta, ca]), jnp.concatenate([tb, cb])
    res_on = jnp.concatenate([jnp.ones(ta.shape[0], bool), con])
    return pts, ep, res_a, res_b, res_on


def thin_count(n, density) -> jax.Array:
    """floor(density * n), density in [0, 1] (traced): exactly n at density 1."""
    return jnp.clip(jnp.floor(jnp.asarray(density, jnp.float32) * n), 0, n).astype(jnp.int32)


def thin_by_rank(on, u, density):
    """Keep floor(density * count) of the True entries of `on` [n], those of the smallest `u`
    [n]: a random subset, nested (a denser room keeps every obstacle of a sparser one), and `on`
    itself at density 1."""
    order = jnp.argsort(jnp.where(on, u, 2.0))
    rank = jnp.zeros(on.shape, jnp.int32).at[order].set(jnp.arange(on.shape[0], dtype=jnp.int32))
    return on & (rank < thin_count(jnp.sum(on), density))


def line_runs(present):
    """Runs of consecutive True along the last axis of `present` bool[L, N]: the first index,
    the index after the last, and whether the slot is used, each [L, ceil(N/2)], each line's runs
    first (two runs are apart by at least one False, so at most ceil(N/2) fit a line)."""
    L, N = present.shape
    R = -(-N // 2)
    idx = jnp.broadcast_to(jnp.arange(N, dtype=jnp.int32), (L, N))
    begins = present & ~jnp.concatenate([jnp.zeros((L, 1), bool), present[:, :-1]], 1)
    stop = jax.lax.cummin(jnp.where(present, N, idx), axis=1, reverse=True)  # first False at or after i
    slot = jnp.where(begins, jnp.cumsum(begins, 1) - 1, R)
    rows = jnp.arange(L)[:, None]
    start = jnp.zeros((L, R), jnp.int32).at[rows, slot].set(idx, mode="drop")
    end = jnp.zeros((L, R), jnp.int32).at[rows, slot].set(stop, mode="drop")
    on = jnp.zeros((L, R), bool).at[rows, slot].set(True, mode="drop")
    return start, end, on


def grid_runs(present_h, present_v, W, H, cx, cy):
    """Inner grid walls as segments. present_h bool[NY-1, NX]: the side between cell rows l and
    l+1 at column x; present_v bool[NX-1, NY]: the side between columns l and l+1 at row y (cells
    cx x cy, grid corner at (-W/2, -H/2)). Returns (segments f32[n, 4], on bool[n]): each line's
    runs merged into one segment (horizontal lines first)."""

    def lines(present, step_along, step_across, lo_along, lo_across, horizontal):
        s, e, on = line_runs(present)
        across = lo_across + (jnp.arange(present.shape[0], dtype=jnp.float32)[:, None] + 1) * step_across
        across = jnp.broadcast_to(across, s.shape)
        a0, a1 = lo_along + s * step_along, lo_along + e * step_along
        seg = jnp.stack([a0, across, a1, across] if horizontal else [across, a0, across, a1], -1)
        return seg.reshape(-1, 4), on.reshape(-1)

    sh, oh = lines(present_h, cx, cy, -W / 2, -H / 2, True)
    sv, ov = lines(present_v, cy, cx, -H / 2, -W / 2, False)
    segs, on = jnp.concatenate([sh, sv]), jnp.concatenate([oh, ov])
    return jnp.where(on[:, None], segs, 0.0), on


def compact(rows, on, k: int):
    """The rows with `on` first, in order, in k slots (zero rows after them; rows beyond k are
    dropped), and how many there were."""
    slot = jnp.where(on, jnp.cumsum(on) - 1, k)
    return jnp.zeros((k, rows.shape[-1]), rows.dtype).at[slot].set(rows, mode="drop"), jnp.sum(on)


def box_edges(centre, sides):
    """The 4 edges f32[..., 4, 4] of axis-aligned boxes (centre, full sides [..., 2]), in the
    order of `worlds.box_segments` at yaw 0."""
    lo, hi = centre - sides / 2, centre + sides / 2
    corners = jnp.stack(
        [
            jnp.stack([lo[..., 0], lo[..., 1]], -1),
            jnp.stack([hi[..., 0], lo[..., 1]], -1),
            jnp.stack([hi[..., 0], hi[..., 1]], -1),
            jnp.stack([lo[..., 0], hi[..., 1]], -1),
        ],
        -2,
    )
    return jnp.concatenate([corners, jnp.roll(corners, -1, axis=-2)], -1)


def assemble(spec: RoomSpec, W, H, segments, circles, ep: Endpoints) -> World:
    """The World: the 4 outer walls, then `segments` f32[m, 4], padded to `padded_shape(spec)`;
    `circles` f32[n, 3] padded; start and goal rows beyond the counts repeat row 0."""
    return pad_world(
        spec, W, H, segments, circles, ep.starts, ep.yaw, ep.start_on, ep.goals, ep.goal_on, ep.num_starts, ep.num_goals
    )


def pad_world(spec: RoomSpec, W, H, segments, circles, starts, yaw, start_on, goals, goal_on, num_starts, num_goals):
    """A generated room as a World of the shapes `padded_shape(spec)`, for every family: the 4 outer
    walls of the W x H room, then `segments` f32[m, 4], zero rows to pad; `circles` f32[n, 3], zero
    rows to pad; starts f32[S, 2] with `yaw` f32[S] and goals f32[G, 2], where the rows off
    `start_on` / `goal_on` (and the padding) repeat row 0."""
    M, C, S_out, G_out = padded_shape(spec)
    hw, hh = W / 2, H / 2
    outer = jnp.stack(
        [
            jnp.stack([-hw, -hh, hw, -hh]),
            jnp.stack([hw, -hh, hw, hh]),
            jnp.stack([hw, hh, -hw, hh]),
            jnp.stack([-hw, hh, -hw, -hh]),
        ]
    )
    segs = jnp.concatenate([outer, segments.reshape(-1, 4)])
    segs = jnp.concatenate([segs, jnp.zeros((M - segs.shape[0], 4), jnp.float32)])
    circles = jnp.concatenate([circles.reshape(-1, 3), jnp.zeros((C - circles.size // 3, 3), jnp.float32)])
    S, G = starts.shape[0], goals.shape[0]
    starts = jnp.concatenate([starts, yaw[:, None]], -1)
    starts = jnp.where(start_on[:, None], starts, starts[0])
    starts = jnp.concatenate([starts, jnp.broadcast_to(starts[0], (S_out - S, 3))])
    goals = jnp.where(goal_on[:, None], goals, goals[0])
    goals = jnp.concatenate([goals, jnp.broadcast_to(goals[0], (G_out - G, 2))])
    return World(
        segments=segs.astype(jnp.float32),
        circles=circles.astype(jnp.float32),
        starts=starts.astype(jnp.float32),
        num_starts=jnp.asarray(num_starts).astype(jnp.int32),
        goals=goals.astype(jnp.float32),
        num_goals=jnp.asarray(num_goals).astype(jnp.int32),
        size=jnp.stack([W, H]).astype(jnp.float32),
    )


def common_info(ep: Endpoints, res_a, res_b, res_on) -> dict:
    """What every dense family's info holds: the clear network (segments start-end f32[n, 4],
    used bool[n], connectors included) and whether the start-goal distance rule held."""
    return {"reserved": jnp.concatenate([res_a, res_b], -1), "reserved_on": res_on, "distance_ok": ep.distance_ok}
