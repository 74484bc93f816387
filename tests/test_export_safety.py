"""The exported policy.py as a safe controller (docs/export.md, "Unsafe observations"): an
observation of the wrong length is a ValueError naming both sizes; one holding NaN or +-inf in any
entry never becomes a motor command (the stop command (0, 0), flagged in `policy.last_unsafe`), and
a recurrent policy's state is not advanced by it; batch and single calls keep their own shapes and
states. Fuzzed with hypothesis: any float array of the right length gives finite commands within the
velocity bounds.

The policies are built from the template (fedjax_nav/deploy/policy_template.py, what `export`
writes as policy.py) with weights made here in numpy, one per network kind (and a normalised one):
no jax, nothing trained. Exact equality with the trained networks is tests/test_export.py's and
tests/test_export_learners.py's.
"""

import importlib.util
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

TEMPLATE = Path(__file__).resolve().parents[1] / "fedjax_nav" / "deploy" / "policy_template.py"
_spec = importlib.util.spec_from_file_location("policy_template_safety", TEMPLATE)
tp = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(tp)

NUM_BEAMS, HIDDEN, GRU, DEPTH = 24, 16, 8, 2
OBS = NUM_BEAMS + 4
V_MAX, OMEGA_MAX = 0.22, 2.84


def _dense(rng, n_in, n_out, name, scale=1.0):
    return {
        f"{name}/kernel": (scale * rng.normal(0, 1 / np.sqrt(n_in), (n_in, n_out))).astype(np.float32),
        f"{name}/bias": rng.normal(0, 0.3, n_out).astype(np.float32),
    }


def weights(kind: str, seed: int = 0, norm: bool = False) -> dict:
    """Random weights of the template's layout for `kind` ("heads", "squashed", "gru")."""
    rng = np.random.default_rng(seed)
    w = {}
    if kind == "gru":
        w |= _dense(rng, OBS, HIDDEN, "embed")
        for g in ("ir", "iz", "in"):
            w |= _dense(rng, HIDDEN, GRU, f"gru/{g}")
        for g in ("hr", "hz"):
            w[f"gru/{g}/kernel"] = _dense(rng, GRU, GRU, "x")["x/kernel"]
        w |= _dense(rng, GRU, GRU, "gru/hn")
        w |= _dense(rng, GRU, HIDDEN, "hidden_0")
        w |= _dense(rng, HIDDEN, 2, "head")
    else:
        w |= _dense(rng, OBS, HIDDEN, "hidden_0") | _dense(rng, HIDDEN, HIDDEN, "hidden_1")
        if kind == "heads":
            w |= _dense(rng, HIDDEN, 1, "v_head") | _dense(rng, HIDDEN, 1, "omega_head")
        else:
            w |= _dense(rng, HIDDEN, 2, "mean", scale=3.0)
    if norm:
        w["obs_norm/mean"] = rng.normal(0, 1, OBS).astype(np.float32)
        w["obs_norm/std"] = rng.uniform(0.5, 2.0, OBS).astype(np.float32)
        w["obs_norm/clip"] = np.asarray(5.0, np.float32)
    return w


def policy(name: str):
    kind, norm = name.split("+")[0], name.endswith("+norm")
    activation = {"heads": "relu", "squashed": "elu", "gru": "tanh"}[kind]
    meta = {
        "network": {"kind": kind, "activation": activation},
        "num_beams": NUM_BEAMS,
        "max_range": 3.5,
        "v_max": V_MAX,
        "omega_max": OMEGA_MAX,
    }
    return tp.Policy(weights=weights(kind, norm=norm), meta=meta)


KINDS = ["heads", "squashed", "gru", "gru+norm", "squashed+norm"]


def plausible(n, seed=1):
    rng = np.random.default_rng(seed)
    parts = [rng.uniform(0, 3.5, (n, NUM_BEAMS)), rng.uniform(0, 6, (n, 1)), rng.uniform(-np.pi, np.pi, (n, 1))]
    parts += [rng.uniform(0, 1, (n, 1)), rng.uniform(-1, 1, (n, 1))]
    return np.concatenate(parts, axis=1).astype(np.float32)


