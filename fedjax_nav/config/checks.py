"""Cross-field checks of a Config (`check`: each error one line naming the fields involved) and
the warning of a run that can never update (`never_updates`)."""

from __future__ import annotations

from dataclasses import fields

from fedjax_nav.config.names import get
from fedjax_nav.config.schema import ROOM_FAMILIES, Config, ConfigError, robot_problem
from fedjax_nav.learner_table import get as learner_row
from fedjax_nav.learner_table import off_policy
from fedjax_nav.messages import show


def check(cfg: Config, src: str = "<config>") -> None:
    """Cross-field checks (each names the fields involved)."""
    if msg := robot_problem(cfg.robot, cfg.env.num_beams):
        raise ConfigError(f"{src}: {msg}")
    d = cfg.offpolicy
    if d.buffer_alloc and d.buffer_alloc < d.buffer_size:
        raise ConfigError(
            f"{src}: offpolicy.buffer_alloc ({d.buffer_alloc}) must be 0 or >= offpolicy.buffer_size ({d.buffer_size})"
        )
    if d.buffer_size < d.batch_size:
        raise ConfigError(
            f"{src}: offpolicy.buffer_size ({d.buffer_size}) is smaller than offpolicy.batch_size ({d.batch_size}); "
            "allowed: buffer_size >= batch_size"
        )
    # IDDPG, SEDDPG, SNDDPG have no federated step: their fed.period is unused, not inconsistent.
    federated = cfg.method not in ("iddpg", "seddpg", "snddpg")
    if federated and cfg.fed.period_unit == "episodes" and cfg.fed.period > cfg.run.episodes:
        raise ConfigError(
            f"{src}: fed.period ({cfg.fed.period} episodes) is longer than run.episodes ({cfg.run.episodes}); "
            "no federated step would ever happen"
        )
    if federated and cfg.fed.period_unit == "steps" and cfg.fed.period > cfg.env.episode_length * cfg.run.episodes:
        raise ConfigError(f"{src}: fed.period ({cfg.fed.period} steps) is longer than the whole run")
    rows = cfg.run.episodes * cfg.env.episode_length * cfg.num_robots * cfg.env.envs_per_robot
    if rows >= 2**31:  # the int32 step counters
        raise ConfigError(
            f"{src}: run.episodes x env.episode_length x robots x env.envs_per_robot = "
            f"{rows:,} transitions; at most 2^31 - 1"
        )
    _check_fed(cfg, src, federated)
    _check_learner(cfg, src)
    _check_rooms(cfg, src)
    _check_learnability(cfg, src)
    if cfg.run.episodes % cfg.run.chunk_episodes:
        raise ConfigError(
            f"{src}: run.episodes ({cfg.run.episodes}) must be a multiple of run.chunk_episodes "
            f"({cfg.run.chunk_episodes})"
        )
    if cfg.run.checkpoint_every % cfg.run.chunk_episodes:
        raise ConfigError(
            f"{src}: run.checkpoint_every ({cfg.run.checkpoint_every}) must be a multiple of "
            f"run.chunk_episodes ({cfg.run.chunk_episodes})"
        )


def _check_learner(cfg: Config, src: str) -> None:
    """The learner against the method and its own loop sizes (docs/learners.md)."""
    from fedjax_nav.methods import METHODS

    p, method, row = cfg.ppo, METHODS[cfg.method], learner_row(cfg.learner)
    # One shared network with its one buffer (snddpg) is one central on-policy learner over every
    # robot's environments; a shared buffer under separate networks (seddpg) would train each
    # network on the others' actions, which an on-policy learner cannot.
    if row.on_policy and method.shared_buffer and not method.shared_network:
        raise ConfigError(
            f"{src}: method {cfg.method} shares one replay buffer between the robots' own networks; learner "
            f"{cfg.learner} learns on-policy from its own policy's rollout and cannot (use iddpg, snddpg or a "
            "federated method)"
        )
    if p.recurrent != "none" and "ppo" not in row.sections:
        raise ConfigError(f"{src}: ppo.recurrent ({p.recurrent!r}) needs learner: ppo (learner is {cfg.learner!r})")
    if p.normalize_obs and "ppo" not in row.sections:
        raise ConfigError(f"{src}: ppo.normalize_obs needs learner: ppo (learner is {cfg.learner!r})")
    _check_n_step(cfg, src, method, row.on_policy)
    if "ppo" in row.sections:
        # the environments of one rollout: a robot's, or every robot's under one shared network
        n = cfg.env.envs_per_robot * (cfg.num_robots if method.shared_network else 1)
        # a GRU's minibatches are whole sequences: they split the environments, not the rows
        recurrent = p.recurrent != "none"
        per = "env.envs_per_robot" + (" x robots" if method.shared_network else "")
        rows, what = (n, per) if recurrent else (p.rollout * n, f"ppo.rollout x {per}")
        if rows % p.minibatches:
            raise ConfigError(f"{src}: ppo.minibatches ({p.minibatches}) must divide {what} ({rows})")


