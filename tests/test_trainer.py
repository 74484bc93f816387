"""The scanned trainer: every shipped config trains, the methods' structure (SEDDPG's one buffer,
SNDDPG's one network), federated steps at the right period and with the right weights,
determinism over seeds, one trace across chunks, and the CLI end to end.

Compiling one trainer takes 10-30 s on a small CPU, so every compiled chunk is built once per
module (the `run_*` caches below) and every test that can reads the same runs:
- `fl`: configs/thesis/flddpg.yaml, 2 seeds, 4 episodes of 16 steps, E_update = 2, compiled once
  with a trace counter; re-run from scratch for the determinism test, and seed 1 alone;
- one episode of each other thesis config (GSDDPG with a step period T_update = 6 over 2 episodes);
- configs/paper/flddpg.yaml through `fedjax-nav train` in the CLI test.
"""

from functools import partial
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest
import yaml

from fedjax_nav import cli
from fedjax_nav.agents import ddpg
from fedjax_nav.config import load_config
from fedjax_nav.federated import aggregators as agg
from fedjax_nav.training import federation
from fedjax_nav.training.hparams import hparams_from_config
from fedjax_nav.training.trainer import Trainer

ROOT = Path(__file__).resolve().parents[1]
THESIS = ROOT / "configs" / "thesis"
PAPER = ROOT / "configs" / "paper" / "flddpg.yaml"
T = 16
ROBOTS = 5
# Small settings for every shipped config (the paper's 512-wide nets included).
TINY = [
    f"env.episode_length={T}",
    "run.chunk_episodes=1",
    "offpolicy.batch_size=8",
    "offpolicy.buffer_size=64",
    "offpolicy.hidden=16",
    "run.checkpoint_every=0",
]
# Per config: extra overrides and the number of episodes (one, with a federated step in it).
EXTRA = {
    "iddpg": ([], 1),
    "seddpg": (["offpolicy.buffer_size=128"], 1),  # T * robots = 80 rows fit without wrapping
    "snddpg": (["offpolicy.buffer_size=128"], 1),
    "pwddpg": (["fed.period=1"], 1),
    "rwddpg": (["fed.period=1"], 1),
    "flsddpg": (["fed.period=1"], 1),
    "gsddpg": (["fed.period_unit=steps", "fed.period=6"], 2),  # T_update not dividing T
    "flddpg": (["fed.period=2"], 4),
}
METRIC_KEYS = {"reward", "goals", "collisions", "critic_loss", "actor_loss", "q", "fed_events", "epsilon"}


def tree_equal(a, b) -> bool:
    la, lb = jax.tree.leaves(a), jax.tree.leaves(b)
    return len(la) == len(lb) and all(np.array_equal(np.asarray(x), np.asarray(y)) for x, y in zip(la, lb))


def stack_metrics(ms: list[dict]) -> dict:
    """Per-chunk metrics (leaves [seeds, 1, ...]) -> leaves [seeds, episodes, ...] (numpy)."""
    return {k: np.concatenate([np.asarray(m[k]) for m in ms], axis=1) for k in ms[0]}


def train_episodes(trainer, chunk, hp, seeds, episodes):
    """Fresh states for `seeds`, then `episodes` calls of the one-episode compiled chunk."""
    states = trainer.init_seeds(jnp.asarray(seeds), hp)
    ms = []
    for e in range(episodes):
        states, m = chunk(states, hp, jnp.int32(e))
        ms.append(m)
    return states, stack_metrics(ms)


class Run:
    """A trained config: cfg, trainer, hp, compiled chunk, final states, metrics [S, E, ...]."""

    def __init__(self, cfg, seeds, count_traces=False):
        self.cfg, self.seeds = cfg, seeds
        self.trainer = Trainer(cfg)
        self.hp = hparams_from_config(cfg)
        self.traces = []
        # Count the traces of the real `compiled_chunk` (its `on_trace` hook runs at each trace).
        on_trace = (lambda: self.traces.append(1)) if count_traces else None
        self.chunk = self.trainer.compiled_chunk(on_trace=on_trace)
        self.states, self.metrics = train_episodes(self.trainer, self.chunk, self.hp, seeds, cfg.run.episodes)


_RUNS: dict = {}


