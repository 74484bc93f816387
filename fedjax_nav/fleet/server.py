"""The fleet's server (docs/fleet.md): the round's exchange (`training.federation.exchange`, the
in-program round's own function, with the run's aggregator and hyperparameters) over what the
robots sent, and the run directory a normal run leaves (config.yaml, metrics.csv, summary.json,
params.npz: `fedjax-nav evaluate` reads it)."""

from __future__ import annotations

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from fedjax_nav import rundir
from fedjax_nav.config import Config
from fedjax_nav.federated.aggregators import TARGET_SUFFIX
from fedjax_nav.fleet import wire
from fedjax_nav.fleet.robot import FleetError, check
from fedjax_nav.training import federation
from fedjax_nav.training.hparams import hparams_from_config
from fedjax_nav.training.metrics import metrics_frame, summarize
from fedjax_nav.training.trainer import Trainer


class Server:
    """The server of the run `cfg` (one seed): the aggregator's state between rounds, the metrics."""

    def __init__(self, cfg: Config):
        check(cfg)
        self.cfg, self.trainer, self.hp = cfg, Trainer(cfg), hparams_from_config(cfg)
        key = jax.random.key(cfg.run.seed)  # the aggregator starts from the robots' initial agents, as in the program
        self.agg_state = jax.jit(lambda k: self.trainer.init_agg_state(self.trainer.init_agents(k, self.hp), self.hp))(
            key
        )
        self._exchange = jax.jit(lambda own, r, k, s: federation.exchange(self.trainer.round, self.hp, own, r, k, s))
        self.metrics: list[dict] = []  # one per round: leaves [1, fed.period, ...]
        self.shared = None  # the robots' shared fields after the last round, leaves [robots, ...]

    def aggregate(self, sends: list[dict[str, np.ndarray]]) -> list[dict[str, np.ndarray]]:
        """One round over every robot's `Robot.sent` (robot order): each robot's answer (its row
        of the exchange, in the same "shared…" form). The robots must hold the run's one key."""
        if len(sends) != self.trainer.num_robots:
            raise FleetError(f"round: {len(sends)} robots answered; the run has {self.trainer.num_robots} (env.worlds)")
        keys = np.stack([s["key"] for s in sends])
        if not (keys == keys[0]).all():
            raise FleetError("run.seed: the robots' run keys differ (not one run)")
        names = [k for k in sends[0] if k.startswith("shared")]
        own = {k: np.concatenate([s[k] for s in sends]) for k in names}  # each robot's leaves are [1, ...]
        r = np.concatenate([s["reward"] for s in sends])
        template = jax.eval_shape(
            self.trainer.shared, jax.eval_shape(self.trainer.init_agents, jax.random.key(0), self.hp)
        )
        tree = wire.unpack(template, {k.removeprefix("shared"): v for k, v in own.items()})
        new, self.agg_state, stats = self._exchange(
            tree, jnp.asarray(r), jax.random.wrap_key_data(keys[0]), self.agg_state
        )
        self.shared = new
        self.stats = jax.device_get(stats)
        flat = {"shared" + k: v for k, v in wire.pack(new).items()}
        return [{k: v[i : i + 1] for k, v in flat.items()} for i in range(len(sends))]

    def record(self, per_robot: list[dict[str, np.ndarray]]) -> None:
        """The round's metrics (each robot's `Robot.train` metrics, robot order), with the round's
        exchange (`aggregate`'s stats) on its last episode, as the program records it."""
        m = {}
        for name, first in per_robot[0].items():
            m[name] = np.concatenate([p[name] for p in per_robot], axis=2) if first.ndim == 3 else np.array(first)
        for name, value in (
            ("fed_events", 1),
            ("fed_clients", self.stats["clients"]),
            ("fed_skipped", self.stats["skipped"]),
        ):
            m[name][:, -1] += value
        self.metrics.append(m)

    def write(self, out: str | Path) -> dict:
        """The run directory: config.yaml, metrics.csv, summary.json, params.npz (the shared fields
        without target networks, leaves [1 seed, robot, ...]). Returns the summary."""
        out = Path(out)
        rundir.make_folder(out, "run directory")
        rundir.write_config(out, self.cfg)
        facts = self.trainer.facts()
        metrics = {k: np.concatenate([m[k] for m in self.metrics], axis=1) for k in self.metrics[0]}
        df = metrics_frame(metrics, self.cfg, facts)
        rundir.write_metrics(out, df)
        summary = summarize(df, self.cfg, facts) | {"fleet": "flower"}
        rundir.write_json(out / rundir.SUMMARY, summary)
        nets = {k: v for k, v in self.shared.items() if not k.endswith(TARGET_SUFFIX)}
        rundir.write_params(out, jax.tree.map(lambda x: np.asarray(x)[None], nets))
        return summary
