"""Federated aggregation over stacked pytrees (`Aggregator` pairs), and communication accounting."""

from fedjax_nav.federated.aggregators import RULES, Aggregator, make
from fedjax_nav.federated.comm import communication

__all__ = ["RULES", "Aggregator", "make", "communication"]