def run_thesis(name: str) -> Run:
    """One run per thesis config, built on first use and shared by every test of this module."""
    if name not in _RUNS:
        extra, episodes = EXTRA[name]
        seeds = [0, 1] if name == "flddpg" else [0]
        cfg = load_config(
            THESIS / f"{name}.yaml", TINY + extra + [f"run.episodes={episodes}", f"run.seeds={len(seeds)}"]
        )
        _RUNS[name] = Run(cfg, seeds, count_traces=(name == "flddpg"))
    return _RUNS[name]


def seed_slice(states, s):
    return jax.tree.map(lambda x: x[s], states)


# ----------------------------------------------------------------------------- every config


@pytest.mark.parametrize("name", sorted(EXTRA))
def test_every_thesis_config_trains_with_finite_metrics(name):
    r = run_thesis(name)
    m, tr = r.metrics, r.trainer
    S, E = len(r.seeds), r.cfg.run.episodes
    assert METRIC_KEYS <= set(m), set(m)
    assert m["params_finite"].shape == (S, E, tr.n_nets) and m["params_finite"].all()
    assert m["reward"].shape == (S, E, ROBOTS) and m["goals"].shape == (S, E, ROBOTS)
    assert m["critic_loss"].shape == (S, E, tr.n_nets) and m["epsilon"].shape == (S, E)
    for k, v in m.items():
        assert np.all(np.isfinite(v)), k
    # 16 steps, T_train = 5, batch 8: updates happen in every episode and move the losses
    assert np.all(m["critic_loss"] > 0)
    # epsilon decays once per step: epsilon_start * decay^(T * episodes so far)
    d = r.cfg.ddpg
    expect = d.epsilon_start * d.epsilon_decay ** (T * np.arange(1, E + 1))
    np.testing.assert_allclose(m["epsilon"], np.broadcast_to(expect, (S, E)), rtol=1e-5)
    # per step: progress at most 40 * v_max * dt, plus the goal reward or the collision penalty
    e = r.cfg.env
    progress = e.progress_scale * e.v_max * e.dt
    assert np.all(m["reward"] <= e.reward_goal + progress + 1e-4)
    assert np.all(m["reward"] >= e.reward_collision - progress - 1e-4)
    assert np.all(m["goals"] >= 0) and np.all(m["collisions"] >= 0) and np.all(m["goals"] + m["collisions"] <= T)
    for leaf in jax.tree.leaves(r.states.agents):
        assert np.all(np.isfinite(np.asarray(leaf)))


def test_every_method_has_its_structure():
    expect = {  # n_nets, n_bufs
        "iddpg": (5, 5),
        "seddpg": (5, 1),
        "snddpg": (1, 1),
        "flddpg": (5, 5),
        "pwddpg": (5, 5),
        "rwddpg": (5, 5),
        "gsddpg": (5, 5),
        "flsddpg": (5, 5),
    }
    for name, (nets, bufs) in expect.items():
        cfg = load_config(THESIS / f"{name}.yaml", TINY)
        tr = Trainer(cfg)
        assert (tr.n_nets, tr.n_bufs) == (nets, bufs), name
        assert bool(np.all(np.asarray(tr.env_params(hparams_from_config(cfg)).random_starts))) == (name == "flsddpg"), (
            name
        )


# ----------------------------------------------------------------------------- SEDDPG / SNDDPG


@pytest.mark.parametrize("name", ["seddpg", "snddpg"])
def test_shared_buffer_holds_every_robots_transitions(name):
    r = run_thesis(name)
    buf = r.states.buffers  # leaves [seed, buffer, row, ...]
    assert r.trainer.n_bufs == 1 and buf.obs.shape == (1, 1, 128, r.trainer.obs_size)
    obs, nxt = np.asarray(buf.obs[0, 0]), np.asarray(buf.next_obs[0, 0])
    filled = T * ROBOTS
    assert np.all(np.abs(obs[:filled]).sum(1) > 0)  # every robot's every step is in
    assert np.all(obs[filled:] == 0) and np.all(np.asarray(buf.reward[0, 0, filled:]) == 0)
    # rows are written step by step, robot by robot: row g * 5 + k is robot k at step g, so its
    # next_obs is the obs of row (g + 1) * 5 + k, except on a terminal step, whose next_obs is the
    # true observation where the robot ended (the next row starts from a start pose)
    done = np.asarray(buf.done[0, 0, : filled - ROBOTS]) > 0
    np.testing.assert_array_equal(nxt[: filled - ROBOTS][~done], obs[ROBOTS:filled][~done])
    # the robots are in different rooms: their rows differ
    assert len({obs[k].tobytes() for k in range(ROBOTS)}) == ROBOTS
    # SEDDPG keeps 5 independent networks, SNDDPG one
    n_nets = 5 if name == "seddpg" else 1
    assert jax.tree.leaves(r.states.agents.actor)[0].shape[:2] == (1, n_nets)