def never_updates(cfg: Config) -> str | None:
    """Why the learner of this run could never update its networks, or None (docs/reliability.md,
    "Runs that cannot learn"): a warning, not a refusal, since a run that only drives (a smoke run
    of the pipeline) is a use; `training.run.train` prints it before training. From its row of
    the learner table: an update event follows step g (0-based,
    per environment) when g + 1 is a multiple of the row's `update_every` field (ppo.rollout,
    offpolicy.train_every: `due` in agents/learners.py and agents/learner_ppo.py), and, for a
    learner with a replay buffer, once that buffer has received a batch, (g + 1) x rows per step
    >= offpolicy.batch_size (`_ready`). The run has run.episodes x env.episode_length steps."""
    from fedjax_nav.methods import METHODS

    row = learner_row(cfg.learner)
    steps = cfg.run.episodes * cfg.env.episode_length
    whole = f"run.episodes x env.episode_length = {steps:,} steps per environment"
    every = get(cfg, row.update_every)
    if every > steps:
        return (
            f"{row.update_every} ({every:,} steps) is longer than the whole run ({whole}); "
            f"no update will happen: lower {row.update_every} or raise run.episodes"
        )
    if row.on_policy:
        return None
    shared = METHODS[cfg.method].shared_buffer
    rows = cfg.env.envs_per_robot * (cfg.num_robots if shared else 1)
    last = steps // every * every  # steps done at the run's last update event
    if last * rows < cfg.offpolicy.batch_size:
        per = "env.envs_per_robot" + (" x robots, one shared buffer" if shared else "")
        return (
            f"offpolicy.batch_size ({cfg.offpolicy.batch_size:,}) is more than the rows a replay buffer "
            f"has received at the run's last update event ({last:,} steps x {rows} per step ({per}) = "
            f"{last * rows:,}; {whole}, an update every {row.update_every} = {every}); "
            "no update will happen: lower offpolicy.batch_size or raise run.episodes"
        )
    return None


def _check_n_step(cfg: Config, src: str, method, on_policy: bool) -> None:
    """offpolicy.n_step: an off-policy learner's, and a window of n steps of every environment writing
    into one buffer must fit in it."""
    d = cfg.offpolicy
    if d.random_steps and on_policy:  # PPO learns from its own policy's actions
        raise ConfigError(
            f"{src}: offpolicy.random_steps ({d.random_steps}) needs an off-policy learner: {', '.join(off_policy())}"
        )
    if d.n_step == 1:
        return
    if on_policy:
        raise ConfigError(
            f"{src}: offpolicy.n_step ({d.n_step}) needs an off-policy learner: {', '.join(off_policy())} "
            f"(learner is {cfg.learner!r})"
        )
    rows = cfg.env.envs_per_robot * (cfg.num_robots if method.shared_buffer else 1)
    if d.n_step * rows > d.buffer_size:
        raise ConfigError(
            f"{src}: offpolicy.n_step ({d.n_step}) x rows written per step into one buffer ({rows}) is more than "
            f"offpolicy.buffer_size ({d.buffer_size}): a window of n steps must fit in the buffer"
        )


