"""Federation that survives real fleets (docs/robustness.md), end to end in the trainer: the robust
aggregators as `Aggregator`s against float64 numpy references (masks and the soft mix tau), the
participation mask (rate, skipped rounds, bitwise today's round at participation 1), the
Byzantine attacks on what is sent, honest-client metrics, one compilation for a sweep over the
new traced fields, and the config errors naming the fields (exit 2).

The centers themselves are tested in tests/test_robust.py; its numpy references are reused."""

import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest
import test_robust as R
import yaml

from fedjax_nav import cli, config
from fedjax_nav.config import load_config
from fedjax_nav.federated import aggregators as agg
from fedjax_nav.federated import attacks, robust
from fedjax_nav.training import federation
from fedjax_nav.training.federation import FED_STREAM
from fedjax_nav.training.hparams import hparams_from_config
from fedjax_nav.training.trainer import Trainer

ROOT = Path(__file__).resolve().parents[1]
FLDDPG = ROOT / "configs" / "thesis" / "flddpg.yaml"
TINY = [
    "env.episode_length=16",
    "run.chunk_episodes=1",
    "offpolicy.batch_size=8",
    "offpolicy.buffer_size=64",
    "offpolicy.hidden=16",
    "run.checkpoint_every=0",
    "run.episodes=2",
    "fed.period=1",
    # 5 clients in the smallest shipped room (compile time grows with the rooms' obstacles)
    "env.worlds=[train-0,train-0,train-0,train-0,train-0]",
]


def tiny(*extra, base=FLDDPG):
    return load_config(base, TINY + list(extra))


def hp_for(**kw):
    """The fed.* HParams of a robust rule (traced dtypes as in hparams_from_config)."""
    hp = hparams_from_config(config.Config())
    return hp.replace_flat({f"fed.{k}": jnp.asarray(v, getattr(hp.fed, k).dtype) for k, v in kw.items()})


# ----------------------------------------------------------------------------- tables


def test_config_choices_are_the_federated_tables():
    assert config.ROBUST_AGGREGATORS == ("method", *agg.ROBUST)
    assert set(agg.ROBUST) == set(robust.CENTERS) and all(agg.RULES[n].keeps_reference for n in agg.ROBUST)
    assert config.ATTACKS == attacks.ATTACKS


# ----------------------------------------------------------------------------- the rules against numpy


def _reference_center(name, params, mask, reference, hp):
    if name == "mean":
        return R.ref_masked_mean(params, mask)
    if name == "median":
        return R.ref_median(params, mask)
    if name == "trimmed_mean":
        return R.ref_trimmed(params, mask, float(hp.fed.trim))
    if name == "krum":
        return R.ref_krum(params, mask, int(hp.fed.krum_f), int(hp.fed.krum_m))
    if name == "geometric_median":
        return R.ref_geometric_median(params, mask, robust.GEOMETRIC_MEDIAN_ITERS)
    return R.ref_norm_bounded(params, mask, reference, float(hp.fed.max_norm))


