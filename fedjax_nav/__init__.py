"""fedjax_nav: JAX-accelerated federated deep RL for robot navigation."""

__version__ = "0.1.0"
