"""The learnability curriculum over procedural rooms (docs/generalization.md, "Learnability
curriculum"): the sampling weights p(1 - p) + floor against numpy, the EMA score of a room always
solved rising to 1, the draw's frequencies (fresh vs bank, and the bank rooms by weight), a tiny
training run whose bank scores change in one compilation over the traced fields, the config's
refusals, and a uniform run bitwise today's program. Tiny sizes: 2 robots x 2 environments,
16-step episodes, a bank of 4 rooms, networks of width 8."""

import hashlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from fedjax_nav.config import ConfigError, load_config
from fedjax_nav.training import rooms as trooms
from fedjax_nav.training.hparams import hparams_from_config
from fedjax_nav.training.metrics import metrics_frame
from fedjax_nav.training.trainer import Trainer
from fedjax_nav.worlds import suites
from fedjax_nav.worlds.procedural import generate

TINY = [
    "env.episode_length=16",
    "run.chunk_episodes=1",
    "run.episodes=3",
    "offpolicy.batch_size=8",
    "offpolicy.buffer_size=64",
    "offpolicy.hidden=8",
    "offpolicy.depth=1",
    "run.checkpoint_every=0",
    "fed.period=1",
    "env.worlds=[train-0,train-2]",
    "env.envs_per_robot=2",
    "env.num_beams=8",
]
PROC = [
    "env.rooms=procedural",
    "env.room_families=[cylinders]",
    "env.room_spec=cylinders_max=2",
    "env.placement=random",
]
LEARN = PROC + ["env.room_sampling=learnability", "env.room_bank=4"]
B = 4


def test_weights_are_p_one_minus_p_plus_floor_normalised():
    rng = np.random.default_rng(0)
    p = np.concatenate([[0.0, 1.0, 0.5], rng.uniform(size=13)]).astype(np.float32)
    for floor in (1e-6, 0.01, 0.3):
        w = p * (1 - p) + floor
        np.testing.assert_allclose(
            np.asarray(trooms.learnability_weights(jnp.asarray(p), floor)), w / w.sum(), rtol=1e-6
        )
    # every room solved or hopeless: the floor alone, uniform
    np.testing.assert_allclose(np.asarray(trooms.learnability_weights(jnp.array([0.0, 1.0, 1.0, 0.0]), 0.01)), 0.25)


def test_a_room_always_solved_rises_to_one_and_a_hopeless_one_falls_to_zero():
    """update_score: p <- (1 - a) p + a outcome on the played slot only; from p = 0.5 (untried),
    always solved gives 1 - 0.5 (1 - a)^n."""
    upd = jax.jit(trooms.update_score)
    a = 0.3
    p = jnp.full(B, trooms.UNTRIED, jnp.float32)
    seen = []
    for _ in range(40):
        p = upd(p, jnp.int32(1), jnp.float32(1.0), a)
        seen.append(float(p[1]))
    np.testing.assert_allclose(seen, 1 - 0.5 * (1 - a) ** np.arange(1, 41), rtol=1e-5)
    assert np.all(np.diff(seen) > 0) and seen[-1] > 0.9999
    assert np.array_equal(np.asarray(p)[[0, 2, 3]], [0.5] * 3)
    q = jnp.full(B, trooms.UNTRIED, jnp.float32)
    for _ in range(40):
        q = upd(q, jnp.int32(2), jnp.float32(0.0), a)
    assert float(q[2]) < 1e-6


def test_score_is_the_goal_share_of_the_episode_and_skips_fixed_rows():
    """TrainRooms.score: goals / attempts of each environment's episode moves its current slot;
    a robot of family fixed (a mixed fleet) keeps its bank as it was."""
    cfg = load_config(None, TINY + LEARN[:1] + ["env.room_families=[cylinders,fixed]"] + LEARN[2:])
    tr = trooms.TrainRooms(cfg)
    assert tr.learnability and tr.banked.tolist() == [True, True, False, False]
    bank = tr.init_bank(jnp.uint32(7))
    bank = bank.replace(slot=jnp.array([0, 3, 1, 2], jnp.int32))
    hp = hparams_from_config(cfg) | {"env.room_ema": jnp.float32(0.5)}
    new = tr.score(bank, hp, jnp.array([3, 0, 2, 1]), jnp.array([4, 5, 2, 1]))
    want = np.full((4, B), 0.5, np.float32)
    want[0, 0] = 0.5 * 0.5 + 0.5 * 0.75  # 3 goals of 4 attempts
    want[1, 3] = 0.25  # no goal in 5 attempts
    np.testing.assert_allclose(np.asarray(new.p), want)
    m = tr.bank_metrics(new)
    np.testing.assert_allclose(np.asarray(m["room_p"])[:2], want[:2].mean(1))
    assert np.isnan(np.asarray(m["room_p"])[2:]).all() and np.isnan(np.asarray(m["fresh_rooms"])[2:]).all()


