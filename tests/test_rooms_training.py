"""Training in rooms the robots never saw (docs/generalization.md): procedural rooms
drawn inside the compiled program, heterogeneous fleets, the disjointness of the training and
test room streams, the fixed-room program unchanged, `evaluate --suite` and `run.eval_every`.
Small: episodes of 16 steps, networks of width 8."""

import json

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest

from fedjax_nav import worlds
from fedjax_nav.config import ConfigError, load_config
from fedjax_nav.training import rooms as trooms
from fedjax_nav.training.hparams import hparams_from_config
from fedjax_nav.training.trainer import Trainer
from fedjax_nav.worlds import suites

TINY = [
    "env.episode_length=16",
    "run.chunk_episodes=1",
    "offpolicy.batch_size=8",
    "offpolicy.hidden=8",
    "offpolicy.depth=1",
    "run.checkpoint_every=0",
    "run.episodes=2",
    "fed.period=1",
    "env.worlds=[train-0,train-2]",
]


def test_procedural_rooms_change_in_one_compilation_and_fixed_robots_keep_theirs():
    """Robot 0 draws cylinder rooms every env.room_every episodes, robot 1 keeps train-2 (a mixed
    fleet); every chunk reuses one compilation, also when room_every (traced) changes."""
    cfg = load_config(
        None,
        TINY
        + [
            "env.rooms=procedural",
            "env.room_families=[cylinders,fixed]",
            "env.room_every=2",
            "env.room_spec=cylinders_max=3",
        ],
    )
    tr = Trainer(cfg)
    hp = hparams_from_config(cfg)
    traces = []
    chunk = tr.compiled_chunk(on_trace=lambda: traces.append(1))
    st = tr.init_seeds(jnp.arange(2), hp)
    M, C, S, G = tr.rooms.shape
    assert st.world.segments.shape == (2, 2, M, 4) and st.world.circles.shape == (2, 2, C, 3)
    assert C == 3 and M >= worlds.load("train-2").segments.shape[0]
    seen = [np.asarray(st.world.segments)]
    for ep in range(3):
        st, m = chunk(st, hp, jnp.int32(ep))
        seen.append(np.asarray(st.world.segments))
    assert len(traces) == 1
    # seen[i + 1]: the rooms of episode i; blocks of 2 episodes: 0, 0, 1
    assert np.array_equal(seen[1], seen[2]) and not np.array_equal(seen[2][:, 0], seen[3][:, 0])
    assert not np.array_equal(seen[1][0, 0], seen[1][1, 0])  # every seed its own rooms
    fixed = worlds.pad(worlds.load("train-2"), M, C, S, G)
    for s in seen:
        assert np.array_equal(s[:, 1], np.broadcast_to(np.asarray(fixed.segments), s[:, 1].shape))
    hp1 = hp | {"env.room_every": jnp.int32(1)}
    a = np.asarray(st.world.circles)
    st, _ = chunk(st, hp1, jnp.int32(3))
    b = np.asarray(st.world.circles)
    st, m = chunk(st, hp1, jnp.int32(4))
    c = np.asarray(st.world.circles)
    assert len(traces) == 1 and not np.array_equal(a[:, 0], b[:, 0]) and not np.array_equal(b[:, 0], c[:, 0])
    assert np.all(np.isfinite(np.asarray(m["reward"])))


def test_room_families_are_checked():
    with pytest.raises(ConfigError, match="room_families"):
        load_config(None, TINY + ["env.room_families=[jungle]"])
    with pytest.raises(ConfigError, match="one per robot"):
        load_config(None, TINY + ["env.room_families=[walls,boxes,walls]"])
    with pytest.raises(worlds.WorldError, match="room_spec"):
        Trainer(load_config(None, TINY + ["env.rooms=procedural", "env.room_spec=walls_max=99"]))


def test_training_room_stream_is_disjoint_from_every_test_suite():
    """The rooms of any seed's stream, block and robot come from train_room_key: never a seed or
    a key of a held-out suite (suites, probe and heldout included), also where the counter wraps."""
    test_seeds = np.concatenate([suites.suite_seeds(n) for n in suites.SUITES])
    assert suites.is_test_seed(test_seeds).all() and len(np.unique(test_seeds)) == len(test_seeds)
    test_keys = {tuple(k) for k in np.asarray(jax.random.key_data(jax.vmap(suites.room_key)(jnp.asarray(test_seeds))))}
    streams = np.array([0, 1, 2**31 - 5, 2**31, 2**32 - 3, 123456789], np.uint32)
    counters = (streams[:, None].astype(np.uint64) + np.arange(4096, dtype=np.uint64)[None]) % 2**32
    counters = counters.astype(np.uint32).ravel()
    masked = counters & np.uint32(suites.TEST_SEED_BASE - 1)
    assert not suites.is_test_seed(masked).any()
    keys = np.asarray(jax.random.key_data(jax.vmap(suites.train_room_key)(jnp.asarray(counters))))
    assert not test_keys & {tuple(k) for k in keys}
    # the same keys as the trainer's draw (stream + block * robots + robot)
    assert np.array_equal(keys[:1], np.asarray(jax.random.key_data(suites.train_room_key(jnp.uint32(0))))[None])