@pytest.mark.parametrize("name", agg.ROBUST)
def test_robust_aggregators_against_numpy_with_masks_and_tau(name):
    """update(): theta_w = the center of the participants (float64 reference), participants
    theta_k <- (1 - tau) theta_k + tau theta_w, absent clients unchanged (even if they hold inf
    or NaN), and the new state's reference is theta_w."""
    rng = np.random.default_rng(14)
    rule = agg.RULES[name]

    @jax.jit
    def update(params, rewards, state, hp, mask):  # the rule built from traced hyperparameters
        return rule.make(**{h: getattr(hp.fed, h) for h in rule.hparams}).update(params, rewards, state, mask)

    for k in (5, 6):
        for mask in R.masks_for(k, rng):
            for tau, extra in [
                (0.5, dict(trim=0.2, krum_f=1, krum_m=1, max_norm=0.5)),
                (1.0, dict(trim=0.34, krum_f=0, krum_m=2, max_norm=3.0)),
            ]:
                params = R.poison_absent(R.random_params(rng, k), mask)
                hp = hp_for(tau=tau, **extra)
                state = agg.ReferenceState(R.random_reference(rng))
                new, st = update(params, jnp.zeros(k), state, hp, jnp.asarray(mask))
                theta_w = _reference_center(name, params, mask, state.reference, hp)
                R.assert_close(st.reference, theta_w, rtol=1e-4, atol=1e-5)
                for got, p, w in zip(jax.tree.leaves(new), R.leaves64(params), theta_w):
                    got = np.asarray(got, np.float64)
                    np.testing.assert_array_equal(got[~mask], np.asarray(p, np.float32)[~mask].astype(np.float64))
                    want = (1 - tau) * p[mask] + tau * w[None]
                    np.testing.assert_allclose(got[mask], want, rtol=1e-4, atol=1e-5, err_msg=f"{name} k={k}")


def test_robust_rule_starts_from_the_mean_and_with_reference_tracks_the_global_model():
    rng = np.random.default_rng(0)
    params = R.random_params(rng, 5)
    st = agg.make("norm_bounded", tau=0.5, max_norm=1.0).init(params)
    R.assert_close(st.reference, [x.mean(0) for x in R.leaves64(params)])
    soft = agg.make("soft", tau=jnp.float32(0.5))
    wrapped = agg.with_reference(soft)
    mask = jnp.asarray([True, False, True, True, False])
    want, _ = soft.update(params, jnp.zeros(5), soft.init(params), mask)
    got, st = wrapped.update(params, jnp.zeros(5), wrapped.init(params), mask)
    assert all(np.array_equal(x, y) for x, y in zip(jax.tree.leaves(got), jax.tree.leaves(want)))
    # soft FedAvg's mix keeps the participants' mean: the reference is theta_w
    R.assert_close(st.reference, R.ref_masked_mean(params, np.asarray(mask)), rtol=1e-5, atol=1e-6)


# ----------------------------------------------------------------------------- participation


@pytest.fixture(scope="module")
def fed_states():
    """Per config: (trainer, hp, one seed's state with clients that differ and rewards)."""
    cache = {}

    def get(*extra, base=FLDDPG):
        key = (base, extra)
        if key not in cache:
            cfg = tiny(*extra, base=base)
            tr, hp = Trainer(cfg), hparams_from_config(cfg)
            st = tr.init(jax.random.key(3), hp)
            st = st.replace(
                reward_sum=jax.random.normal(jax.random.key(1), st.reward_sum.shape), reward_steps=jnp.float32(20.0)
            )
            cache[key] = (tr, hp, st)
        return cache[key]

    return get


def _rounds(tr, hp, st, n):
    """n rounds from the same state with n different keys: (states, stats), leaves [n, ...]."""
    keys = jax.random.split(jax.random.key(7), n)
    return jax.jit(jax.vmap(lambda k: tr.federated_round(st.replace(key=k), hp)))(keys)


def test_participation_mask_rate(fed_states):
    tr, hp, _ = fed_states("fed.participation=0.3")
    draws = jax.vmap(lambda k: federation.participation(tr.round, k, hp))(jax.random.split(jax.random.key(0), 4000))
    assert draws.shape == (4000, 5) and abs(float(draws.mean()) - 0.3) < 0.02
    assert np.allclose(np.asarray(draws).mean(0), 0.3, atol=0.04)  # every client alike
    for p, want in [(1.0, True), (0.0, False)]:
        d = jax.vmap(lambda k, p=p: federation.participation(tr.round, k, hp | {"fed.participation": jnp.float32(p)}))(
            jax.random.split(jax.random.key(1), 500)
        )
        assert np.all(np.asarray(d) == want)