def test_snddpg_acts_with_one_network_for_every_robot():
    r = run_thesis("snddpg")
    tr = r.trainer
    assert tr.n_nets == 1
    state = seed_slice(r.states, 0).replace(explore=jnp.float32(0.0))
    actions = np.asarray(jax.jit(tr._act)(state, jax.random.key(3)))
    actor = jax.tree.map(lambda p: p[0], state.agents.actor)
    for k in range(ROBOTS):
        ref = np.asarray(ddpg.act(tr.nets, actor, state.obs[k]))
        np.testing.assert_allclose(actions[k], ref, rtol=1e-5, atol=1e-6)
    assert len({a.tobytes() for a in actions}) == ROBOTS  # different observations, different actions


def test_independent_networks_act_each_for_their_robot():
    r = run_thesis("iddpg")
    tr = r.trainer
    state = seed_slice(r.states, 0).replace(explore=jnp.float32(0.0))
    actions = np.asarray(jax.jit(tr._act)(state, jax.random.key(3)))
    for k in range(ROBOTS):
        own = jax.tree.map(lambda p, k=k: p[k], state.agents.actor)
        other = jax.tree.map(lambda p, k=k: p[(k + 1) % ROBOTS], state.agents.actor)
        np.testing.assert_allclose(actions[k], np.asarray(ddpg.act(tr.nets, own, state.obs[k])), rtol=1e-5, atol=1e-6)
        assert not np.allclose(actions[k], np.asarray(ddpg.act(tr.nets, other, state.obs[k])), atol=1e-6)


# ----------------------------------------------------------------------------- federated period


def test_aggregation_events_every_E_update_episodes():
    r = run_thesis("flddpg")  # 4 episodes, E_update = 2: after episodes 2 and 4
    np.testing.assert_array_equal(r.metrics["fed_events"], [[0, 1, 0, 1], [0, 1, 0, 1]])
    assert r.metrics["fed_events"].sum(1).tolist() == [2, 2]


@pytest.mark.parametrize("name", ["pwddpg", "rwddpg", "flsddpg", "iddpg", "seddpg", "snddpg"])
def test_aggregation_events_with_period_one_and_none_without_aggregator(name):
    r = run_thesis(name)
    expect = 0 if r.trainer.method.aggregator == "none" else 1
    np.testing.assert_array_equal(r.metrics["fed_events"], [[expect]])


def test_aggregation_events_every_T_update_steps_and_gs_makes_clients_equal():
    r = run_thesis("gsddpg")  # T_update = 6, T = 16: global steps 6, 12 | 18, 24, 30
    np.testing.assert_array_equal(r.metrics["fed_events"], [[2, 3]])
    # the last federated step (global step 30) was after the last gradient step (step 30; the next
    # would be 35): every client holds the global model, which is the carried theta_w
    st = seed_slice(r.states, 0)
    for name in ("actor", "critic"):
        for leaf, w in zip(jax.tree.leaves(getattr(st.agents, name)), jax.tree.leaves(st.agg_state.theta_w[name])):
            leaf = np.asarray(leaf)
            for k in range(ROBOTS):
                np.testing.assert_array_equal(leaf[k], np.asarray(w))


# ----------------------------------------------------------------------------- federated step


def _fed_state(reward_sum):
    """One seed's TrainState after the `fl` run (clients differ), with given rewards since the last
    federated step over 20 steps."""
    st = seed_slice(run_thesis("flddpg").states, 0)
    return st.replace(reward_sum=jnp.asarray(reward_sum, jnp.float32), reward_steps=jnp.float32(20))


REWARD_SUM = [10.0, -20.0, 5.0, 0.0, 40.0]  # r = [0.5, -1, 0.25, 0, 2] per step


