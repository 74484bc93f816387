"""The thesis's methods as data (docs/decisions.md, "Methods"): how many networks and buffers,
which aggregator (a name in `fedjax_nav.federated.aggregators.RULES`), which starts. The
trainer reads these flags; there are no subclasses. The config's `method` choices are this
table's keys. The names are the thesis's, but a method is only the sharing: with `learner: td3`
(or sac, ppo) `flddpg` is soft FedAvg of TD3 agents (docs/learners.md); an on-policy learner
cannot share a buffer (seddpg, snddpg: config.validate says so)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Method:
    name: str
    shared_network: bool  # one network acts and learns for every robot (SNDDPG)
    shared_buffer: bool  # one replay buffer that every robot writes (SEDDPG, SNDDPG)
    aggregator: str  # federated step: none | soft | pw | rw | gs
    random_starts: bool  # FLS: reset to a random one of the room's starts
    sends_rewards: bool = False  # PW/RW send r_k with the parameters (Table 3)


METHODS = {
    m.name: m
    for m in [
        Method("iddpg", False, False, "none", False),
        Method("seddpg", False, True, "none", False),
        Method("snddpg", True, True, "none", False),
        Method("flddpg", False, False, "soft", False),
        Method("pwddpg", False, False, "pw", False, sends_rewards=True),
        Method("rwddpg", False, False, "rw", False, sends_rewards=True),
        Method("gsddpg", False, False, "gs", False),
        Method("flsddpg", False, False, "soft", True),
    ]
}


def get(name: str) -> Method:
    try:
        return METHODS[name.lower()]
    except KeyError:
        raise ValueError(f"unknown method {name!r}; allowed: {', '.join(METHODS)}") from None
