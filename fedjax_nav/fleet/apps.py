"""The Flower app (docs/fleet.md; needs `pip install "fedjax_nav[fleet]"`): `app` is the
ClientApp (one robot: `robot.Robot`, its program compiled once per process, its training state
kept in the node's context between rounds), `FleetStrategy` the server's strategy (the round's
exchange of `server.Server`, the in-program round's own function), `server_app` the ServerApp of
one run and `run_simulation` the whole run on Flower's simulation engine, one node per robot."""

from __future__ import annotations

import hashlib
import time
from pathlib import Path

import jax
from flwr.app import ArrayRecord, Context, Message, MetricRecord, RecordDict
from flwr.clientapp import ClientApp
from flwr.serverapp import Grid, ServerApp

from fedjax_nav import rundir
from fedjax_nav.config import Config, load_config
from fedjax_nav.fleet import wire
from fedjax_nav.fleet.robot import FleetError, Robot, load_state, rounds, save_state
from fedjax_nav.fleet.server import Server
from fedjax_nav.fleet.strategy import FleetStrategy, numpy_of, record_of

app = ClientApp()
_ROBOTS: dict[tuple[str, int], Robot] = {}  # (config text, robot): one compiled program per process


def _robot(text: str, index: int) -> Robot:
    return _ROBOTS.get((text, index)) or _ROBOTS.setdefault((text, index), Robot(wire.config_from_text(text), index))


def _start_state(robot: Robot, context: Context, name: str, round_index: int):
    """The robot's state before round `round_index`: kept in the node's context (this run), or
    saved on the robot's disk (node config "state-dir": a restarted robot, a resumed run), or the
    run's initial state."""
    kept = context.state.array_records.get("state")
    if kept is not None:
        return robot.load(numpy_of(kept))
    folder = context.node_config.get("state-dir")
    saved = load_state(str(folder), name, round_index) if folder else None
    return robot.init() if saved is None else robot.load(saved[1])


@app.query()
def query(msg: Message, context: Context) -> Message:
    """Which robot this node is (its node config's partition-id)."""
    return Message(
        RecordDict({"robot": MetricRecord({"index": int(context.node_config["partition-id"])})}), reply_to=msg
    )


@app.train()
def train(msg: Message, context: Context) -> Message:
    """One round of robot `partition-id` (node config): take the server's answer (the model it
    holds for this robot and the run's key), train fed.period episodes, send its shared fields,
    reward and key, and its episodes' metrics; its state stays in the context and, with a node
    config "state-dir", on its disk."""
    text, index = str(msg.content["config"]["config"]), int(context.node_config["partition-id"])
    round_index, robot = int(msg.content["config"]["round"]), _robot(text, index)
    name = f"robot-{index}-{hashlib.sha256(text.encode()).hexdigest()[:8]}"
    states = _start_state(robot, context, name, round_index)
    answer = numpy_of(msg.content["answer"]) if "answer" in msg.content.array_records else None
    if answer is not None:
        states = robot.settle(states, answer)
    start = time.perf_counter()
    states, metrics = robot.train(states, round_index)
    metrics = jax.device_get(metrics)  # waits for the round's training
    train_s = time.perf_counter() - start
    packed = wire.pack(states)
    context.state["state"] = record_of(packed)
    if folder := context.node_config.get("state-dir"):
        save_state(str(folder), name, round_index + 1, packed)
    sent = robot.sent(states)
    if kind := context.node_config.get("byzantine"):  # a robot that lies (docs/fleet.md, "Faults and trust")
        sent = robot.attacked(sent, str(kind), answer)
    content = RecordDict(
        {
            "sent": record_of(sent),
            "metrics": record_of(metrics),
            "robot": MetricRecord({"index": index, "reward": float(sent["reward"][0]), "train_s": train_s}),
        }
    )
    return Message(content, reply_to=msg)


def server_app(
    cfg: Config | None = None, out: str | Path | None = None, round_timeout: float | None = None
) -> ServerApp:
    """The ServerApp of the run `cfg` writing its run directory `out` after every round (a run
    directory holding a fleet state of the same config is resumed), a round waiting at most
    `round_timeout` s for the robots' replies; without them, from the run config's "config" (a
    config file or shipped name), "out" and "round-timeout" (600 s; `flwr run`)."""
    server = ServerApp()

    @server.main()
    def main(grid: Grid, context: Context) -> None:
        c = cfg if cfg is not None else load_config(str(context.run_config["config"]))
        o = out if out is not None else str(context.run_config["out"])
        wait = round_timeout or float(context.run_config.get("round-timeout", 600.0))
        fleet_server = Server(c, o)
        remaining = rounds(c) - fleet_server.done
        FleetStrategy(fleet_server, o, wait).start(grid, ArrayRecord(), num_rounds=remaining, timeout=wait)

    return server


server = server_app()  # the Deployment Engine's ServerApp: the run config names "config" and "out"


def run_simulation(
    cfg: Config, out: str | Path, backend_config: dict | None = None, round_timeout: float = 3600.0
) -> dict:
    """The run `cfg` on Flower's simulation engine (Ray on this machine), one node per robot;
    returns its summary (summary.json of the run directory `out`). `round_timeout`: the longest
    a round waits for the robots (the first round compiles every robot's program, on a few
    cores one after the other: 50 robots took over 10 minutes here)."""
    from flwr.simulation import run_simulation as flower_simulation

    resources = {"client_resources": {"num_cpus": 1, "num_gpus": 0.0}}
    backend = backend_config or resources
    flower_simulation(server_app(cfg, out, round_timeout), app, num_supernodes=cfg.num_robots, backend_config=backend)
    path = Path(out) / rundir.SUMMARY
    if not path.exists():
        raise FleetError(f"{out}: the simulation wrote no run directory (see Flower's log above)")
    return rundir.read_json(path)
