"""`fedjax-nav export` of the learners beside DDPG (deploy/export.py's actor_kind): SAC's and
feed-forward PPO's squashed mean, recurrent PPO's GRU with its hidden state, each PPO kind also
with its observation normaliser (ppo.normalize_obs), in numpy (policy.py's `Policy`) and ONNX,
against the learner's own `greedy` (agents.learners).

Each run directory is written directly (config.yaml + params.npz of the learner's initial actor
with every leaf perturbed (`_perturb`), so that biases are non-zero and the small policy head does not hide
the trunk; a normaliser's statistics are those of a few hundred observations, other ones per robot),
so nothing is trained here; tests/test_learner_runs.py exports trained runs.
"""

import importlib.util
import json
import os

os.environ.setdefault("JAX_PLATFORMS", "cpu")

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from fedjax_nav.agents import learners, normalize, ppo  # noqa: E402
from fedjax_nav.config import from_dict, save_config, values  # noqa: E402
from fedjax_nav.deploy import export as ex  # noqa: E402
from fedjax_nav.evaluation import load_run  # noqa: E402
from fedjax_nav.training.hparams import hparams_from_config  # noqa: E402

TOL = 1e-5
N_OBS = 1024
NUM_BEAMS = 24
SEQ, RESET_AT, N_SEQ = 10, 5, 64  # recurrent: N_SEQ sequences of SEQ steps, a reset before step RESET_AT

CASES = {
    "sac": {"learner": "sac", "offpolicy": {"hidden": 16, "depth": 2, "activation": "relu"}},
    "ppo": {"learner": "ppo", "ppo": {"hidden": 16, "depth": 2, "activation": "tanh"}},
    "ppo-elu": {"learner": "ppo", "ppo": {"hidden": 16, "depth": 3, "activation": "elu"}},
    "ppo-gru": {
        "learner": "ppo",
        "ppo": {"hidden": 16, "depth": 2, "activation": "tanh", "recurrent": "gru", "gru_hidden": 8, "minibatches": 1},
    },
    "ppo-norm": {"learner": "ppo", "ppo": {"hidden": 16, "depth": 2, "activation": "tanh", "normalize_obs": True}},
    "ppo-gru-norm": {
        "learner": "ppo",
        "ppo": {"hidden": 16, "depth": 2, "recurrent": "gru", "gru_hidden": 8, "minibatches": 1, "normalize_obs": True},
    },
}