def _np_mix(tree, w, tau):
    out = []
    for p in jax.tree.leaves(tree):
        p = np.asarray(p, np.float64)
        out.append((1 - tau) * p + tau * np.tensordot(w, p, axes=1)[None])
    return out


@pytest.mark.parametrize("name", ["flddpg", "pwddpg", "rwddpg"])
def test_federated_step_mixes_nets_with_the_method_weights_and_keeps_the_rest_local(name):
    cfg = load_config(THESIS / f"{name}.yaml", TINY + ["fed.tau=0.5", "fed.beta=0.5"])
    tr = Trainer(cfg)
    st = _fed_state(REWARD_SUM)
    out = federation.federated_round(tr.round, st, hparams_from_config(cfg))[0]
    r = np.array(REWARD_SUM) / 20
    w = {
        "flddpg": np.full(ROBOTS, 0.2),
        "pwddpg": np.exp(0.5 * r) / np.exp(0.5 * r).sum(),
        "rwddpg": np.sign(r) * np.abs(r) ** 0.5 / (np.abs(r) ** 0.5).sum(),
    }[name]
    for net in ("actor", "critic"):
        for got, ref in zip(jax.tree.leaves(getattr(out.agents, net)), _np_mix(getattr(st.agents, net), w, 0.5)):
            np.testing.assert_allclose(np.asarray(got), ref, rtol=1e-5, atol=1e-6)
    # targets and optimiser states stay local (fed.include_targets = false)
    local = lambda a: (a.actor_targ, a.critic_targ, a.actor_opt, a.critic_opt)  # noqa: E731
    assert tree_equal(local(out.agents), local(st.agents))
    assert float(out.reward_steps) == 0.0 and np.all(np.asarray(out.reward_sum) == 0.0)


def test_federated_step_include_targets_averages_the_targets_too():
    cfg = load_config(THESIS / "flddpg.yaml", TINY + ["fed.tau=1.0", "fed.include_targets=true"])
    tr = Trainer(cfg)
    st = _fed_state(REWARD_SUM)
    out = federation.federated_round(tr.round, st, hparams_from_config(cfg))[0]
    for name in ("actor", "critic", "actor_targ", "critic_targ"):
        for got, ref in zip(
            jax.tree.leaves(getattr(out.agents, name)), _np_mix(getattr(st.agents, name), np.full(ROBOTS, 0.2), 1.0)
        ):
            np.testing.assert_allclose(np.asarray(got), ref, rtol=1e-5, atol=1e-6)
    assert tree_equal((out.agents.actor_opt, out.agents.critic_opt), (st.agents.actor_opt, st.agents.critic_opt))


@pytest.mark.parametrize("include_targets", [False, True])
def test_gs_federated_step_moves_the_global_model_and_every_client_to_it(include_targets):
    cfg = load_config(
        THESIS / "gsddpg.yaml", TINY + ["fed.beta=0.5", f"fed.include_targets={str(include_targets).lower()}"]
    )
    tr = Trainer(cfg)
    st = _fed_state(REWARD_SUM)
    nets = {"actor": st.agents.actor, "critic": st.agents.critic}
    prev = agg.GlobalState(jax.tree.map(lambda x: x.mean(0) + 1.0, nets))  # a global model != the clients' mean
    st = st.replace(agg_state=prev)
    out = federation.federated_round(tr.round, st, hparams_from_config(cfg))[0]
    ref = [
        0.5 * np.asarray(p, np.float64) + 0.5 * np.asarray(c, np.float64).mean(0)
        for p, c in zip(jax.tree.leaves(prev), jax.tree.leaves(nets))
    ]
    for got, want in zip(jax.tree.leaves(out.agg_state), ref):
        np.testing.assert_allclose(np.asarray(got), want, rtol=1e-5, atol=1e-6)
    clients = {"actor": out.agents.actor, "critic": out.agents.critic}
    for got, want in zip(jax.tree.leaves(clients), ref):
        np.testing.assert_allclose(np.asarray(got), np.broadcast_to(want, got.shape), rtol=1e-5, atol=1e-6)
    targets = {"actor": out.agents.actor_targ, "critic": out.agents.critic_targ}
    if include_targets:  # the targets follow the same global model
        for got, want in zip(jax.tree.leaves(targets), ref):
            np.testing.assert_allclose(np.asarray(got), np.broadcast_to(want, got.shape), rtol=1e-5, atol=1e-6)
    else:
        assert tree_equal(targets, {"actor": st.agents.actor_targ, "critic": st.agents.critic_targ})


