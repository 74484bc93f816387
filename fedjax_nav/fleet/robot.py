"""One robot of a fleet (a Flower client, docs/fleet.md): its slice of the run's compiled program
(`Trainer(fleet=(i, robots))`: robot i's rooms, learner and key stream, no round compiled in; one
program per world, the robot's index traced), run fed.period episodes a round. Between rounds its
whole training state is a flat dict of arrays (`wire.pack`), which the Flower client keeps in its
context. The round itself is
`training.federation`'s: the robot `sent`s, the server `exchange`s, the robot `settle`s."""

from __future__ import annotations

import dataclasses
import functools
from functools import cached_property
from pathlib import Path
from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from fedjax_nav import methods, rundir
from fedjax_nav.config import Config
from fedjax_nav.federated import attacks
from fedjax_nav.fleet import wire
from fedjax_nav.training import federation
from fedjax_nav.training.hparams import hparams_from_config
from fedjax_nav.training.trainer import Trainer


class FleetError(ValueError):
    """A config the fleet cannot run (one line naming the field)."""


def check(cfg: Config) -> None:
    """Refuse what this first fleet does not hold (docs/fleet.md, "What is left")."""
    method = methods.get(cfg.method)
    refusals = [
        (method.shared_network or method.shared_buffer, "method", f"{cfg.method} shares one network or buffer"),
        (cfg.fed.period_unit != "episodes", "fed.period_unit", "rounds between steps of an episode"),
        (cfg.env.rooms != "fixed", "env.rooms", "procedural rooms"),
        (cfg.env.placement != "fixed", "env.placement", "random placement"),
        (cfg.env.shared_rooms, "env.shared_rooms", "shared rooms (one robot per program)"),
        (cfg.run.eval_every != 0, "run.eval_every", "the held-out probe"),
        (cfg.run.seeds != 1, "run.seeds", "more than one seed (one fleet is one seed)"),
        (cfg.run.episodes % cfg.fed.period != 0, "run.episodes", "a last round that is not whole (fed.period)"),
    ]
    for bad, field, what in refusals:
        if bad:
            raise FleetError(f"{field}: the fleet does not run {what} yet (docs/fleet.md)")


def rounds(cfg: Config) -> int:
    """The run's federated rounds: run.episodes / fed.period."""
    return cfg.run.episodes // cfg.fed.period


class Program(NamedTuple):
    """One world's compiled program of a fleet's robots (`program`)."""

    trainer: Trainer  # robot 0's (`Trainer.robot(i)` is robot i's)
    hp: object  # the run's HParams
    init: Callable  # (seeds, hp, index) -> states
    chunk: Callable  # (states, hp, first_episode, index) -> (states, metrics): fed.period episodes


@functools.lru_cache(maxsize=None)
def program(text: str, world: str) -> Program:
    """The compiled program of every robot of the run `text` (`wire.config_text`) that drives in
    `world`, compiled once per process: the robot's index is traced (`Trainer.robot`), so a
    Flower process that runs 50 robots of 5 worlds holds 5 programs, not 50."""
    cfg = wire.config_from_text(text)
    mine = dataclasses.replace(cfg, env=dataclasses.replace(cfg.env, worlds=(world,)))
    trainer, period = Trainer(mine, fleet=(0, cfg.num_robots)), cfg.fed.period
    return Program(
        trainer,
        hparams_from_config(mine),
        jax.jit(lambda seeds, hp, i: trainer.robot(i).init_seeds(seeds, hp)),
        jax.jit(lambda st, hp, e, i: trainer.robot(i).chunk(st, hp, e, period), donate_argnums=0),
    )