def _load(path):
    spec = importlib.util.spec_from_file_location(f"policy_{abs(hash(str(path)))}", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _obs(n, seed=0):
    """Plausible observations and wide Gaussian ones (saturating the squash), half each."""
    rng = np.random.default_rng(seed)
    h = n // 2
    plausible = np.concatenate(
        [rng.uniform(0, 3.5, (h, NUM_BEAMS)), rng.uniform(0, 12, (h, 1)), rng.uniform(-np.pi, np.pi, (h, 1))]
        + [rng.uniform(0, 1, (h, 1)), rng.uniform(-1, 1, (h, 1))],
        axis=1,
    )
    return np.concatenate([plausible, rng.normal(0, 4, (n - h, NUM_BEAMS + 4))]).astype(np.float32)


def _perturb(x, key):
    """Biases + N(0, 0.3^2); kernels + N(0, 1 / fan_in) (the small policy head included)."""
    scale = 0.3 if x.ndim == 1 else 1.0 / np.sqrt(x.shape[0])
    return x + scale * jax.random.normal(key, x.shape)


@pytest.fixture(scope="module", params=list(CASES))
def case(request, tmp_path_factory):
    """(name, run dir, cfg, the learner, its nets, the exported agent's actor params)."""
    root = tmp_path_factory.mktemp("exportrun") / request.param
    root.mkdir()
    cfg = from_dict(
        {"method": "iddpg", "env": {"worlds": ["train-0", "train-2"], "num_beams": NUM_BEAMS}, **CASES[request.param]}
    )
    save_config(cfg, root / "config.yaml")
    learner = learners.get(cfg.learner)
    nets = learner.make_nets(values(cfg))
    hp = hparams_from_config(cfg)
    per = []
    for i, k in enumerate(jax.random.split(jax.random.key(11), 2)):  # 1 seed x 2 robots
        actor = learner.policy(learner.init(nets, k, NUM_BEAMS + 4, hp))
        weights = ppo.weights(actor) if cfg.learner == "ppo" else actor
        leaves, tree = jax.tree.flatten(weights)
        ks = jax.random.split(jax.random.fold_in(k, 1), len(leaves))
        weights = jax.tree.unflatten(tree, [_perturb(x, kk) for x, kk in zip(leaves, ks)])
        if ppo.NORM in actor:  # the statistics of some observations, other ones per robot
            stats = normalize.update(normalize.init(NUM_BEAMS + 4), jnp.asarray(_obs(300, seed=20 + i)))
            weights = {**weights, ppo.NORM: normalize.moments(stats)}
        per.append(weights)
    stacked = jax.tree.map(lambda *xs: np.stack(xs)[None], *per)
    flat = {
        "actor/" + "/".join(str(getattr(k, "key", k)) for k in kp): np.asarray(leaf)
        for kp, leaf in jax.tree_util.tree_flatten_with_path(stacked)[0]
    }
    np.savez(root / "params.npz", **flat)
    run = load_run(root)
    return request.param, root, cfg, learner, nets, jax.tree.map(lambda x: x[1], run.actor_params)


def _greedy_sequences(learner, nets, actor, obs, first):
    """The learner's greedy actions f32[N, T, 2] along N sequences obs [N, T, obs] (first [T])."""

    def one(seq):
        def step(memory, x):
            o, f = x
            action, memory = learner.greedy(nets, actor, o, memory, f)
            return memory, action

        return jax.lax.scan(step, learner.memory(nets), (seq, jnp.asarray(first)))[1]

    return np.asarray(jax.jit(jax.vmap(one))(jnp.asarray(obs)))


def _sequences():
    obs = _obs(N_SEQ * SEQ, seed=3).reshape(N_SEQ, SEQ, NUM_BEAMS + 4)
    return obs, np.arange(SEQ) % RESET_AT == 0  # first at step 0 and at RESET_AT


def test_numpy_export_acts_as_greedy(case, tmp_path):
    name, root, cfg, learner, nets, actor = case
    ex.export_run(root, tmp_path / "np", "numpy", agent=1)
    meta = json.loads((tmp_path / "np" / "meta.json").read_text())
    assert meta["learner"] == cfg.learner and meta["network"]["kind"] == ex.actor_kind(cfg)
    policy = _load(tmp_path / "np" / "policy.py").Policy(str(tmp_path / "np"))
    obs, first = _sequences()
    want = _greedy_sequences(learner, nets, actor, obs, first)  # [N, T, 2]
    got = []
    for t in range(SEQ):  # one batched Policy: N robots stepping together
        if first[t]:
            policy.reset()
        got.append(policy(obs[:, t]))
    got = np.stack(got, 1)
    diff = float(np.abs(got - want).max())
    print(f"\n{name}: numpy export vs greedy, {N_SEQ} x {SEQ} steps: max |diff| = {diff:.3g}")
    assert got.dtype == np.float32 and diff <= TOL
    assert ("obs_norm/mean" in np.load(tmp_path / "np" / "weights.npz")) == ("observation_normalization" in meta)
    assert ("observation_normalization" in meta) == (cfg.learner == "ppo" and cfg.ppo.normalize_obs)
    if meta["network"]["kind"] == "gru":
        assert meta["network"]["gru"] == cfg.ppo.gru_hidden and "memory" in meta
        # the state is what carries: a policy reset at every step acts otherwise
        forgetful = []
        for t in range(SEQ):
            policy.reset()
            forgetful.append(policy(obs[:, t]))
        assert np.abs(np.stack(forgetful, 1) - want).max() > 1e-2
    else:  # memoryless: many observations at once, and one alone
        flat = _obs(N_OBS)
        ref = np.asarray(jax.vmap(lambda o: learner.greedy(nets, actor, o, learner.memory(nets), None)[0])(flat))
        assert np.abs(policy(flat) - ref).max() <= TOL
        assert np.allclose(policy(flat[0]), ref[0], atol=TOL)


def test_onnx_export_acts_as_greedy(case, tmp_path):
    pytest.importorskip("onnx")
    ort = pytest.importorskip("onnxruntime")
    name, root, cfg, learner, nets, actor = case
    ex.export_run(root, tmp_path / "ox", "onnx", agent=1)
    meta = json.loads((tmp_path / "ox" / "meta.json").read_text())
    sess = ort.InferenceSession(str(tmp_path / "ox" / "policy.onnx"))
    obs, first = _sequences()
    want = _greedy_sequences(learner, nets, actor, obs, first)
    recurrent = meta["network"]["kind"] == "gru"
    assert [i.name for i in sess.get_inputs()] == (["obs", "h"] if recurrent else ["obs"])
    got, h = [], None
    for t in range(SEQ):
        feed = {"obs": obs[:, t]}
        if recurrent:
            h = np.zeros((N_SEQ, meta["network"]["gru"]), np.float32) if first[t] else h
            action, h = sess.run(["action", "h_out"], {**feed, "h": h})
        else:
            (action,) = sess.run(["action"], feed)
        got.append(action)
    diff = float(np.abs(np.stack(got, 1) - want).max())
    print(f"\n{name}: ONNX export vs greedy, {N_SEQ} x {SEQ} steps: max |diff| = {diff:.3g}")
    assert diff <= TOL


def test_every_learner_has_an_export():
    from fedjax_nav.config import from_dict
    from fedjax_nav.learner_table import LEARNERS

    for name in LEARNERS:
        assert ex.actor_kind(from_dict({"learner": name, "method": "iddpg"})) in ex.WEIGHTS
