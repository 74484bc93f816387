"""scripts/profile_chunk.py's attribution of XLA thunks to parts of the program (docs/benchmarks.md,
"where PPO's time goes"): shapes read from a compiled module, parts named by their row counts."""

import importlib.util
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import pytest

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "profile_chunk.py"


@pytest.fixture(scope="module")
def pc():
    spec = importlib.util.spec_from_file_location("profile_chunk", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod
    spec.loader.exec_module(mod)
    return mod


def test_the_shapes_are_read_from_a_compiled_module(pc):
    f = jax.jit(lambda x, w: jnp.tanh(x @ w))
    hlo = f.lower(jnp.ones((40, 8)), jnp.ones((8, 4))).compile().as_text()
    shapes = pc.output_shapes(hlo)
    assert shapes and all(s for s in shapes.values())
    assert any(s.startswith("f32[40,4]") for s in shapes.values())  # the product and its tanh
    assert not any(s.startswith("f32[4,40]") for s in shapes.values())


def test_a_thunk_is_named_by_the_rows_it_writes(pc):
    parts = {1280: "rollout: env step", 40960: "update: minibatch", 163840: "update: value pass"}
    assert pc.part_of("sort.46", "(u32[163840]{0}, s32[163840]{0})", parts) == "update: minibatch permutation (sort)"
    assert pc.part_of("ynn_fusion.10", "f32[40960,64]{1,0}", parts).endswith("matmuls (forward, backward)")
    assert pc.part_of("add_tanh_fusion.2", "f32[1,40960,64]{2,1,0}", parts).startswith("update: minibatch, elem")
    assert pc.part_of("dot.105", "f32[64,64]{1,0}", parts).startswith("update: weight gradients")
    assert pc.part_of("ynn_fusion.25", "f32[163840,64]{1,0}", parts) == "update: value pass"
    assert pc.part_of("cosine_atan2_fusion", "f32[1280,24]{1,0}", parts) == "rollout: env step"
    # layout braces hold numbers too: they are not rows
    assert pc.part_of("add.3", "f32[64]{0}", parts).startswith("other")


def test_a_ppo_program_names_its_step_rollout_and_minibatch_rows(pc):
    from fedjax_nav.config import load_config
    from fedjax_nav.training.trainer import Trainer

    cfg = load_config("learners/ppo", ["env.envs_per_robot=4", "ppo.rollout=8", "ppo.minibatches=2"])
    parts = pc.row_parts(Trainer(cfg))
    assert parts[5 * 4].startswith("rollout") and parts[4].startswith("rollout")
    assert parts[8 * 4] == "update: value pass and GAE over the rollout"
    assert parts[8 * 4 // 2] == "update: minibatch"