def raw_actions(name, obs_seq):
    """The bare network (the template's forward functions, no checks) along a sequence [T, ..., obs]."""
    p = policy(name)
    h = np.zeros((*obs_seq.shape[1:-1], GRU), np.float32)
    out = []
    for obs in obs_seq:
        if p.kind == "gru":
            a, h = tp.gru_forward(p.weights, obs, h, p.activation)
        elif p.kind == "squashed":
            a = tp.squashed_forward(p.weights, obs, p.activation)
        else:
            a = tp.actor_forward(p.weights, obs, p.activation)
        out.append(a)
    return np.stack(out)


# ----------------------------------------------------------------------------- wrong length


@pytest.mark.parametrize("name", KINDS)
@pytest.mark.parametrize("shape", [(OBS - 1,), (OBS + 1,), (3, OBS - 4), (0,), ()])
def test_a_wrong_length_is_a_value_error_naming_both_sizes(name, shape):
    p = policy(name)
    with pytest.raises(ValueError) as e:
        p(np.zeros(shape, np.float32))
    msg = str(e.value)
    assert f"has {OBS} entries" in msg and "\n" not in msg, msg
    assert ("a scalar" in msg) if shape == () else (f"got {shape[-1]} entries" in msg), msg
    with pytest.raises(ValueError, match=f"has {OBS} entries"):  # the ONNX caller's check
        tp.check_observation(np.zeros(shape), OBS)


# ----------------------------------------------------------------------------- non-finite entries

ENTRIES = [0, 5, NUM_BEAMS - 1, NUM_BEAMS, NUM_BEAMS + 1, NUM_BEAMS + 2, NUM_BEAMS + 3]  # beams, goal, previous action


@pytest.mark.parametrize("name", KINDS)
@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_a_non_finite_entry_is_the_stop_command_and_flagged(name, bad):
    p = policy(name)
    obs = plausible(6)
    p(obs[0])  # a state to keep
    for i in ENTRIES:
        before = p.h.copy()
        o = obs[1].copy()
        o[i] = bad
        action = p(o)
        assert action.shape == (2,) and action.dtype == np.float32 and np.array_equal(action, tp.STOP), (i, action)
        assert p.last_unsafe is True and p.velocity(action) == (0.0, 0.0)
        assert np.array_equal(p.h, before) and np.all(np.isfinite(p.h)), i  # the state was not advanced
        p(obs[2])
        assert p.last_unsafe is False


@pytest.mark.parametrize("name", KINDS)
def test_a_batch_stops_its_unsafe_rows_only_and_keeps_their_state(name):
    """Rows 1 and 3 of a 4-robot batch turn NaN / inf at step 2: they get STOP and keep the state of
    step 1; the other rows act exactly as the bare network on the same observations."""
    seq = plausible(4 * 5, seed=2).reshape(5, 4, OBS)
    dirty = seq.copy()
    dirty[2, 1, 3], dirty[2, 3, NUM_BEAMS] = np.nan, np.inf
    p = policy(name)
    got = [p(o) for o in dirty[:2]]
    h1 = p.h.copy()
    got.append(p(dirty[2]))
    assert p.last_unsafe.tolist() == [False, True, False, True]
    assert np.array_equal(got[2][[1, 3]], np.stack([tp.STOP, tp.STOP]))
    if p.kind == "gru":
        assert np.array_equal(p.h[[1, 3]], h1[[1, 3]]) and not np.array_equal(p.h[[0, 2]], h1[[0, 2]])
    clean = raw_actions(name, seq[:3])
    assert np.array_equal(np.stack(got)[:, [0, 2]], clean[:, [0, 2]])  # bit for bit: the guard changes nothing there
    assert np.array_equal(np.stack(got)[:2], clean[:2])


@pytest.mark.parametrize("name", KINDS)
def test_finite_observations_act_as_the_bare_network_bit_for_bit(name):
    seq = plausible(3 * 4, seed=4).reshape(4, 3, OBS) * np.float32(3.0)
    p = policy(name)
    got = np.stack([p(o) for o in seq])
    assert np.array_equal(got, raw_actions(name, seq)) and not np.any(p.last_unsafe)
    q = policy(name)
    single = np.stack([q(o) for o in seq[:, 0]])
    assert np.array_equal(single, raw_actions(name, seq[:, :1])[:, 0])


