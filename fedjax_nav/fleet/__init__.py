"""Real fleets: the federated round between processes and machines, on Flower (docs/fleet.md).

`robot` (one client: its slice of the run's program for one round) and `server` (the round's
exchange over what the clients sent, and the run directory) need nothing beyond the package;
`apps` is the Flower app around them (`pip install "fedjax_nav[fleet]"`): import it only where
Flower is installed. Nothing else in the package imports this one.
"""