def test_draws_come_fresh_or_from_the_bank_with_the_right_frequencies():
    """Over many keys: a fresh room with probability room_fresh (binomial bound), placed in the
    least learnable slot (ties: the lowest) as untried; otherwise a bank slot with frequencies
    learnability_weights (chi-square, 3 degrees of freedom, p = 0.001)."""
    n, fresh_prob, floor = 20_000, 0.3, 0.01
    rooms = jnp.array([10, 11, 12, 13], jnp.uint32)
    p = jnp.array([0.5, 0.9, 1.0, 0.0], jnp.float32)  # scores 0.25, 0.09, 0, 0
    keys = jax.random.split(jax.random.key(42), n)
    draw = jax.jit(jax.vmap(trooms.draw_room, in_axes=(0, None, None, None, None, None)))
    r, q, slot, fresh = (np.asarray(x) for x in draw(keys, rooms, p, jnp.uint32(99), fresh_prob, floor))
    k = fresh.sum()
    assert abs(k - n * fresh_prob) < 4.5 * np.sqrt(n * fresh_prob * (1 - fresh_prob)), k
    assert (slot[fresh] == 2).all() and (r[fresh, 2] == 99).all() and (q[fresh, 2] == 0.5).all()
    assert (r[~fresh] == np.asarray(rooms)).all() and (q[~fresh] == np.asarray(p)).all()
    counts = np.bincount(slot[~fresh], minlength=B)
    expected = np.asarray(trooms.learnability_weights(p, floor)) * (~fresh).sum()
    chi2 = ((counts - expected) ** 2 / expected).sum()
    assert chi2 < 16.27, (counts, expected)  # the 0.999 quantile of chi-square with 3 dof
    assert counts[0] > 2 * counts[1] > 4 * counts[2]  # p(1 - p) dominates the floor
    never = draw(keys[:500], rooms, p, jnp.uint32(99), 0.0, floor)[3]
    always = draw(keys[:500], rooms, p, jnp.uint32(99), 1.0, floor)[3]
    assert not np.asarray(never).any() and np.asarray(always).all()


@pytest.fixture(scope="module")
def learn_run():
    """3 episodes of a learnability run (one seed), compiled once with a trace counter, then one
    more chunk with other values of the three traced fields."""
    cfg = load_config(None, TINY + LEARN)
    tr, hp = Trainer(cfg), hparams_from_config(cfg)
    traces = []
    chunk = tr.compiled_chunk(on_trace=lambda: traces.append(1))
    st0 = tr.init_seeds(jnp.arange(1), hp)
    init = jax.device_get(st0.bank)
    st, ms = st0, []
    for ep in range(3):
        st, m = chunk(st, hp, jnp.int32(ep))
        ms.append(jax.device_get(m))
    hp2 = hp | {
        "env.room_fresh": jnp.float32(1.0),
        "env.room_ema": jnp.float32(0.9),
        "env.room_floor": jnp.float32(0.2),
    }
    before = jax.device_get(st.bank)
    st, m2 = chunk(st, hp2, jnp.int32(3))
    return {"tr": tr, "init": init, "before": before, "st": st, "ms": ms, "m2": jax.device_get(m2), "traces": traces}


