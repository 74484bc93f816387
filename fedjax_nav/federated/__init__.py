"""Federated aggregation over stacked pytrees (`Aggregator` pairs), and communication accounting."""

from fedjax_nav.federated.aggregators import AGGREGATORS, Aggregator, init_global, make
from fedjax_nav.federated.comm import communication

__all__ = ["AGGREGATORS", "Aggregator", "init_global", "make", "communication"]