def test_absent_clients_keep_their_model_and_small_rounds_are_skipped(fed_states):
    tr, hp, st = fed_states("fed.participation=0.5", "fed.min_clients=3", "fed.tau=1.0")
    out, stats = _rounds(tr, hp, st, 64)
    part_keys = jax.vmap(lambda k: jax.random.split(jax.random.fold_in(k, FED_STREAM))[0])(
        jax.random.split(jax.random.key(7), 64)
    )
    masks = jax.vmap(lambda k: federation.participation(tr.round, k, hp))(part_keys)
    n = np.asarray(masks).sum(1)
    held = n >= 3
    assert held.any() and (~held).any()
    np.testing.assert_array_equal(stats["skipped"], (~held).astype(int))
    np.testing.assert_array_equal(stats["clients"], np.where(held, n, 0))
    own = np.asarray(st.agents.actor["params"]["Dense_0"]["kernel"])
    got = np.asarray(out.agents.actor["params"]["Dense_0"]["kernel"])  # [rounds, clients, ...]
    for i in range(64):
        m = np.asarray(masks[i])
        if not held[i]:
            np.testing.assert_array_equal(got[i], own)  # skipped: nothing moves
            continue
        np.testing.assert_array_equal(got[i][~m], own[~m])  # absent: their own (stale) model
        np.testing.assert_allclose(got[i][m], np.broadcast_to(own[m].mean(0), got[i][m].shape), rtol=1e-5, atol=1e-6)
    assert np.all(np.asarray(out.reward_steps) == 0)


def test_participation_one_is_todays_round_bit_for_bit(fed_states):
    """The round before partial participation existed: every client, the method's aggregator, no draws."""
    for base in (FLDDPG, ROOT / "configs" / "thesis" / "pwddpg.yaml", ROOT / "configs" / "thesis" / "gsddpg.yaml"):
        tr, hp, st = fed_states(base=base)

        def old_round(st, hp, tr=tr):  # both jitted: eager op-by-op float32 differs from XLA's fusion
            r = st.reward_sum / jnp.maximum(st.reward_steps, 1.0)
            new, agg_state = tr.aggregator(hp).update(tr.shared(st.agents), r, st.agg_state, jnp.ones(5, bool))
            return st.replace(
                agents=st.agents.replace(**new),
                agg_state=agg_state,
                reward_sum=jnp.zeros_like(st.reward_sum),
                reward_steps=jnp.float32(0),
            )

        want = jax.jit(old_round)(st, hp)
        got, stats = jax.jit(tr.federated_round)(st, hp)
        raw = lambda t: jax.tree.leaves(jax.tree.map(_raw, t))  # noqa: E731
        for x, y in zip(raw(got), raw(want)):
            np.testing.assert_array_equal(x, y)
        assert int(stats["clients"]) == 5 and int(stats["skipped"]) == 0


def _raw(x):
    return jax.random.key_data(x) if _is_key(x) else x


def _is_key(x):
    return isinstance(x, jax.Array) and jax.dtypes.issubdtype(x.dtype, jax.dtypes.prng_key)


def test_a_whole_run_at_participation_one_is_todays_run(monkeypatch):
    """A tiny FLDDPG run (2 episodes, a round each) equals the same run with the round
    before partial participation patched in, bit for bit: the participation draws do not touch the key stream."""
    cfg = tiny("run.episodes=2")
    hp = hparams_from_config(cfg)

    def run(tr):
        states = tr.init_seeds(jnp.arange(1), hp)
        states, m = jax.jit(lambda s: tr.chunk(s, hp, jnp.int32(0), 2))(states)
        return states, m

    new_states, new_m = run(Trainer(cfg))
    old = Trainer(cfg)

    def old_round(state, hp):
        r = state.reward_sum / jnp.maximum(state.reward_steps, 1.0)
        new, agg_state = old.aggregator(hp).update(old.shared(state.agents), r, state.agg_state, jnp.ones(5, bool))
        return state.replace(
            agents=state.agents.replace(**new),
            agg_state=agg_state,
            reward_sum=jnp.zeros_like(state.reward_sum),
            reward_steps=jnp.float32(0),
        ), {"clients": jnp.int32(5), "skipped": jnp.int32(0)}

    monkeypatch.setattr(federation, "federated_round", lambda rnd, state, hp: old_round(state, hp))
    old_states, old_m = run(old)
    for k in ("reward", "goals", "critic_loss", "q", "fed_events", "fed_clients"):
        np.testing.assert_array_equal(new_m[k], old_m[k], err_msg=k)
    for x, y in zip(jax.tree.leaves(new_states.agents), jax.tree.leaves(old_states.agents)):
        np.testing.assert_array_equal(x, y)


