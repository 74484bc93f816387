"""Federated aggregation over stacked pytrees, and communication accounting."""
from fedjax_nav.federated.aggregators import (
    AGGREGATORS,
    aggregate,
    global_soft,
    init_global,
    positive_weighting,
    positive_weights,
    real_weighting,
    real_weights,
    soft_fedavg,
)
from fedjax_nav.federated.comm import communication

__all__ = [
    "AGGREGATORS", "aggregate", "global_soft", "init_global", "positive_weighting", "positive_weights",
    "real_weighting", "real_weights", "soft_fedavg", "communication",
]