def test_a_tiny_learnability_run_scores_its_bank_in_one_compilation(learn_run):
    r = learn_run
    tr, st, init = r["tr"], r["st"], r["init"]
    assert len(r["traces"]) == 1  # three traced fields changed: no recompilation
    # the initial bank: the rooms of blocks 0 .. B-1 (block 0 = the initial room), all untried
    stream = np.asarray(st.room_stream)[0]
    want = (
        stream + np.arange(B, dtype=np.uint32)[None] * np.uint32(4) + np.arange(4, dtype=np.uint32)[:, None]
    ).astype(np.uint32)
    assert np.array_equal(init.rooms[0], want) and (init.p == 0.5).all()
    assert init.rooms.shape == (1, 4, B) and init.p.shape == (1, 4, B)
    # the scores moved, within [0, 1]; the metrics are per robot and read the bank
    p = np.asarray(r["before"].p[0])
    assert (p != 0.5).any() and ((p >= 0) & (p <= 1)).all()
    for m in r["ms"]:
        assert m["room_p"].shape == (1, 1, 2) and m["fresh_rooms"].shape == (1, 1, 2)
        assert set(np.unique(m["fresh_rooms"] * 2)) <= {0.0, 1.0, 2.0}
    np.testing.assert_allclose(r["ms"][-1]["room_p"][0, 0], p.reshape(2, 2 * B).mean(1), rtol=1e-6)
    df = metrics_frame(r["ms"][-1], tr.cfg, tr.facts())  # what metrics.csv holds: one row per seed, episode, robot
    np.testing.assert_allclose(df["room_p"], r["ms"][-1]["room_p"].ravel())
    assert "fresh_rooms" in df and len(df) == 2
    # room_fresh = 1: every environment drew a fresh room, the fresh room of block 3 + B
    after = st.bank
    assert (r["m2"]["fresh_rooms"] == 1).all() and np.asarray(after.fresh).all()
    slot = np.asarray(after.slot[0])
    fresh = (stream + np.uint32(3 + B) * np.uint32(4) + np.arange(4, dtype=np.uint32)).astype(np.uint32)
    assert np.array_equal(np.asarray(after.rooms[0])[np.arange(4), slot], fresh)
    # each environment's current room is its slot's room, generated from a training key (here op by
    # op, so equal to float32 round-off)
    spec = tr.rooms.specs["cylinders"]
    for row in range(4):
        room = generate(suites.train_room_key(jnp.uint32(fresh[row])), spec)
        np.testing.assert_allclose(np.asarray(st.world.circles[0, row]), np.asarray(room.circles), atol=1e-6)
        np.testing.assert_allclose(np.asarray(st.world.segments[0, row]), np.asarray(room.segments), atol=1e-6)


def _bytes(x) -> bytes:
    x = jax.random.key_data(x) if jax.dtypes.issubdtype(x.dtype, jax.dtypes.prng_key) else x
    return np.ascontiguousarray(np.asarray(x)).tobytes()


# sha256 of the metrics and the final state of the uniform run below, one record per (jax versions,
# CPU kind) as in tests/test_programme_fingerprint.py: this machine's from the code before the typed
# HParams and the learner table (f36fbce), itself equal to the program before the learnability
# curriculum; skipped, saying so, on a machine with no record
UNIFORM = {
    "records": [
        {
            "versions": {
                "cpu": "AuthenticAMD family 23 model 1 flags 4306b6e1dba3",
                "flax": "0.12.8",
                "jax": "0.10.2",
                "jaxlib": "0.10.2",
                "machine": "x86_64",
            },
            "recorded_from": "f36fbce",
            "cases": {"uniform": "8ca56ee7e900d3325b7bff82c3a2e1eb0ae14429dc67fa3c27696ed976f95d51"},
        }
    ]
}


def test_uniform_sampling_is_bitwise_todays_program():
    """The default (env.room_sampling = uniform) procedural run: no bank in the state, and its
    metrics and state bitwise those of the program before the curriculum existed."""
    from test_programme_fingerprint import skip_unless_recorded

    cfg = load_config(None, TINY + PROC)
    assert cfg.env.room_sampling == "uniform" and cfg == load_config(None, TINY + PROC + ["env.room_sampling=uniform"])
    tr, hp = Trainer(cfg), hparams_from_config(cfg)
    assert not tr.rooms.learnability
    st = tr.init_seeds(jnp.arange(1), hp)
    assert st.bank is None
    digest = skip_unless_recorded(UNIFORM, "the uniform run's digest")["cases"]["uniform"]
    chunk = tr.compiled_chunk()
    h = hashlib.sha256()
    for ep in range(2):
        st, m = chunk(st, hp, jnp.int32(ep))
        assert "room_p" not in m and "fresh_rooms" not in m
        for k in sorted(m):
            h.update(k.encode() + _bytes(m[k]))
    for leaf in jax.tree.leaves(st):
        h.update(_bytes(leaf))
    assert h.hexdigest() == digest


@pytest.mark.parametrize(
    "sets,match",
    [
        (["env.room_sampling=learnability"], "env.room_sampling = learnability draws procedural"),
        (PROC + ["env.room_fresh=0.2"], "env.room_fresh"),
        (PROC + ["env.room_bank=8"], "env.room_bank"),
        (PROC + ["env.room_ema=0.1"], "env.room_ema"),
        (PROC + ["env.room_floor=0.1"], "env.room_floor"),
        (LEARN + ["env.room_families=[fixed]"], "needs a generated family"),
        (LEARN + ["env.room_floor=0"], "env.room_floor"),
        (LEARN + ["env.room_bank=0"], "env.room_bank"),
        (LEARN + ["env.room_sampling=sfl"], "env.room_sampling"),
    ],
)
def test_the_curriculum_fields_are_checked(sets, match):
    with pytest.raises(ConfigError, match=match):
        load_config(None, TINY + sets)
