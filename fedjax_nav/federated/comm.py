"""Communication accounting: the thesis's Eq. 25 and bytes on the wire.

N_comm = (N_data + N_NN) E, with per-episode counts (Table 3):
    SEDDPG: N_data = T + ceil(T / T_train) * batch   (every transition up, every batch down)
    SNDDPG: N_data = T, N_NN = ceil(T / T_train)     (transitions up, the network down per update)
    FL/GS/FLS: N_NN = 1 / E_update (or T / T_update)   PW/RW: twice that (rewards sent too)
"""

from __future__ import annotations

import math


def communication(
    method, episodes: int, steps: int, train_every: int, batch: int, period_unit: str, period: int
) -> dict:
    """Per-episode N_data, N_NN and the run's N_comm (floats: the thesis rounds 62.5 up to 63)."""
    updates = math.ceil(steps / train_every)
    n_data, n_nn = 0.0, 0.0
    if method.aggregator == "none":
        if method.shared_network:
            n_data, n_nn = float(steps), float(updates)
        elif method.shared_buffer:
            n_data = float(steps + updates * batch)
    else:
        rounds = 1.0 / period if period_unit == "episodes" else steps / period
        n_nn = rounds * (2.0 if method.sends_rewards else 1.0)
    return {"n_data_per_episode": n_data, "n_nn_per_episode": n_nn, "n_comm": (n_data + n_nn) * episodes}


def bytes_per_round(num_params: int, clients: int, sends_rewards: bool, dtype_bytes: int = 4) -> int:
    """Bytes of one federated round: every client uploads its parameters (and reward) and
    downloads the aggregate."""
    up = clients * (num_params + (1 if sends_rewards else 0)) * dtype_bytes
    down = clients * num_params * dtype_bytes
    return up + down