# ----------------------------------------------------------------------------- attacks


def test_byzantine_clients_send_the_attack_and_keep_their_own_model(fed_states):
    tr, hp, st = fed_states("fed.byzantine=2", "fed.attack=zeros", "fed.tau=1.0")
    got, stats = jax.jit(tr.federated_round)(st, hp)
    own = np.asarray(st.agents.critic["params"]["Dense_0"]["kernel"], np.float64)
    new = np.asarray(got.agents.critic["params"]["Dense_0"]["kernel"], np.float64)
    assert tr.byzantine.tolist() == [False, False, False, True, True]
    # honest clients take the mean of what was sent: 3 honest models and 2 zero rows
    np.testing.assert_allclose(new[:3], np.broadcast_to(own[:3].sum(0) / 5, new[:3].shape), rtol=1e-5, atol=1e-6)
    np.testing.assert_array_equal(new[3:], own[3:])  # Byzantine robots keep training their own
    assert int(stats["clients"]) == 5


def test_pw_byzantine_clients_inflate_their_reward(fed_states):
    tr, hp, st = fed_states(
        "fed.byzantine=1", "fed.attack=zeros", "fed.tau=1.0", base=ROOT / "configs" / "thesis" / "pwddpg.yaml"
    )
    got, _ = jax.jit(tr.federated_round)(st, hp)
    r = np.asarray(st.reward_sum / st.reward_steps, np.float64)
    r_sent = r.copy()
    r_sent[4] = abs(r[4]) * attacks.DEFAULT_REWARD_SCALE + attacks.DEFAULT_REWARD_SCALE
    w = np.exp(float(hp.fed.beta) * r_sent)
    w /= w.sum()
    own = np.asarray(st.agents.actor["params"]["Dense_0"]["kernel"], np.float64)
    sent = own.copy()
    sent[4] = 0.0
    want = np.tensordot(w, sent, axes=1)
    new = np.asarray(got.agents.actor["params"]["Dense_0"]["kernel"], np.float64)
    np.testing.assert_allclose(new[:4], np.broadcast_to(want, new[:4].shape), rtol=1e-5, atol=1e-6)


def test_scale_attack_uses_the_last_global_model(fed_states):
    tr, hp, st = fed_states("fed.byzantine=1", "fed.attack=scale", "fed.tau=1.0", "fed.attack_scale=-3.0")
    ref = agg.reference(st.agg_state)
    assert ref is not None  # soft FedAvg wrapped to keep its global model for the attack
    got, _ = jax.jit(tr.federated_round)(st, hp)
    own = np.asarray(st.agents.actor["params"]["Dense_0"]["kernel"], np.float64)
    g = np.asarray(ref["actor"]["params"]["Dense_0"]["kernel"], np.float64)
    sent = own.copy()
    sent[4] = g - 3.0 * (own[4] - g)
    new = np.asarray(got.agents.actor["params"]["Dense_0"]["kernel"], np.float64)
    np.testing.assert_allclose(new[0], sent.mean(0), rtol=1e-5, atol=1e-5)
    # the new global model is what the server sent back (theta_w), not the Byzantine robot's own
    np.testing.assert_allclose(
        np.asarray(agg.reference(got.agg_state)["actor"]["params"]["Dense_0"]["kernel"]),
        sent.mean(0),
        rtol=1e-5,
        atol=1e-5,
    )


