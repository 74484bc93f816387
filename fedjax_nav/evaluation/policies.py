"""Policies with a memory in the evaluation program (`rollout.eval_program`): a recurrent policy's
state starts at `init()` in every episode, with `first` set at the episode's first step, and is
carried step to step (`MemoryPolicy`); a plain `policy(params, obs) -> action` is one without.
"""

from __future__ import annotations

import functools
from typing import Callable, NamedTuple


class MemoryPolicy(NamedTuple):
    """A policy with a memory, as the learners' `memory` and `greedy` (agents.learners) give it.

    init() -> one episode's memory at its start (a pytree of arrays; None: no memory, then
        `first` is None too). step(params, obs, memory, first) -> (action, memory), one agent's
        params and one observation f32[obs]; first: bool[] obs is the episode's first (the
        learner resets its memory there). Hashable: the program is cached by the pair of functions.
    """

    init: Callable
    step: Callable


def as_memory_policy(policy) -> MemoryPolicy:
    """`policy(params, obs) -> action` as a MemoryPolicy without a memory (a MemoryPolicy as is)."""
    if isinstance(policy, MemoryPolicy):
        return policy
    return _stateless(policy)


@functools.lru_cache(maxsize=32)
def _stateless(policy: Callable) -> MemoryPolicy:
    return MemoryPolicy(no_memory, lambda params, obs, memory, first: (policy(params, obs), memory))


def no_memory():
    return None
