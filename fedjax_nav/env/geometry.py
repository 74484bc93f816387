"""Analytic 2D geometry for one robot: lidar raycasting and distance to the nearest obstacle.

Everything here is written for one pose and is jittable and vmappable (over poses, over worlds,
or both); batch axes are added by the caller. Padding rows (zero-length segments, zero-radius
circles) never hit and are never near.

Two implementations of each function, chosen from the static obstacle count M + C
(docs/dense_rooms.md):

- up to `UNROLL_MAX_ROWS` rows (every shipped playground, also when stacked): the Python loop
  over obstacles is unrolled at trace time (the code of the thesis runs, unchanged). Under
  `vmap` every operation is elementwise over [batch, beams] and XLA fuses the whole cast into
  one loop, but the program, its compile time and its compile memory grow with every row (354
  rows: 20-55 s to compile one step on the development machine; a training run in a
  1,000-cylinder room was still compiling at 4 GB after 5 minutes);
- above it: a `lax.fori_loop` over fixed-size chunks of rows, each chunk unrolled, so the program
  and its compile time are bounded by the chunk size whatever the number of obstacles. Same
  per-row arithmetic; results agree with the unrolled path to float32 rounding (not bitwise).

The per-row arithmetic and both loops live in `raycast`. A third method, `method="culled"`
(`cull`, never chosen by "auto"), is the chunked loop for one pose and under a vmap whose rooms
are batched with the poses; under a vmap over the poses of one shared room it casts tiles of
poses against the rows near them only, with results bitwise the chunked loop's (docs/dense_rooms.md,
"Culling per tile").
"""

from __future__ import annotations

import jax

from fedjax_nav.env import cull
from fedjax_nav.env.raycast import (  # noqa: F401  (LIDAR_CHUNK, NEAREST_CHUNK: re-exported)
    LIDAR_CHUNK,
    NEAREST_CHUNK,
    _lidar_chunked,
    _lidar_unrolled,
    _nearest_chunked,
    _nearest_unrolled,
    beam_angles,
)

# Rows (segments + circles) up to which the unrolled loop is used. It must be >= 69: the shipped
# playgrounds stacked (48 + 21 rows after padding) keep the unrolled program and so their
# numbers bit for bit, and so do the procedural rooms of the default RoomSpec. Measured
# (docs/dense_rooms.md), the unrolled program is never faster: per CPU-second the chunked loop
# steps as fast at 32-48 rows and 8-50% faster from 64 to 192 rows, and its compile time stays
# flat while the unrolled one grows with every row. So the threshold is as low as the shipped
# rooms allow, with a margin of a few obstacles (11 rows) for small edits of them.
UNROLL_MAX_ROWS = 80

METHODS = ("auto", "unrolled", "chunked", "culled")


def _num_rows(segments: jax.Array, circles: jax.Array | None) -> int:
    return segments.shape[-2] + (0 if circles is None else circles.shape[-2])


def _use_unrolled(segments: jax.Array, circles: jax.Array | None, method: str) -> bool:
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    if method == "auto":
        return _num_rows(segments, circles) <= UNROLL_MAX_ROWS
    return method == "unrolled"


def lidar(
    segments: jax.Array,
    pose: jax.Array,
    num_beams: int = 24,
    max_range: float = 3.5,
    circles: jax.Array | None = None,
    *,
    method: str = "auto",
) -> jax.Array:
    """Ranges of `num_beams` beams from `pose` to the nearest segment or circle: f32[num_beams].

    segments: f32[M, 4] rows (x1, y1, x2, y2); circles: f32[C, 3] rows (cx, cy, r), optional;
    pose: (x, y, theta). Beam i points at theta + 2 pi i / num_beams. A beam that hits nothing
    within `max_range` reads `max_range`. Zero-length segments and zero-radius circles never hit.

    method (static): "auto" (unrolled up to `UNROLL_MAX_ROWS` rows, chunked above), "unrolled",
    "chunked" or "culled" (the chunked loop's numbers, faster for many poses in one dense room).

    Speed (measured, docs/benchmarks.md, docs/dense_rooms.md): for small rooms the loop over
    obstacles is unrolled in Python, so that under `vmap` every operation is elementwise over
    [batch, beams] and XLA fuses the whole cast into one vectorised loop; a [beams, M]
    formulation with a min-reduction over M ran 5.7x slower on CPU. The nearest hit is kept as a
    fraction (num / den) and compared by cross-multiplication, so there is one division per beam
    (per chunk, in the chunked loop) instead of one per beam-segment pair.
    """
    if method == "culled":
        return cull.lidar(segments, pose, num_beams, max_range, circles)
    if _use_unrolled(segments, circles, method):
        return _lidar_unrolled(segments, pose, num_beams, max_range, circles)
    return _lidar_chunked(segments, pose, num_beams, max_range, circles)


def nearest_distance(
    segments: jax.Array, point: jax.Array, circles: jax.Array | None = None, *, method: str = "auto"
) -> jax.Array:
    """Exact distance from `point` (x, y) to the nearest segment or circle surface: f32[].

    Negative inside a circle. Unrolled over obstacles for the same reason as `lidar`, chunked
    above `UNROLL_MAX_ROWS` rows (method as in `lidar`).
    """
    if method == "culled":
        return cull.nearest_distance(segments, point, circles)
    if _use_unrolled(segments, circles, method):
        return _nearest_unrolled(segments, point, circles)
    return _nearest_chunked(segments, point, circles)