# ----------------------------------------------------------------------------- one compilation, metrics


def test_a_sweep_over_participation_trim_and_attack_scale_compiles_once_and_reports_honest_clients(tmp_path):
    from fedjax_nav.config.sweepfile import load_sweep
    from fedjax_nav.experiments.sweeps import run_sweep
    from fedjax_nav.training import sweep as sw

    spec = {
        "name": "robust",
        "base": str(FLDDPG),
        "seeds": 1,
        "set": TINY + ["fed.aggregator=trimmed_mean", "fed.byzantine=1", "fed.attack=scale", "fed.min_clients=2"],
        "grid": {"fed.participation": [0.4, 1.0], "fed.trim": [0.2, 0.4], "fed.attack_scale": [-10.0, 2.0]},
    }
    path = tmp_path / "robust.yaml"
    path.write_text(yaml.safe_dump(spec, sort_keys=False))
    sweep = load_sweep(path)
    assert len(sweep.points) == 8 and len(sw.plan(sw.merge_jobs(sweep.points), budget=2**40)) == 1
    _, stats = run_sweep(sweep, tmp_path / "out", progress=False, echo=lambda s: None)
    assert [g["traces"] for g in stats["groups"]] == [1]
    per_client = None
    for p in sweep.points:
        folder = tmp_path / "out" / "points" / p.id
        df = pd.read_csv(folder / "metrics.csv")
        assert df.groupby("robot")["byzantine"].first().tolist() == [0, 0, 0, 0, 1]
        first = df[df.robot == 0]
        assert (first["fed_clients"] + 5 * first["fed_skipped"] <= 5 * first["fed_events"]).all()
        if p.cfg.fed.participation == 1.0:
            assert (first["fed_clients"] == 5 * first["fed_events"]).all() and first["fed_skipped"].sum() == 0
            per_client = (first["fed_bytes"] / first["fed_clients"]).iloc[0]
        summ = json.loads((folder / "summary.json").read_text())
        honest = df[(df.byzantine == 0) & (df.episode >= df.episode.max() + 1 - 25)]
        want = honest.groupby(["seed", "episode"])["reached_goal"].mean().groupby("seed").mean().mean()
        assert summ["success_last_honest"] == pytest.approx(want)
        assert summ["fed_bytes_sent"] == pytest.approx(first["fed_bytes"].sum())
    assert per_client and per_client > 0


# ----------------------------------------------------------------------------- config errors


@pytest.mark.parametrize(
    "sets, names",
    [
        (["fed.participation=1.5"], ["fed.participation"]),
        (["fed.trim=0.7"], ["fed.trim"]),
        (["fed.max_norm=-1"], ["fed.max_norm"]),
        (["fed.krum_m=0"], ["fed.krum_m"]),
        (["fed.aggregator=mode"], ["fed.aggregator"]),
        (["fed.attack=flood", "fed.byzantine=1"], ["fed.attack"]),
        (["fed.byzantine=5", "fed.attack=noise"], ["fed.byzantine"]),
        (["fed.byzantine=1"], ["fed.byzantine", "fed.attack"]),
        (["fed.aggregator=krum", "fed.krum_f=2"], ["fed.krum_f"]),
        (["fed.aggregator=krum", "fed.krum_m=5"], ["fed.krum_m"]),
        (["fed.min_clients=6"], ["fed.min_clients"]),
        (["method=iddpg", "fed.aggregator=median"], ["fed.aggregator"]),
        (["method=iddpg", "fed.participation=0.5"], ["fed.participation"]),
    ],
)
def test_bad_robust_federation_fields_exit_2_naming_them(sets, names, tmp_path, capsys):
    args = ["train", "--config", str(FLDDPG), "--out", str(tmp_path / "run"), "--quiet"]
    for s in sets:
        args += ["--set", s]
    assert cli.main(args) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and all(n in err for n in names), err
    assert not (tmp_path / "run").exists()


