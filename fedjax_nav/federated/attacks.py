"""Byzantine clients: what a malicious client SENDS in place of its honest parameters.

`apply_attack(kind, sent, byzantine, key, scale, reference)` takes the stacked honest
parameters `sent` (leaves `[K, ...]`), a mask `byzantine: bool[K]` and returns the stacked
parameters the server receives: Byzantine rows replaced by the attack, honest rows returned
bit for bit. `reference` is the previous global model (the model the clients last received;
a pytree without the client axis). The kind is static (a Python string, one of ATTACKS);
`scale` is traced (a jnp scalar can be swept in one compilation). Pure JAX: jittable and
vmappable over seeds (`key` and every array may carry the seed axis).

    none       theta_k                                        (no attack)
    noise      eps_k ~ N(0, scale^2) i.i.d. per coordinate    (random parameters; scale 1)
    scale      reference + scale (theta_k - reference)        (boosted / reversed update; -10)
    sign_flip  reference - (theta_k - reference)              (reversed update; scale unused)
    zeros      0
    stale      reference                                      (sends back what it received)

"stale" is read as a client that does no local work and returns the global model it last
received (its update is zero), not an older copy of its own parameters: the latter would need
a per-client history the simulator does not keep. "noise" replaces the parameters outright
(Gaussian model, as in Blanchard et al. 2017's experiments), it is not reference + noise.

`inflate_reward(rewards, byzantine, scale)` is the attack on reward-weighted aggregation (PW,
RW): Byzantine clients report |r_k| * scale + scale instead of their mean reward r_k, which
with scale > 0 is positive and larger than any honest |r| below 1, so PW/RW give them the
largest weight.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from fedjax_nav.federated.stacked import num_clients, rows

ATTACKS = ("none", "noise", "scale", "sign_flip", "zeros", "stale")
# The attacks that read the previous global model: a run with one of them keeps it in the
# aggregator's state (`fedjax_nav.federated.aggregators.with_reference` where the rule does not).
NEEDS_REFERENCE = ("scale", "sign_flip", "stale")
# The `scale` each attack uses when the caller passes None (sign_flip, zeros, stale, none
# ignore scale).
DEFAULT_SCALES = {"none": 0.0, "noise": 1.0, "scale": -10.0, "sign_flip": 0.0, "zeros": 0.0, "stale": 0.0}
DEFAULT_REWARD_SCALE = 10.0


def _check(sent, byzantine):
    k = num_clients(sent)
    byzantine = jnp.asarray(byzantine).astype(bool)
    if byzantine.shape != (k,):
        raise ValueError(f"byzantine must have shape ({k},); got {byzantine.shape}")
    return k, byzantine


def attacked_params(kind: str, sent, key=None, scale=None, reference=None):
    """What EVERY client would send under attack `kind` (stacked like `sent`); `apply_attack`
    keeps these rows for the Byzantine clients only."""
    if kind not in ATTACKS:
        raise ValueError(f"unknown attack {kind!r}; allowed: {', '.join(ATTACKS)}")
    if scale is None:
        scale = DEFAULT_SCALES[kind]
    if kind in NEEDS_REFERENCE:
        if reference is None:
            raise ValueError(f"attack {kind!r} needs reference (the previous global model)")
        if jax.tree.structure(reference) != jax.tree.structure(sent):
            raise ValueError("reference must have the structure of sent (without the client axis)")
    if kind == "none":
        return sent
    if kind == "noise":
        if key is None:
            raise ValueError("attack 'noise' needs a PRNG key")
        leaves, treedef = jax.tree.flatten(sent)
        keys = jax.random.split(key, len(leaves))
        noise = [
            (jnp.asarray(scale).astype(jnp.float32) * jax.random.normal(k, p.shape, jnp.float32)).astype(p.dtype)
            for k, p in zip(keys, leaves)
        ]
        return jax.tree.unflatten(treedef, noise)
    if kind == "scale":
        s = jnp.asarray(scale).astype(jnp.float32)
        return jax.tree.map(
            lambda p, r: (
                r[None].astype(jnp.float32) + s * (p.astype(jnp.float32) - r[None].astype(jnp.float32))
            ).astype(p.dtype),
            sent,
            reference,
        )
    if kind == "sign_flip":
        return jax.tree.map(lambda p, r: (r[None] - (p - r[None].astype(p.dtype))).astype(p.dtype), sent, reference)
    if kind == "zeros":
        return jax.tree.map(jnp.zeros_like, sent)
    # stale
    return jax.tree.map(lambda p, r: jnp.broadcast_to(r.astype(p.dtype)[None], p.shape), sent, reference)


def apply_attack(kind: str, sent, byzantine, key=None, scale=None, reference=None):
    """Stacked params as received: row k is the attack's output if byzantine[k], else sent's
    row k unchanged. kind: static name (ATTACKS); key: a PRNG key (used by "noise"; one draw
    per leaf from split(key)); scale: traced scalar (None: DEFAULT_SCALES[kind]); reference:
    the previous global model, needed by "scale", "sign_flip" and "stale"."""
    _, byzantine = _check(sent, byzantine)
    if kind == "none":
        return sent
    bad = attacked_params(kind, sent, key, scale, reference)
    return jax.tree.map(lambda b, p: jnp.where(rows(byzantine, p), b, p), bad, sent)


def inflate_reward(rewards, byzantine, scale=DEFAULT_REWARD_SCALE):
    """f32[K]: rewards as reported, r_k for honest clients and |r_k| * scale + scale for
    Byzantine ones (scale traced), the attack on PW/RW's reward weighting."""
    rewards = jnp.asarray(rewards)
    if not jnp.issubdtype(rewards.dtype, jnp.floating):
        rewards = rewards.astype(jnp.float32)
    byzantine = jnp.asarray(byzantine).astype(bool)
    if rewards.ndim != 1 or byzantine.shape != rewards.shape:
        raise ValueError(f"rewards must be [K] and byzantine bool[K]; got {rewards.shape} and {byzantine.shape}")
    s = jnp.asarray(scale).astype(rewards.dtype)
    inflated = jnp.abs(rewards) * s + s
    return jnp.where(byzantine, inflated, rewards)
