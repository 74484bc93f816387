"""A run's learned value along observations (docs/clutter.md, "Why detours fail"): what the critic
thinks of the states a replayed episode went through.

    params = value_params(run)                 # the row's `value_networks` from params.npz, [A, ...]
    v = values_along(run, params, obs)         # obs f32[A, E, T, obs] -> V f32[A, E, T]

The learner's row of fedjax_nav.learner_table names the networks of params.npz its value reads
(`value_networks`) and its `agents.learners.Learner.value` computes it: PPO's value net V(s) (the
observation normalised with the actor's statistics when kept; a recurrent PPO's GRU carried along
the sequence from zeros), DDPG's Q(s, mu(s)) at the greedy action, TD3's and SAC's min of the twin
critics there (SAC: without the entropy term). A learner without one is refused in one line.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from fedjax_nav import rundir
from fedjax_nav.evaluation.limits import EvalError
from fedjax_nav.evaluation.run_data import RunAgents


def _row(run: RunAgents):
    """The run's learner row, or an EvalError (one line) where there is no value to call."""
    from fedjax_nav.agents import learners
    from fedjax_nav.learner_table import get

    if run.policy is not None:
        raise EvalError(f"{run.run_dir}: a scripted policy drives it; there is no learned value to read")
    row = get(run.cfg.learner)
    if not row.value_networks or learners.get(row.name).value is None:
        raise EvalError(
            f"learner {row.name!r}: the learner table gives it no value function (value_networks); "
            "there is no learned value to read"
        )
    return row


def value_params(run: RunAgents) -> dict:
    """{network: its parameters, leaves [A, ...]} of the row's `value_networks`, read from the run's
    params.npz through fedjax_nav.rundir and flattened as `runs.load_run` flattens the actor's."""
    row, lead = _row(run), (len(np.unique(run.agent_seed)), run.n_nets)
    out = {}
    for net in row.value_networks:
        try:
            tree = rundir.read_params(run.run_dir, net)
        except rundir.RunDirError as e:
            what = f"learner {row.name!r} reads its value from {', '.join(row.value_networks)}"
            raise EvalError(f"{e} ({what})") from None
        for leaf in jax.tree.leaves(tree):
            if tuple(leaf.shape[:2]) != lead:
                raise EvalError(
                    f"{run.run_dir / rundir.PARAMS}: {net} has leading axes {list(leaf.shape[:2])}, "
                    f"the actor {list(lead)}"
                )
        out[net] = jax.tree.map(lambda x: jnp.asarray(x.reshape(-1, *x.shape[2:]), jnp.float32), tree)
    return out


@functools.lru_cache(maxsize=16)
def _program(learner_name: str, frozen_values: tuple):
    """jit(V along [A, E, T, obs]) for one learner and network settings."""
    from fedjax_nav.agents import learners

    learner = learners.get(learner_name)
    nets = learner.make_nets(dict(frozen_values))

    def episode(params, obs):  # one agent's one sequence f32[T, obs]: the memory from its start
        def step(memory, x):
            t, o = x
            v, memory = learner.value(nets, params, o, memory, t == 0)
            return memory, v

        return jax.lax.scan(step, learner.memory(nets), (jnp.arange(obs.shape[0]), obs))[1]

    return jax.jit(jax.vmap(jax.vmap(episode, (None, 0)), (0, 0)))


def values_along(run: RunAgents, params: dict, obs) -> np.ndarray:
    """V f32[A, E, T] of each agent along each of its sequences `obs` f32[A, E, T, obs] (step 0
    is a sequence's first: a memory starts there), with `value_params`' params."""
    from fedjax_nav.config import values

    row = _row(run)
    mine = {k: v for k, v in values(run.cfg).items() if k.split(".")[0] in ("learner", *row.sections)}
    program = _program(row.name, tuple(sorted(mine.items())))
    return np.asarray(jax.device_get(program(params, jnp.asarray(obs, jnp.float32))))