# ----------------------------------------------------------------------------- padding for devices

PAD_SCRIPT = """
import json, sys
import jax, jax.numpy as jnp, numpy as np
from fedjax_nav.config import load_config
from fedjax_nav.training import parallel
from fedjax_nav.training.hparams import hparams_from_config
from fedjax_nav.training.trainer import Trainer
cfg = load_config(sys.argv[1], json.loads(sys.argv[2]))
hp = hparams_from_config(cfg)
out = {}
for name, devices in [("one", 0), ("two", 2)]:
    mesh = parallel.make_mesh(devices) if devices else None
    tr = Trainer(cfg, pad=parallel.client_padding(mesh, cfg.num_robots))
    st = tr.init_seeds(jnp.arange(2), hp, mesh=mesh)
    chunk = tr.compiled_chunk(2, mesh=mesh, states=st, hp=hp) if mesh else tr.compiled_chunk(2)
    st, m = chunk(st, hp, jnp.int32(0))
    actor = tr.real_rows(jax.tree.map(lambda x: x[0], st.agents.actor))
    out[name] = {"pad": tr.pad, **{k: np.asarray(m[k]).tolist() for k in ("reward", "goals", "critic_loss",
                                                                         "fed_clients")},
                 "kernel": np.asarray(actor["params"]["Dense_0"]["kernel"]).tolist()}
print(json.dumps(out))
"""


def _compare_runs(a, b):
    for k in ("goals", "fed_clients"):
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)
    for k in ("reward", "critic_loss", "kernel"):
        np.testing.assert_allclose(a[k], b[k], rtol=1e-5, atol=1e-6, err_msg=k)


def test_padded_clients_are_permanently_masked_and_change_nothing(tmp_path):
    """5 robots as 6 clients (one masked) on 1 device equal the 5-robot run to float32 round-off;
    on 2 forced CPU devices (a subprocess) the padded run shards the clients 3 + 3 and equals
    the 1-device unpadded run too."""
    import os
    import subprocess
    import sys

    sets = TINY + ["fed.tau=1.0"]
    cfg, hp = tiny("fed.tau=1.0"), hparams_from_config(tiny("fed.tau=1.0"))
    runs = {}
    for pad in (0, 1):
        tr = Trainer(cfg, pad=pad)
        st = tr.init_seeds(jnp.arange(2), hp)
        st, m = tr.compiled_chunk(2)(st, hp, jnp.int32(0))
        assert st.agents.actor["params"]["Dense_0"]["kernel"].shape[1] == 5 + pad and m["reward"].shape == (2, 2, 5)
        runs[pad] = {
            **{k: np.asarray(m[k]) for k in ("reward", "goals", "critic_loss", "fed_clients")},
            "kernel": np.asarray(
                tr.real_rows(jax.tree.map(lambda x: x[0], st.agents.actor))["params"]["Dense_0"]["kernel"]
            ),
        }
        assert np.all(runs[pad]["fed_clients"] == 5)  # the padding client never takes part
    _compare_runs(runs[1], runs[0])
    env = {**os.environ, "XLA_FLAGS": "--xla_force_host_platform_device_count=2", "JAX_PLATFORMS": "cpu"}
    r = subprocess.run(
        [sys.executable, "-c", PAD_SCRIPT, str(FLDDPG), json.dumps(sets)],
        env=env,
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert r.returncode == 0, r.stderr[-3000:]
    got = json.loads(r.stdout.strip().splitlines()[-1])
    assert got["one"]["pad"] == 0 and got["two"]["pad"] == 1
    _compare_runs(got["one"], {k: v.tolist() for k, v in runs[0].items()})
    _compare_runs(got["two"], got["one"])
