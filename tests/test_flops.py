"""The matmul FLOP counter of `fedjax-nav bench train` (experiments/flops.py) against hand counts."""

import jax
import jax.numpy as jnp
import pytest

from fedjax_nav.agents import learners
from fedjax_nav.agents.ddpg import update_flops
from fedjax_nav.config import values
from fedjax_nav.experiments import bench, flops
from fedjax_nav.training.hparams import hparams_from_config


def test_a_matmul_a_scan_a_vmap_and_a_cond_count_as_by_hand():
    a, b = jnp.zeros((3, 4)), jnp.zeros((4, 5))
    assert flops.matmul_flops(jnp.matmul, a, b) == 2 * 3 * 4 * 5
    sq = jnp.zeros((5, 5))
    scan7 = lambda x, w: jax.lax.scan(lambda c, _: (c @ w, None), x, None, length=7)[0]  # noqa: E731
    assert flops.matmul_flops(scan7, sq, sq) == 7 * 2 * 125
    assert flops.matmul_flops(jax.vmap(jnp.matmul), jnp.zeros((2, 3, 4)), jnp.zeros((2, 4, 5))) == 2 * 2 * 60
    # a cond counts its most expensive branch; a jitted call inside counts once
    cond = lambda p, x, w: jax.lax.cond(p, lambda: jax.jit(jnp.matmul)(x, w), lambda: jnp.zeros((3, 5)))  # noqa: E731
    assert flops.matmul_flops(cond, True, a, b) == 120
    # elementwise work is not counted
    assert flops.matmul_flops(lambda x: jnp.tanh(x) * 2.0, a) == 0


@pytest.fixture(scope="module")
def ddpg_setup():
    cfg = bench._train_config([], "ddpg")
    learner = learners.get("ddpg")
    return cfg, learner, learner.make_nets(values(cfg)), hparams_from_config(cfg)


def test_the_ddpg_update_counted_on_its_jaxpr_is_the_analytic_count_less_the_unneeded_input_gradients(ddpg_setup):
    cfg, learner, nets, hp = ddpg_setup
    per_event, per_act = flops.learner_flops(learner, nets, 28, 1, hp)
    analytic = cfg.offpolicy.gradient_steps * update_flops(
        28, cfg.offpolicy.hidden, cfg.offpolicy.depth, cfg.offpolicy.batch_size
    )
    # The analytic count takes every layer's backward as 2x its forward; autodiff skips the input
    # gradient of the first layers (actor and critic: 28x64 and 30x64 per row, 2 FLOPs a MAC).
    skipped = cfg.offpolicy.gradient_steps * cfg.offpolicy.batch_size * 2 * (28 * 64 + 30 * 64)
    assert per_event == analytic - skipped
    h = cfg.offpolicy.hidden
    assert per_act == 2 * (28 * h + (cfg.offpolicy.depth - 1) * h * h + h * 2)  # one actor forward