def test_random_placement_draws_clear_starts_and_goals():
    w = worlds.load("train-0")
    placed = jax.vmap(trooms.place, in_axes=(None, 0))(w, jax.random.split(jax.random.key(0), 32))
    from fedjax_nav.env.geometry import nearest_distance

    d = jax.vmap(lambda p: nearest_distance(w.segments, p[:2], w.circles))(placed.starts[:, 0])
    assert np.all(np.asarray(d) > worlds.CLEARANCE) and len(np.unique(np.asarray(placed.starts[:, 0, 0]))) > 16
    assert np.all(np.abs(np.asarray(placed.goals[:, 0])) < np.asarray(w.size) / 2)


def test_fixed_room_program_is_unchanged_by_the_room_fields():
    """A fixed-room config gives the same program (jaxpr) and state structure whatever the
    procedural fields say, and bitwise the metrics of the default config."""
    base = load_config(None, TINY)
    other = load_config(None, TINY + ["env.rooms=fixed", "env.room_families=[walls]", "env.room_every=7"])
    outs = []
    for cfg in (base, other):
        tr = Trainer(cfg)
        hp = hparams_from_config(cfg)
        st = tr.init_seeds(jnp.arange(1), hp)
        assert st.world is None and st.room_stream is None
        jaxpr = str(jax.make_jaxpr(lambda s, h, tr=tr: tr.chunk(s, h, jnp.int32(0), 1))(st, hp))
        st, m = tr.compiled_chunk()(st, hp, jnp.int32(0))
        outs.append((jaxpr, jax.device_get(m)))
    assert outs[0][0] == outs[1][0]
    for k in outs[0][1]:
        assert np.array_equal(outs[0][1][k], outs[1][1][k], equal_nan=True), k


@pytest.fixture(scope="module")
def probed_run(tmp_path_factory):
    from fedjax_nav.training.run import train

    out = tmp_path_factory.mktemp("gen") / "run"
    cfg = load_config(None, TINY + ["run.eval_every=2", "run.episodes=4", "run.eval_suite=probe", "method=snddpg"])
    train(cfg, out, progress=False)
    return out


def test_eval_every_adds_the_eval_success_column(probed_run):
    df = pd.read_csv(probed_run / "metrics.csv")
    assert "eval_success" in df
    on = df.episode % 2 == 1
    assert df.loc[~on, "eval_success"].isna().all()
    vals = df.loc[on, "eval_success"]
    assert vals.notna().all() and ((vals >= 0) & (vals <= 1)).all()


def test_evaluate_suite_writes_per_family_results_with_cis(probed_run, capsys):
    from fedjax_nav.cli import main

    assert main(["evaluate", str(probed_run), "--suite", "probe", "--attempts", "1", "--max-steps", "16"]) == 0
    folder = probed_run / "eval" / "probe"
    fams = pd.read_csv(folder / "suite_families.csv")
    assert list(fams.family) == ["cylinders", "boxes", "walls", "mixture", "all"]
    assert (fams.rooms[:4] == 4).all() and fams.rooms.iloc[4] == 16
    assert {"success", "ci_rooms_low", "ci_rooms_high", "ci_seeds_low", "ci_seeds_high"} <= set(fams)
    ok = fams.ci_rooms_low.notna()
    assert (fams.ci_rooms_low[ok] <= fams.success[ok] + 1e-9).all()
    assert (fams.success[ok] <= fams.ci_rooms_high[ok] + 1e-9).all()
    ep = pd.read_csv(folder / "suite_episodes.csv")
    assert len(ep) == 16 * 2 * 2  # rooms x goals x (1 attempt x 2 robots: SNDDPG's one network per seed)
    assert suites.is_test_seed(ep.room_seed.to_numpy()).all()
    summary = json.loads((folder / "suite.json").read_text())
    assert summary["suite"] == "probe" and len(summary["families"]) == 5
    assert main(["evaluate", str(probed_run), "--suite", "nope"]) == 2


def test_a_procedural_state_saved_and_restored_continues_bitwise(tmp_path):
    """The rooms and the room stream are checkpointed like any other leaf of the state."""
    from fedjax_nav.training.checkpoint import Checkpointer

    cfg = load_config(
        None, TINY + ["env.rooms=procedural", "env.room_families=[cylinders]", "env.room_spec=cylinders_max=3"]
    )
    tr = Trainer(cfg)
    hp = hparams_from_config(cfg)
    chunk = tr.compiled_chunk()

    def run(stop=None):
        st, out = tr.init_seeds(jnp.arange(1), hp), []
        for ep in range(3):
            if ep == stop:
                ck = Checkpointer(tmp_path, async_save=False)
                ck.save(ep, st, {"x": np.zeros(1)})
                st, _ = ck.restore(tr.init_seeds(jnp.arange(1), hp))
            st, m = chunk(st, hp, jnp.int32(ep))
            out.append(jax.device_get(m))
        return np.asarray(st.world.segments), out

    (wa, ma), (wb, mb) = run(), run(stop=2)
    assert np.array_equal(wa, wb)
    for x, y in zip(ma, mb):
        for k in x:
            assert np.array_equal(x[k], y[k], equal_nan=True), k


