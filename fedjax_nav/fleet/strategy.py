"""The fleet server's Flower strategy (docs/fleet.md): which node is which robot, one round's
messages, the replies that arrived in time (a robot that fails or is killed mid-round is an
absent client of that round), the run directory written after every round."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
from flwr.app import Array, ArrayRecord, ConfigRecord, Message, MessageType, MetricRecord, RecordDict
from flwr.common import log
from flwr.serverapp import Grid
from flwr.serverapp.strategy import Strategy

from fedjax_nav.fleet import wire
from fedjax_nav.fleet.robot import FleetError
from fedjax_nav.fleet.server import Server

WARNING = 30  # logging.WARNING


def numpy_of(record: ArrayRecord) -> dict[str, np.ndarray]:
    return {k: v.numpy() for k, v in record.items()}


def record_of(arrays: dict) -> ArrayRecord:
    return ArrayRecord(array_dict={k: Array(np.ascontiguousarray(np.asarray(v))) for k, v in arrays.items()})


class FleetStrategy(Strategy):
    """Every robot present trains every round. Before the first round the strategy waits (at most
    `wait_s`) for every robot; later rounds go on with the robots whose nodes are online after a
    grace of `rejoin_s` (a restarted robot's new node is asked which robot it is and rejoins)."""

    def __init__(self, server: Server, out: str | Path, wait_s: float = 600.0, rejoin_s: float = 10.0):
        self.server, self.out, self.text = server, out, wire.config_text(server.cfg)
        self.wait_s, self.rejoin_s = wait_s, rejoin_s
        self.nodes: dict[int, int] = {}  # robot -> node id
        self.strangers: set[int] = set()  # nodes that are no robot of this run

    def _learn_nodes(self, grid: Grid, online: set[int]) -> None:
        unknown = online - set(self.nodes.values()) - self.strangers
        if not unknown:
            return
        ask = [
            Message(RecordDict({"config": ConfigRecord({})}), dst_node_id=n, message_type=MessageType.QUERY)
            for n in unknown
        ]
        for reply in grid.send_and_receive(ask, timeout=self.wait_s):
            node = reply.metadata.src_node_id
            index = -1 if reply.has_error() else int(reply.content["robot"]["index"])
            if 0 <= index < self.server.n:
                self.nodes[index] = node
            else:
                self.strangers.add(node)

    def present(self, grid: Grid) -> list[int]:
        """The robots whose nodes are online (all of them before the first round)."""
        start, n = time.monotonic(), self.server.n
        while True:
            online = set(grid.get_node_ids())
            self._learn_nodes(grid, online)
            live = sorted(i for i, node in self.nodes.items() if node in online)
            waited = time.monotonic() - start
            if len(live) == n or (self.server.done > 0 and live and waited > self.rejoin_s):
                return live
            if waited > self.wait_s:
                raise FleetError(f"round {self.server.done + 1}: {len(live)} of {n} robots connected (env.worlds)")
            time.sleep(0.5)

    def configure_train(self, server_round: int, arrays: ArrayRecord, config: ConfigRecord, grid: Grid):
        out, self._start, self._down = [], time.monotonic(), 0
        for i in self.present(grid):
            content = RecordDict({"config": ConfigRecord({"config": self.text, "round": self.server.done})})
            if (answer := self.server.answer(i)) is not None:
                content["answer"] = record_of(answer)
                self._down += sum(np.asarray(v).nbytes for v in answer.values())
            out.append(Message(content, dst_node_id=self.nodes[i], message_type=MessageType.TRAIN))
        return out

    def aggregate_train(self, server_round: int, replies):
        sends, metrics, train_s = {}, {}, []
        for reply in replies:
            if reply.has_error():
                log(WARNING, "round %s: a robot did not answer: %s", self.server.done + 1, reply.error.reason)
                continue
            index = int(reply.content["robot"]["index"])
            sends[index], metrics[index] = numpy_of(reply.content["sent"]), numpy_of(reply.content["metrics"])
            train_s.append(float(reply.content["robot"]["train_s"]))
        refused = self.server.aggregate(sends)
        for i, why in refused.items():
            log(WARNING, "round %s: robot %s's send refused: %s", self.server.done, i, why)
        self.server.record(metrics)
        self.server.rounds_log.append(
            {
                "round": self.server.done,
                "answered": len(sends),
                "refused": len(refused),
                "wall_s": time.monotonic() - self._start,
                "robot_train_s_max": max(train_s, default=0.0),
                "bytes_to_robots": self._down,  # payload: the answers' arrays (the config text not counted)
                "bytes_params_from_robots": sum(a.nbytes for s in sends.values() for a in s.values()),
                "bytes_metrics_from_robots": sum(a.nbytes for m in metrics.values() for a in m.values()),
            }
        )
        self.server.write(self.out)
        reward = float(np.mean([s["reward"] for i, s in sends.items() if i not in refused]))
        return None, MetricRecord({"reward": reward, "clients": int(self.server.stats["clients"])})

    def configure_evaluate(self, server_round: int, arrays: ArrayRecord, config: ConfigRecord, grid: Grid):
        return []  # the held-out evaluation is `fedjax-nav evaluate` on the run directory

    def aggregate_evaluate(self, server_round: int, replies):
        return None

    def summary(self) -> None:
        tr, done = self.server.trainer, self.server.done
        resumed = f", resumed after round {done}" if done else ""
        print(f"FleetStrategy: {self.server.cfg.method} ({tr.round.rule}), {tr.num_robots} robots{resumed}")
