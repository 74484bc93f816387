"""A program that runs some of a run's robots (docs/fleet.md): robots first .. first + n - 1 of a
run of `total` robots (`Trainer(fleet=(first, total))`, one Flower client's program) draws each
per-robot random value as its robots' rows of the whole run's draw. JAX's PRNG is partitionable
(split(k, m)[i] does not depend on m, nor uniform(k, (m, 2))[i]), so a robot's key stream is the
one it has in the whole run's program, and a slice of one robot reproduces that robot's run."""

from __future__ import annotations

from typing import Callable

import jax


def rows(draw: Callable[[int], jax.Array], per_robot: int, n: int, fleet: tuple) -> jax.Array:
    """Rows of robots first .. first + n - 1 (per_robot rows each) of draw(total * per_robot),
    (first, total) = fleet; draw(n * per_robot) itself for a whole run (fleet = (0, n)). `first`
    may be traced: one compiled program then serves every robot of a world (fleet/robot.py)."""
    first, total = fleet
    if isinstance(first, int) and (first, total) == (0, n):
        return draw(n * per_robot)
    return jax.lax.dynamic_slice_in_dim(draw(total * per_robot), first * per_robot, n * per_robot)
