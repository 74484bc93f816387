"""Matmul FLOPs of a function, counted on its jaxpr: what `fedjax-nav bench train` divides by the
matmul ceiling for every learner (docs/benchmarks.md).

Every `dot_general` counts 2 FLOPs per multiply-add (2 x batch x contracted x both free sizes);
a `scan` body counts `length` times; a `cond` counts its most expensive branch (so a cond that
skips work some of the time, TD3's delayed actor, is counted as if it always ran: an upper bound);
a `while` body counts once (its trip count is not in the jaxpr); every other sub-jaxpr (jit,
custom_jvp/vjp, remat) counts once. Elementwise work is not counted: the ceiling is a matmul's.
XLA's own `cost_analysis()` is not used because it counts a while/scan body once whatever its
trip count, which is most of a training chunk.
"""

from __future__ import annotations

import math

import jax
from jax.extend import core as jcore


def _dot_flops(eqn) -> int:
    lhs, rhs = (v.aval.shape for v in eqn.invars)
    (lc, rc), (lb, rb) = eqn.params["dimension_numbers"]
    batch = math.prod(lhs[d] for d in lb)
    contract = math.prod(lhs[d] for d in lc)
    lhs_free = math.prod(s for d, s in enumerate(lhs) if d not in lc and d not in lb)
    rhs_free = math.prod(s for d, s in enumerate(rhs) if d not in rc and d not in rb)
    return 2 * batch * contract * lhs_free * rhs_free


def _sub_jaxprs(value):
    if isinstance(value, jcore.ClosedJaxpr):
        yield value.jaxpr
    elif isinstance(value, jcore.Jaxpr):
        yield value
    elif isinstance(value, tuple | list):
        for v in value:
            yield from _sub_jaxprs(v)


def jaxpr_flops(jaxpr) -> int:
    """Matmul FLOPs of one evaluation of `jaxpr` (rules in the module docstring)."""
    total = 0
    for eqn in jaxpr.eqns:
        name = eqn.primitive.name
        if name == "dot_general":
            total += _dot_flops(eqn)
        elif name == "scan":
            total += eqn.params["length"] * jaxpr_flops(eqn.params["jaxpr"].jaxpr)
        elif name == "cond":
            total += max(jaxpr_flops(b.jaxpr) for b in eqn.params["branches"])
        else:
            for value in eqn.params.values():
                for sub in _sub_jaxprs(value):
                    total += jaxpr_flops(sub)
    return total


def matmul_flops(fn, *args) -> int:
    """Matmul FLOPs of `fn(*args)` (arrays or jax.ShapeDtypeStruct: nothing is computed)."""
    return jaxpr_flops(jax.make_jaxpr(fn)(*args).jaxpr)


def learner_flops(learner, nets, obs_size: int, rows: int, hp) -> tuple[int, int]:
    """(FLOPs of one update event of one network on storage of `rows` rows per step, FLOPs of one
    exploration action for one environment), from the learner table's own functions."""
    key = jax.random.key(0)
    state = jax.eval_shape(lambda k: learner.init(nets, k, obs_size, hp), key)
    storage = jax.eval_shape(lambda: learner.storage(nets, obs_size, rows))
    update = matmul_flops(lambda s, b, k: learner.update(nets, s, b, k, 0, rows, hp), state, storage, key)
    obs = jax.ShapeDtypeStruct((obs_size,), jax.numpy.float32)
    memory = learner.memory(nets)
    first = jax.numpy.bool_(True)
    act = matmul_flops(
        lambda s, o, k: learner.explore(nets, s, o, k, hp, jax.numpy.float32(0.0), memory, first), state, obs, key
    )
    return update, act