def _check_rooms(cfg: Config, src: str) -> None:
    """env.room_families against the families and the robot count (RoomSpec overrides are checked
    by the trainer, which imports the generator)."""
    fams, n = cfg.env.room_families, cfg.num_robots
    e = cfg.env
    if e.rooms != "procedural" and (e.room_curriculum_episodes or e.room_density_start != 1.0):
        field = "room_curriculum_episodes" if e.room_curriculum_episodes else "room_density_start"
        raise ConfigError(f"{src}: env.{field} thins procedural rooms; it needs env.rooms = procedural")
    if e.rooms != "procedural" and e.room_spec.strip():
        raise ConfigError(
            f"{src}: env.room_spec ({show(e.room_spec)}) shapes procedural rooms; it needs env.rooms = procedural "
            f"(env.rooms is {e.rooms!r})"
        )
    bad = [f for f in fams if f not in ROOM_FAMILIES]
    if bad:
        raise ConfigError(f"{src}: env.room_families: {show(bad[0])} is not one of {', '.join(ROOM_FAMILIES)}")
    if len(fams) not in (1, n):
        raise ConfigError(
            f"{src}: env.room_families has {len(fams)} entries; allowed: 1 (every robot) or one per "
            f"robot ({n}, env.worlds)"
        )


def _check_learnability(cfg: Config, src: str) -> None:
    """The learnability curriculum's fields (docs/generalization.md): they act on procedural rooms
    sampled by learnability only, and need at least one robot of a generated family."""
    e = cfg.env
    if e.room_sampling == "learnability":
        if e.rooms != "procedural":
            raise ConfigError(
                f"{src}: env.room_sampling = learnability draws procedural rooms; it needs env.rooms = procedural "
                f"(env.rooms is {e.rooms!r})"
            )
        if all(f == "fixed" for f in e.room_families):
            raise ConfigError(
                f"{src}: env.room_sampling = learnability needs a generated family in env.room_families "
                "(every robot keeps its fixed room)"
            )
        return
    defaults = {f.name: f.default for f in fields(type(e))}
    for name in ("room_bank", "room_fresh", "room_ema", "room_floor"):
        if getattr(e, name) != defaults[name]:
            raise ConfigError(
                f"{src}: env.{name} ({getattr(e, name)!r}) sets the learnability curriculum; it needs "
                f"env.room_sampling = learnability (env.room_sampling is {e.room_sampling!r})"
            )


def _check_fed(cfg: Config, src: str, federated: bool) -> None:
    """The robust-federation fields against each other, the method and the robot count."""
    f, n = cfg.fed, cfg.num_robots
    if not federated:
        for name, value, default in [
            ("aggregator", f.aggregator, "method"),
            ("byzantine", f.byzantine, 0),
            ("participation", f.participation, 1.0),
        ]:
            if value != default:
                raise ConfigError(
                    f"{src}: fed.{name} ({value!r}) needs a federated method; {cfg.method} has no "
                    f"federated step (allowed: {default!r})"
                )
    if f.byzantine >= n:
        raise ConfigError(
            f"{src}: fed.byzantine ({f.byzantine}) must be smaller than the number of robots ({n}, env.worlds)"
        )
    if f.min_clients > n:
        raise ConfigError(
            f"{src}: fed.min_clients ({f.min_clients}) is larger than the number of robots ({n}, "
            "env.worlds): every round would be skipped"
        )
    if (f.byzantine > 0) != (f.attack != "none"):
        raise ConfigError(
            f"{src}: fed.byzantine ({f.byzantine}) and fed.attack ({f.attack!r}) go together: "
            "set both (byzantine >= 1 and an attack) or neither"
        )
    if f.aggregator == "krum":
        if 2 * f.krum_f + 2 > n:
            raise ConfigError(
                f"{src}: fed.krum_f ({f.krum_f}) is too large for {n} robots: Krum needs "
                f"2 * fed.krum_f + 2 <= robots ({2 * f.krum_f + 2} > {n})"
            )
        if f.krum_m > n - f.krum_f:
            raise ConfigError(f"{src}: fed.krum_m ({f.krum_m}) must be <= robots - fed.krum_f ({n - f.krum_f})")