def test_gs_global_model_starts_as_the_mean_of_the_initial_params():
    r = run_thesis("gsddpg")
    st = seed_slice(r.trainer.init_seeds(jnp.asarray([0]), r.hp), 0)
    init = {"actor": st.agents.actor, "critic": st.agents.critic}
    for w, p in zip(jax.tree.leaves(st.agg_state), jax.tree.leaves(init)):
        np.testing.assert_allclose(np.asarray(w), np.asarray(p).mean(0), rtol=1e-6, atol=1e-7)
    # every robot's network has its own initialisation
    k = np.asarray(st.agents.actor["params"]["Dense_0"]["kernel"])
    assert len({k[i].tobytes() for i in range(ROBOTS)}) == ROBOTS


# ----------------------------------------------------------------------------- determinism, seeds


def test_same_seed_bitwise_same_metrics_and_params():
    r = run_thesis("flddpg")
    states, metrics = train_episodes(r.trainer, r.chunk, r.hp, r.seeds, r.cfg.run.episodes)
    for k in metrics:
        np.testing.assert_array_equal(metrics[k], r.metrics[k], err_msg=k)
    assert tree_equal(states.agents, r.states.agents) and tree_equal(states.buffers, r.states.buffers)


def test_different_seeds_differ():
    r = run_thesis("flddpg")
    m = r.metrics
    assert not np.array_equal(m["reward"][0], m["reward"][1])
    assert not np.array_equal(m["critic_loss"][0], m["critic_loss"][1])
    a0, a1 = (jax.tree.leaves(seed_slice(r.states.agents.actor, s))[0] for s in (0, 1))
    assert not np.array_equal(np.asarray(a0), np.asarray(a1))


def test_seed_in_a_batch_equals_the_seed_alone():
    """Seed 1 trained alone (its own compilation, batch of 1) == seed 1 in the batch [0, 1].

    Compared to 1e-5, not bitwise: XLA may order a reduction differently for a batch of 1 and
    of 2. When written (jax 0.10.2, CPU) the metrics were bitwise equal and only Adam's moments of
    the critic's output bias differed, by one ulp."""
    r = run_thesis("flddpg")
    # the same trainer, a separate jit (not the trace-counted one): a batch of 1 is a new shape
    chunk_alone = jax.jit(partial(Trainer.chunk, r.trainer, num_episodes=1), donate_argnums=0)
    states, m = train_episodes(r.trainer, chunk_alone, r.hp, [1], r.cfg.run.episodes)
    for k in m:
        np.testing.assert_allclose(m[k][0], r.metrics[k][1], rtol=1e-5, atol=1e-5, err_msg=k)
    for a, b in zip(jax.tree.leaves(seed_slice(states.agents, 0)), jax.tree.leaves(seed_slice(r.states.agents, 1))):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-5, atol=1e-5)
    # discrete outcomes (goals, collisions, aggregation events) are identical
    for k in ("goals", "collisions", "fed_events"):
        np.testing.assert_array_equal(m[k][0], r.metrics[k][1])


# ----------------------------------------------------------------------------- one trace


def test_one_trace_across_chunks():
    """The compiled chunk is traced once, whatever the first episode (it is a traced argument)."""
    r = run_thesis("flddpg")
    calls_before = len(r.traces)
    assert calls_before == 1
    states = r.trainer.init_seeds(jnp.asarray(r.seeds), r.hp)
    for first in (7, 100, 3):
        states, _ = r.chunk(states, r.hp, jnp.int32(first))
    assert len(r.traces) == 1
    # a numpy int32 is the same abstract value (a Python int is weakly typed: it would retrace)
    states, _ = r.chunk(states, r.hp, np.int32(5))
    assert len(r.traces) == 1


# ----------------------------------------------------------------------------- CLI end to end


