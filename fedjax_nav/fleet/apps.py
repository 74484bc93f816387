"""The Flower app (docs/fleet.md; needs `pip install "fedjax_nav[fleet]"`): `app` is the
ClientApp (one robot: `robot.Robot`, its program compiled once per process, its training state
kept in the node's context between rounds), `FleetStrategy` the server's strategy (the round's
exchange of `server.Server`, the in-program round's own function), `server_app` the ServerApp of
one run and `run_simulation` the whole run on Flower's simulation engine, one node per robot."""

from __future__ import annotations

import time
from pathlib import Path

import jax
import numpy as np
from flwr.app import Array, ArrayRecord, ConfigRecord, Context, Message, MessageType, MetricRecord, RecordDict
from flwr.clientapp import ClientApp
from flwr.serverapp import Grid, ServerApp
from flwr.serverapp.strategy import Strategy

from fedjax_nav import rundir
from fedjax_nav.config import Config, load_config
from fedjax_nav.fleet import wire
from fedjax_nav.fleet.robot import FleetError, Robot, rounds
from fedjax_nav.fleet.server import Server

app = ClientApp()
_ROBOTS: dict[tuple[str, int], Robot] = {}  # (config text, robot): one compiled program per process


def _numpy(record: ArrayRecord) -> dict[str, np.ndarray]:
    return {k: v.numpy() for k, v in record.items()}


def _record(arrays: dict) -> ArrayRecord:
    return ArrayRecord(array_dict={k: Array(np.ascontiguousarray(np.asarray(v))) for k, v in arrays.items()})


@app.train()
def train(msg: Message, context: Context) -> Message:
    """One round of robot `partition-id` (node config): take the server's last answer, train
    fed.period episodes, send its shared fields, reward and key, and its episodes' metrics."""
    text, index = str(msg.content["config"]["config"]), int(context.node_config["partition-id"])
    robot = _ROBOTS.get((text, index)) or _ROBOTS.setdefault((text, index), Robot(wire.config_from_text(text), index))
    kept = context.state.array_records.get("state")
    states = robot.init() if kept is None else robot.load(_numpy(kept))
    if "answer" in msg.content.array_records:
        states = robot.settle(states, _numpy(msg.content["answer"]))
    states, metrics = robot.train(states, int(msg.content["config"]["round"]))
    context.state["state"] = _record(wire.pack(states))
    sent = robot.sent(states)
    content = RecordDict(
        {
            "sent": _record(sent),
            "metrics": _record(jax.device_get(metrics)),
            "robot": MetricRecord({"index": index, "reward": float(sent["reward"][0])}),
        }
    )
    return Message(content, reply_to=msg)


class FleetStrategy(Strategy):
    """Every robot trains every round; the server's answer to robot i travels with round r + 1's
    message (the robots' node ids are learnt from their first replies)."""

    def __init__(self, server: Server, wait_s: float = 600.0):
        self.server, self.text, self.wait_s = server, wire.config_text(server.cfg), wait_s
        self.nodes: dict[int, int] = {}  # robot -> node id
        self.answers: list[dict] | None = None

    def configure_train(self, server_round: int, arrays: ArrayRecord, config: ConfigRecord, grid: Grid):
        n, start = self.server.trainer.num_robots, time.monotonic()
        while len(nodes := list(grid.get_node_ids())) < n:
            if time.monotonic() - start > self.wait_s:
                raise FleetError(f"round {server_round}: {len(nodes)} of {n} robots connected (env.worlds)")
            time.sleep(0.5)
        out = []
        for i, node in enumerate(nodes[:n]) if not self.nodes else self.nodes.items():
            content = RecordDict({"config": ConfigRecord({"config": self.text, "round": server_round - 1})})
            if self.answers is not None:
                content["answer"] = _record(self.answers[i])
            out.append(Message(content, dst_node_id=node, message_type=MessageType.TRAIN))
        return out

    def aggregate_train(self, server_round: int, replies):
        by_robot = {}
        for reply in replies:
            if reply.has_error():
                raise FleetError(f"round {server_round}: a robot failed: {reply.error.reason}")
            index = int(reply.content["robot"]["index"])
            self.nodes[index], by_robot[index] = reply.metadata.src_node_id, reply.content
        order = [by_robot[i] for i in sorted(by_robot)]
        self.answers = self.server.aggregate([_numpy(c["sent"]) for c in order])
        self.server.record([_numpy(c["metrics"]) for c in order])
        rewards = [float(c["robot"]["reward"]) for c in order]
        return None, MetricRecord({"reward": float(np.mean(rewards)), "clients": int(self.server.stats["clients"])})

    def configure_evaluate(self, server_round: int, arrays: ArrayRecord, config: ConfigRecord, grid: Grid):
        return []  # the held-out evaluation is `fedjax-nav evaluate` on the run directory

    def aggregate_evaluate(self, server_round: int, replies):
        return None

    def summary(self) -> None:
        tr = self.server.trainer
        print(f"FleetStrategy: {self.server.cfg.method} ({tr.round.rule}), {tr.num_robots} robots")


def server_app(cfg: Config | None = None, out: str | Path | None = None) -> ServerApp:
    """The ServerApp of the run `cfg` writing its run directory `out`; without them, from the run
    config's "config" (a config file or shipped name) and "out" (`flwr run`, docs/fleet.md)."""
    server = ServerApp()

    @server.main()
    def main(grid: Grid, context: Context) -> None:
        c = cfg if cfg is not None else load_config(str(context.run_config["config"]))
        fleet_server = Server(c)
        FleetStrategy(fleet_server).start(grid, ArrayRecord(), num_rounds=rounds(c))
        fleet_server.write(out if out is not None else str(context.run_config["out"]))

    return server


server = server_app()  # the Deployment Engine's ServerApp: the run config names "config" and "out"


def run_simulation(cfg: Config, out: str | Path, backend_config: dict | None = None) -> dict:
    """The run `cfg` on Flower's simulation engine (Ray on this machine), one node per robot;
    returns its summary (summary.json of the run directory `out`)."""
    from flwr.simulation import run_simulation as flower_simulation

    resources = {"client_resources": {"num_cpus": 1, "num_gpus": 0.0}}
    flower_simulation(
        server_app(cfg, out), app, num_supernodes=cfg.num_robots, backend_config=backend_config or resources
    )
    path = Path(out) / rundir.SUMMARY
    if not path.exists():
        raise FleetError(f"{out}: the simulation wrote no run directory (see Flower's log above)")
    return rundir.read_json(path)