def test_a_finite_observation_that_overflows_the_network_is_stopped_too():
    """Entries of +-3e38 (finite in float32): relu(inf) - relu(inf) is NaN in the heads' network."""
    obs = np.full(OBS, 3e38, np.float32)
    obs[::2] *= -1
    p = policy("heads")
    with np.errstate(over="ignore", invalid="ignore"):
        assert not np.all(np.isfinite(tp.actor_forward(p.weights, obs, p.activation)))  # the bare network
    assert np.array_equal(p(obs), tp.STOP) and p.last_unsafe is True


def test_velocity_of_a_non_finite_action_is_no_command():
    for a in ([np.nan, 0.0], [0.5, np.inf], [-np.inf, np.nan]):
        assert tp.action_to_velocity(a, V_MAX, OMEGA_MAX) == (0.0, 0.0)
    assert tp.action_to_velocity([2.0, -3.0], V_MAX, OMEGA_MAX) == (V_MAX, -OMEGA_MAX)  # clipped, as before


# ----------------------------------------------------------------------------- batch and single shapes


def test_a_gru_policy_keeps_a_state_per_batch_shape():
    """A batch of 3, then one observation: (2,), not (3, 2); each shape carries its own state, as
    two policies would; reset() clears both."""
    seq = plausible(4 * 3, seed=5).reshape(4, 3, OBS)
    one = plausible(4, seed=6)
    p, batch_only, single_only = policy("gru"), policy("gru"), policy("gru")
    for t in range(4):
        a = p(seq[t])
        b = p(one[t])
        assert a.shape == (3, 2) and b.shape == (2,) and p.h.shape == (GRU,)
        assert np.array_equal(a, batch_only(seq[t])) and np.array_equal(b, single_only(one[t]))
    p.reset()
    assert np.array_equal(p(one[0]), policy("gru")(one[0]))


@pytest.mark.parametrize("name", KINDS)
def test_shapes_follow_the_observation(name):
    p = policy(name)
    obs = plausible(6).reshape(2, 3, OBS)
    assert p(obs).shape == (2, 3, 2) and p.last_unsafe.shape == (2, 3)
    assert p(obs[0, 0]).shape == (2,) and p.last_unsafe is False
    assert p(obs[0]).shape == (3, 2) and p.last_unsafe.shape == (3,)


# ----------------------------------------------------------------------------- fuzz

floats = st.floats(allow_nan=True, allow_infinity=True)
observations = st.one_of(
    hnp.arrays(np.float64, st.sampled_from([(OBS,), (3, OBS)]), elements=floats),
    hnp.arrays(np.float32, st.sampled_from([(OBS,), (3, OBS)]), elements=st.floats(width=32)),
    hnp.arrays(np.float64, (OBS,), elements=st.sampled_from([0.0, 1.0, -1.0, 3e38, -3e38, 1e300, 1e-300])),
)


@settings(max_examples=150, deadline=None, database=None, suppress_health_check=list(HealthCheck))
@given(name=st.sampled_from(KINDS), seq=st.lists(observations, min_size=1, max_size=4))
def test_any_float_observation_gives_a_finite_command_within_the_bounds(name, seq):
    p = policy(name)
    for obs in seq:
        action = p(obs)
        assert action.shape == (*obs.shape[:-1], 2) and action.dtype == np.float32
        assert np.all(np.isfinite(action)), (obs, action)
        assert np.all((action[..., 0] >= 0) & (action[..., 0] <= 1) & (np.abs(action[..., 1]) <= 1)), action
        assert np.all(np.isfinite(p.h)), p.h  # a recurrent state never holds a NaN
        stopped = np.asarray(p.last_unsafe)
        with np.errstate(over="ignore"):  # beyond float32: inf, as the policy reads it
            finite = np.all(np.isfinite(obs.astype(np.float32)), axis=-1)
        assert np.all(stopped | finite)  # every row with a NaN or an infinity was stopped
        assert np.array_equal(action[stopped], np.zeros((int(stopped.sum()), 2), np.float32))
        for a in action.reshape(-1, 2):
            v, w = p.velocity(a)
            assert 0.0 <= v <= V_MAX and -OMEGA_MAX <= w <= OMEGA_MAX
