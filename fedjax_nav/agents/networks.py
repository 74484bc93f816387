"""Actor and critic (flax linen), as the thesis describes them (docs/decisions.md, "action units").

Actor: obs -> depth x Dense(hidden) + activation -> two 1-d heads, sigmoid (v) and tanh (omega),
Xavier-uniform initialised. The output is in the env's action units, (v / v_max, omega / omega_max)
in [0, 1] x [-1, 1]; the env rescales to m/s and rad/s.
Critic: concat(obs, action) -> depth x Dense(hidden) + activation -> Dense(1).
"""

from __future__ import annotations

import flax.linen as nn
import jax.numpy as jnp

ACTIVATIONS = {"relu": nn.relu, "tanh": nn.tanh, "elu": nn.elu, "gelu": nn.gelu, "silu": nn.silu}


# f32 values per batch row and hidden unit of each layer in one replay update (critic step, then
# actor step; forward and backward). Measured: XLA CPU's temporaries of the thesis FLDDPG chunk
# program (5 networks), batch 65536 minus batch 4096, per row and network: hidden 16 / depth 1, 2:
# 204, 268 values; hidden 64 / depth 3: 1,054; hidden 256 / depth 1, 3, 6: 1,630, 3,934, 7,006.
# (5 depth + 3) hidden plus the batch twice gives 1.2-1.3x each of them.
ACTIVATIONS_PER_LAYER = 5
ACTIVATIONS_OUTSIDE = 3


class Actor(nn.Module):
    hidden: int = 64
    depth: int = 3
    activation: str = "relu"

    @nn.compact
    def __call__(self, obs: jnp.ndarray) -> jnp.ndarray:
        act = ACTIVATIONS[self.activation]
        x = obs
        for _ in range(self.depth):
            x = act(nn.Dense(self.hidden)(x))
        init = nn.initializers.xavier_uniform()
        v = nn.sigmoid(nn.Dense(1, kernel_init=init, name="v_head")(x))
        w = nn.tanh(nn.Dense(1, kernel_init=init, name="omega_head")(x))
        return jnp.concatenate([v, w], axis=-1)


class Critic(nn.Module):
    hidden: int = 64
    depth: int = 3
    activation: str = "relu"

    @nn.compact
    def __call__(self, obs: jnp.ndarray, action: jnp.ndarray) -> jnp.ndarray:
        act = ACTIVATIONS[self.activation]
        x = jnp.concatenate([obs, action], axis=-1)
        for _ in range(self.depth):
            x = act(nn.Dense(self.hidden)(x))
        return nn.Dense(1)(x)[..., 0]


def mlp_flops(in_dim: int, hidden: int, depth: int, out_dim: int) -> int:
    """Multiply-add FLOPs (2 per MAC) of one forward pass for one input row."""
    dims = [in_dim] + [hidden] * depth + [out_dim]
    return 2 * sum(a * b for a, b in zip(dims[:-1], dims[1:]))