class Robot:
    """Robot `index`'s program of the run `cfg` (one seed: cfg.run.seed), compiled once per world."""

    def __init__(self, cfg: Config, index: int):
        check(cfg)
        if not 0 <= index < cfg.num_robots:
            raise FleetError(f"partition-id: robot {index} of a run of {cfg.num_robots} (env.worlds)")
        self.cfg, self.index = cfg, index
        self._program = program(wire.config_text(cfg), cfg.env.worlds[index])
        self.trainer, self.hp = self._program.trainer.robot(index), self._program.hp

    def init(self):
        """The robot's initial state, stacked over the run's one seed."""
        return self._program.init(jnp.asarray([self.cfg.run.seed]), self.hp, jnp.int32(self.index))

    @cached_property
    def template(self):
        return jax.eval_shape(self.init)

    @cached_property
    def shared_template(self):
        """The shapes of one seed's shared fields (leaves [1 robot, ...]), as sent and answered."""
        return jax.eval_shape(lambda s: self.trainer.shared(jax.tree.map(lambda x: x[0], s.agents)), self.template)

    def load(self, arrays: dict[str, np.ndarray]):
        return wire.unpack(self.template, arrays)

    def train(self, states, round_index: int):
        """fed.period episodes from episode round_index * fed.period: (states, metrics [1, E, ...])."""
        first = jnp.int32(round_index * self.cfg.fed.period)
        return self._program.chunk(states, self.hp, first, jnp.int32(self.index))

    def sent(self, states) -> dict[str, np.ndarray]:
        """What the robot sends (`federation.sent`): its shared fields ("shared…" paths, leaves
        [1, ...]), its mean reward ("reward", f32[1]) and the run's key at the round ("key")."""
        own, r = jax.vmap(lambda s: federation.sent(self.trainer.round, s))(states)
        out = {k: v[0] for k, v in wire.shared_arrays(own).items()}
        return out | {"reward": np.asarray(r[0]), "key": np.asarray(jax.random.key_data(states.key[0]))}

    def settle(self, states, new: dict[str, np.ndarray]):
        """The states with the server's answer in place (`federation.settle`; `new` in `sent`'s
        "shared…" form, leaves [1, ...]) and the run's key it carries ("key": the same key for a
        robot that took part in every round, the run's key for one that missed rounds)."""
        taken = wire.unpack(self.shared_template, wire.shared_fields(new))
        settle = lambda s, n: federation.settle(self.trainer.round, s, n, s.agg_state)
        states = jax.vmap(settle)(states, jax.tree.map(lambda x: x[None], taken))
        return states.replace(key=jax.random.wrap_key_data(np.asarray(new["key"])[None])) if "key" in new else states

    def attacked(self, sent: dict[str, np.ndarray], kind: str, reference: dict[str, np.ndarray] | None):
        """What a Byzantine robot sends instead of `sent` (node config "byzantine": a fed.attack
        name): the program's attack on its own shared fields, with fed.attack_scale when the run's
        fed.attack is this one (else the attack's default), noise drawn from the run's key, and
        for scale and sign_flip the model it last took from the server as the reference
        (`reference`, `sent`'s form; None: its initial model). "stale" is the server's alone."""
        if kind not in attacks.ATTACKS or kind == "stale":
            allowed = ", ".join(a for a in attacks.ATTACKS if a != "stale")
            raise FleetError(f"byzantine: {kind!r} is no attack a robot sends (allowed: {allowed})")
        shared = lambda d: wire.unpack(self.shared_template, wire.shared_fields(d))
        ref = jax.tree.map(lambda x: x[0], shared(reference if reference is not None else self.sent(self.init())))
        scale = self.hp.fed.attack_scale if self.cfg.fed.attack == kind else None
        key = jax.random.fold_in(jax.random.wrap_key_data(sent["key"]), self.index)
        bad = attacks.apply_attack(kind, shared(sent), jnp.ones(1, bool), key, scale, ref)
        return sent | {k: np.asarray(v) for k, v in wire.shared_arrays(bad).items()}


def save_state(folder: str | Path, name: str, trained: int, arrays: dict[str, np.ndarray], keep: int = 2) -> Path:
    """A robot's packed state after `trained` rounds, NAME-TRAINED.npz in `folder` (the robot's own
    disk: a restarted robot or a resumed run starts from it), written whole; the `keep` latest kept."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    path = rundir.atomic_write(folder / f"{name}-{trained}.npz", lambda p: np.savez(open(p, "wb"), **arrays))
    for old in sorted(_saved(folder, name))[:-keep]:
        (folder / f"{name}-{old}.npz").unlink(missing_ok=True)
    return path


def load_state(folder: str | Path, name: str, round_index: int) -> tuple[int, dict[str, np.ndarray]] | None:
    """The robot's saved state for round `round_index` (trained that many rounds), or the latest
    one before it: (trained, arrays); None when it has none."""
    found = [t for t in _saved(Path(folder), name) if t <= round_index]
    if not found:
        return None
    with np.load(Path(folder) / f"{name}-{max(found)}.npz") as z:
        return max(found), {k: z[k] for k in z.files}


def _saved(folder: Path, name: str) -> list[int]:
    tails = (p.stem[len(name) + 1 :] for p in folder.glob(f"{name}-*.npz"))
    return [int(t) for t in tails if t.isdigit()]