def test_density_thins_the_same_draws_and_one_is_the_unthinned_room():
    """generate(key, spec, density): floor(density * n) of the requested walls, boxes and
    cylinders, from the same draws; density 1 is bitwise the room without the argument."""
    from fedjax_nav.worlds.procedural import generate, generate_with_info
    from fedjax_nav.worlds.rooms import make_spec

    spec = make_spec("mixture")
    keys = jax.random.split(jax.random.key(3), 16)
    full = jax.jit(jax.vmap(lambda k: generate(k, spec)))(keys)
    one = jax.jit(jax.vmap(lambda k, d: generate(k, spec, d), in_axes=(0, None)))
    for a, b in zip(jax.tree.leaves(full), jax.tree.leaves(one(keys, 1.0))):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    info = jax.jit(jax.vmap(lambda k, d: generate_with_info(k, spec, d)[1], in_axes=(0, None)))
    i1, ih, i0 = info(keys, 1.0), info(keys, 0.5), info(keys, 0.0)
    for kind in ("walls", "boxes", "cylinders"):
        req = np.asarray(i1[f"{kind}_requested"])
        assert np.array_equal(np.asarray(ih[f"{kind}_requested"]), req // 2)
        assert (np.asarray(ih[kind]) <= req // 2).all() and (np.asarray(i0[kind]) == 0).all()
    assert np.asarray(i1["cylinders"]).sum() > 0  # the full rooms do have obstacles


def test_curriculum_density_rises_in_one_compilation_and_is_checked(capsys):
    """A run whose rooms start empty (env.room_density_start = 0) and fill over 2 episodes: episode
    0's rooms have no cylinders, later ones do; changing the (traced) curriculum recompiles
    nothing. On fixed rooms the curriculum fields are an error naming the field."""
    from fedjax_nav.cli import main

    sets = ["env.rooms=procedural", "env.room_families=[cylinders]", "env.room_spec=cylinders_min=3, cylinders_max=3"]
    cfg = load_config(None, TINY + sets + ["env.room_density_start=0", "env.room_curriculum_episodes=2"])
    tr, hp = Trainer(cfg), hparams_from_config(cfg)
    assert [float(trooms.density(hp, e)) for e in (0, 1, 2, 5)] == [0.0, 0.5, 1.0, 1.0]
    traces = []
    chunk = tr.compiled_chunk(on_trace=lambda: traces.append(1))
    st = tr.init_seeds(jnp.arange(1), hp)
    placed = []
    for ep in range(3):
        st, _ = chunk(st, hp, jnp.int32(ep))
        placed.append(int((np.asarray(st.world.circles)[..., 2] > 0).sum()))
    assert placed[0] == 0 and placed[2] > placed[0], placed
    hp2 = hp | {"env.room_density_start": jnp.float32(0.5)}
    chunk(tr.init_seeds(jnp.arange(1), hp2), hp2, jnp.int32(0))
    assert len(traces) == 1
    args = ["train", "--set", "env.room_curriculum_episodes=10", "--episodes", "2", "--quiet"]
    assert main(args) == 2
    assert "env.room_curriculum_episodes" in capsys.readouterr().err


def test_rooms_are_generated_in_batches_bitwise_as_in_one_vmap(monkeypatch):
    """Above ROOM_BATCH keys the rooms of a renewal are generated a batch at a time (bounded
    temporaries at any number of environments, docs/reliability.md): bitwise the rooms of one vmap
    over every key (the program before batching), across batch borders and a padded last batch;
    a run's rooms go through it (`TrainRooms.rooms_at`)."""
    from fedjax_nav.worlds.procedural import generate
    from fedjax_nav.worlds.rooms import make_spec

    monkeypatch.setattr(trooms, "ROOM_BATCH", 64)
    spec = make_spec("mixture")
    keys = jax.vmap(suites.train_room_key)(jnp.arange(150, dtype=jnp.uint32) + 77)  # 2 batches + 22 padded
    one = jax.jit(jax.vmap(lambda k: generate(k, spec)))(keys)
    batched = jax.jit(lambda k: trooms.generate_rooms(k, spec))(keys)
    for a, b in zip(jax.tree.leaves(one), jax.tree.leaves(batched)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    calls = []
    monkeypatch.setattr(trooms, "generate_rooms", lambda k, s, d: calls.append(k.shape) or one)
    cfg = load_config(None, [*TINY, "env.rooms=procedural", "env.room_families=[mixture]", "env.envs_per_robot=75"])
    jax.eval_shape(trooms.TrainRooms(cfg).rooms_at, jnp.arange(150, dtype=jnp.uint32))
    assert calls == [(150,)]
