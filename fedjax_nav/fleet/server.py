"""The fleet's server (docs/fleet.md): the round's exchange (`training.federation.exchange`, the
in-program round's own function, with the run's aggregator and hyperparameters) over what the
robots sent, and the run directory a normal run leaves (config.yaml, metrics.csv, summary.json,
params.npz: `fedjax-nav evaluate` reads it), written after every round with the server's round
state (fleet_state.npz), so that a server killed at any moment resumes where it stopped."""

from __future__ import annotations

import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd

from fedjax_nav import rundir
from fedjax_nav.config import Config
from fedjax_nav.federated.aggregators import TARGET_SUFFIX
from fedjax_nav.fleet import wire
from fedjax_nav.fleet.robot import FleetError, check
from fedjax_nav.training import federation
from fedjax_nav.training.hparams import hparams_from_config
from fedjax_nav.training.metrics import metrics_frame, summarize
from fedjax_nav.training.trainer import Trainer


def _rows(flat: dict[str, np.ndarray], n: int) -> list[dict[str, np.ndarray]]:
    return [{k: v[i : i + 1] for k, v in flat.items()} for i in range(n)]


class Server:
    """The server of the run `cfg` (one seed): the aggregator's state between rounds, what each
    robot holds after its last exchange (`held`, the answer it gets), the metrics. With `out`
    holding a fleet state of the same config, the server resumes from it."""

    def __init__(self, cfg: Config, out: str | Path | None = None):
        check(cfg)
        self.cfg, self.trainer, self.hp = cfg, Trainer(cfg), hparams_from_config(cfg)
        self.n = self.trainer.num_robots
        key = jax.random.key(cfg.run.seed)  # the aggregator starts from the robots' initial agents, as in the program
        agents = jax.jit(self.trainer.init_agents)(key, self.hp)
        self.agg_state = jax.jit(self.trainer.init_agg_state)(agents, self.hp)
        self._exchange = jax.jit(
            lambda own, r, k, s, a: federation.exchange(self.trainer.round, self.hp, own, r, k, s, a)
        )
        self.template = jax.eval_shape(self.trainer.shared, agents)
        self._key_shape = jax.random.key_data(key).shape
        # what each robot holds: the initial agents until it takes part in an exchange ("shared…" form)
        self.held = _rows(wire.shared_arrays(self.trainer.shared(agents)), self.n)
        self.sent = [dict(h, reward=np.zeros(1, np.float32)) for h in self.held]  # each robot's last send
        self.key: np.ndarray | None = None  # the run's key at the last round (key data)
        self.done, self.metrics, self.stats = 0, [], {}
        self.rounds_log: list[dict] = []  # one row per round (FleetStrategy): clients, wall time, bytes
        if out is not None and (Path(out) / rundir.FLEET_STATE).exists():
            self._load(Path(out))

    def answer(self, robot: int) -> dict[str, np.ndarray] | None:
        """What robot `robot` takes before its next round: the model the server holds for it and
        the run's key (a robot that missed rounds takes both); None before the first round."""
        return None if self.key is None else self.held[robot] | {"key": self.key}

    def refusal(self, send: dict[str, np.ndarray]) -> str | None:
        """Why a robot's send cannot enter the round (one line), or None: every shared field of
        the run's shape and dtype and finite, a finite reward, a run key."""
        want = self.held[0] | {"reward": self.sent[0]["reward"], "key": np.zeros(self._key_shape, np.uint32)}
        for name, ref in want.items():
            x = send.get(name)
            if x is None:
                return f"no array {name!r}"
            if x.shape != ref.shape or x.dtype != ref.dtype:
                return f"{name}: {x.dtype}{list(x.shape)}, the run's is {ref.dtype}{list(ref.shape)}"
            if x.dtype.kind == "f" and not np.isfinite(x).all():
                return f"{name}: not finite"
        return None

    def aggregate(self, sends: dict[int, dict[str, np.ndarray]]) -> dict[int, str]:
        """One round over the robots that answered ({robot: its `Robot.sent`}): the others, and
        those whose send is refused (`refusal`, or a run key other than most robots'), are absent
        clients (`exchange`'s `answered`); their last good send stands in for them. Returns the
        refused robots: {robot: why}."""
        refused = {i: why for i, s in sends.items() if (why := self.refusal(s)) is not None}
        sends = {i: s for i, s in sends.items() if i not in refused}
        if sends:
            keys, counts = np.unique(np.stack([s["key"] for s in sends.values()]), axis=0, return_counts=True)
            run_key = keys[np.argmax(counts)]
            refused |= {
                i: "run key: not the fleet's (not this run)" for i, s in sends.items() if (s["key"] != run_key).any()
            }
            sends = {i: s for i, s in sends.items() if i not in refused}
        if not sends:
            raise FleetError(f"round {self.done + 1}: no robot's send could be used ({refused or 'none answered'})")
        keys = np.stack([s["key"] for s in sends.values()])
        for i, s in sends.items():
            self.sent[i] = {k: v for k, v in s.items() if k != "key"}
        own = wire.shared_fields({k: np.concatenate([s[k] for s in self.sent]) for k in self.held[0]})
        r = np.concatenate([s["reward"] for s in self.sent])
        answered = np.array([i in sends for i in range(self.n)])
        new, self.agg_state, stats = self._exchange(
            wire.unpack(self.template, own),
            jnp.asarray(r),
            jax.random.wrap_key_data(keys[0]),
            self.agg_state,
            jnp.asarray(answered),
        )
        rows = _rows(wire.shared_arrays(new), self.n)
        self.held = [rows[i] if answered[i] else self.held[i] for i in range(self.n)]
        self.key, self.stats, self.done = keys[0], jax.device_get(stats), self.done + 1
        return refused

    def record(self, per_robot: dict[int, dict[str, np.ndarray]]) -> None:
        """The round's metrics ({robot: its `Robot.train` metrics}; a robot that did not answer
        has NaN), with the round's exchange (`aggregate`'s stats) on its last episode."""
        first = next(iter(per_robot.values()))
        m = {}
        for name, x in first.items():
            if x.ndim != 3:  # not per robot
                m[name] = np.array(x)
                continue
            lost = np.full_like(x, np.nan, dtype=np.float32 if x.dtype.kind != "f" else x.dtype)
            m[name] = np.concatenate([per_robot[i][name] if i in per_robot else lost for i in range(self.n)], axis=2)
        for name, value in (
            ("fed_events", 1),
            ("fed_clients", self.stats["clients"]),
            ("fed_skipped", self.stats["skipped"]),
        ):
            m[name][:, -1] += value
        self.metrics.append(m)

    def write(self, out: str | Path) -> dict:
        """The run directory as of the last round: config.yaml, metrics.csv, summary.json,
        params.npz (the held models without target networks, leaves [1 seed, robot, ...]) and the
        round state (fleet_state.npz), each written whole (`rundir.atomic_write`). Returns the summary."""
        out = Path(out)
        rundir.make_folder(out, "run directory")
        rundir.write_config(out, self.cfg)
        facts = self.trainer.facts()
        metrics = {k: np.concatenate([m[k] for m in self.metrics], axis=1) for k in self.metrics[0]}
        df = metrics_frame(metrics, self.cfg, facts)
        rundir.write_metrics(out, df)
        summary = summarize(df, self.cfg, facts) | {"fleet": "flower", "rounds_done": self.done}
        rundir.write_json(out / rundir.SUMMARY, summary)
        held = wire.shared_fields({k: np.concatenate([h[k] for h in self.held]) for k in self.held[0]})
        nets = {k: v for k, v in wire.unpack(self.template, held).items() if not k.endswith(TARGET_SUFFIX)}
        rundir.write_params(out, jax.tree.map(lambda x: np.asarray(x)[None], nets))
        rundir.write_text(out / rundir.FLEET_ROUNDS, pd.DataFrame(self.rounds_log).to_csv(index=False))
        rundir.atomic_write(out / rundir.FLEET_STATE, lambda p: np.savez(open(p, "wb"), **self._state()))
        return summary

    def _state(self) -> dict[str, np.ndarray]:
        state = {"done": np.int64(self.done), "key": self.key, "rounds_log": np.array(json.dumps(self.rounds_log))}
        state |= {"agg" + k: v for k, v in wire.pack(self.agg_state).items()}
        for i in range(self.n):
            state |= {f"held{i}/{k}": v for k, v in self.held[i].items()}
            state |= {f"sent{i}/{k}": v for k, v in self.sent[i].items()}
        for r, m in enumerate(self.metrics):
            state |= {f"metrics{r}/{k}": v for k, v in m.items()}
        return state

    def _load(self, out: Path) -> None:
        if rundir.read_config(out) != self.cfg:
            raise FleetError(f"{out}: holds a fleet run of another config; resume it with its own config.yaml")
        with np.load(out / rundir.FLEET_STATE) as z:
            s = {k: z[k] for k in z.files}
        self.done, self.key, self.rounds_log = int(s["done"]), s["key"], json.loads(str(s["rounds_log"]))
        part = lambda prefix: {k[len(prefix) :]: v for k, v in s.items() if k.startswith(prefix)}
        self.agg_state = wire.unpack(self.agg_state, part("agg"))
        self.held = [part(f"held{i}/") for i in range(self.n)]
        self.sent = [part(f"sent{i}/") for i in range(self.n)]
        self.metrics = [part(f"metrics{r}/") for r in range(self.done)]