def test_cli_train_end_to_end_on_the_paper_config(tmp_path, capsys):
    """configs/paper/flddpg.yaml (6 rooms, E_update = 1), shrunk, through `fedjax-nav train`."""
    data = yaml.safe_load(PAPER.read_text())
    data["env"]["episode_length"] = T
    data["offpolicy"].update(hidden=16, batch_size=8, buffer_size=64)
    data["run"].update(episodes=2, chunk_episodes=1, checkpoint_every=0)
    cfg_path = tmp_path / "tiny.yaml"
    cfg_path.write_text(yaml.safe_dump(data))
    out = tmp_path / "run"
    rc = cli.main(
        [
            "train",
            "--config",
            str(cfg_path),
            "--out",
            str(out),
            "--seeds",
            "2",
            "--quiet",
            "--set",
            "offpolicy.gamma=0.8",
        ]
    )
    assert rc == 0, capsys.readouterr().err
    for f in ("config.yaml", "metrics.csv", "summary.json", "params.npz", "learning_curves.png"):
        assert (out / f).is_file() and (out / f).stat().st_size > 0, f
    cfg = load_config(out / "config.yaml")
    assert cfg == load_config(cfg_path, ["run.seeds=2", "offpolicy.gamma=0.8"])  # resolved, with --set and --seeds

    df = pd.read_csv(out / "metrics.csv")
    for col in ("episode", "seed", "robot", "reward", "reached_goal", "goals", "collisions"):
        assert col in df.columns, col
    robots = 6
    assert len(df) == 2 * 2 * robots
    idx = set(zip(df.episode, df.seed, df.robot))
    assert idx == {(e, s, k) for e in range(2) for s in range(2) for k in range(robots)}
    assert np.all(np.isfinite(df[["reward", "goals", "collisions"]].to_numpy(float)))
    np.testing.assert_array_equal(df.reached_goal, (df.goals > 0).astype(int))
    # the two seeds learned differently
    by_seed = df.sort_values(["episode", "robot"]).groupby("seed")["reward"].apply(np.asarray)
    assert not np.array_equal(by_seed[0], by_seed[1])

    import json

    summary = json.loads((out / "summary.json").read_text())
    assert summary["method"] == "flddpg" and summary["seeds"] == 2
    assert summary["aggregation_events"] == 2  # E_update = 1, 2 episodes
    assert summary["communication"]["n_comm"] == 2.0
    assert 0.0 <= summary["success_last"] <= 1.0 and np.isfinite(summary["reward_last"])

    params = np.load(out / "params.npz")
    kernels = [k for k in params.files if k.startswith("actor/") and k.endswith("kernel")]
    assert kernels and all(params[k].shape[:2] == (2, robots) for k in kernels)
    assert any(k.startswith("critic/") for k in params.files)
    assert (out / "learning_curves.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_a_new_episode_metric_is_one_line_in_the_table(monkeypatch):
    """The step metrics are summed over the episode in the step scan; EPISODE_METRICS turns the
    sums into episode values. A metric added there (and nowhere else) comes out of the chunk."""
    from fedjax_nav.training.step_metrics import EPISODE_METRICS  # the table's one declaration

    monkeypatch.setitem(EPISODE_METRICS, "goal_rate", lambda m, T: m.goals / T)
    monkeypatch.setitem(EPISODE_METRICS, "steps", lambda m, T: jnp.int32(T))
    cfg = load_config(THESIS / "iddpg.yaml", TINY)
    tr, hp = Trainer(cfg), hparams_from_config(cfg)
    states = tr.init_seeds(jnp.arange(1), hp)
    _, m = jax.jit(lambda s, h: tr.chunk(s, h, jnp.int32(0), 1))(states, hp)
    assert np.all(np.asarray(m["steps"]) == T)
    np.testing.assert_allclose(np.asarray(m["goal_rate"]) * T, np.asarray(m["goals"]))


@pytest.mark.parametrize("name", sorted(EXTRA))
def test_every_thesis_run_is_bitwise_what_it_was_before_the_refactorings(name):
    """This module's run of each thesis config, hashed (metrics, final networks and buffers),
    equals the hash recorded from the code before the aggregators, the env builder and the
    learner table were refactored (`scripts/trainer_fingerprints.py`; same jax/XLA versions and
    CPU kind, else skipped and said)."""
    import json

    from test_programme_fingerprint import digest, skip_unless_recorded

    data = json.loads((Path(__file__).parent / "data" / "trainer_run_fingerprints.json").read_text())
    rec = skip_unless_recorded(data, "trainer_run_fingerprints.json")
    r = run_thesis(name)
    assert digest(r.metrics, r.states) == rec["cases"][name], f"{name}: the programme's numbers changed"
