"""The metrics of the evaluation (docs/evaluation.md): one row per episode, then per goal and
overall, for every agent (the headline) and for the best agent per seed (selected on the
evaluation episodes themselves, and marked so).

    episodes_frame(result, agent_seed, agent_net, agent_byzantine) -> DataFrame   one row per episode
    summarize(frame) -> dict                                      what eval.json's metrics hold

A run with Byzantine robots (`fed.byzantine`) is also summarized for its honest agents and its
Byzantine ones separately (`honest_agents`, `byzantine_agents`); `all_agents` stays every agent.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from fedjax_nav.evaluation.rollout import EvalResult

SELECTED_NOTE = "selected on evaluation data (best agent per seed by evaluation success rate)"
STRAIGHT_LINE_NOTE = (
    "straight_line = |goal - start| - goal_radius (the episode succeeds on entering the goal "
    "radius); efficiency = straight_line / path_length, successful episodes only"
)


def episodes_frame(
    result: EvalResult,
    agent_seed: np.ndarray | None = None,
    agent_net: np.ndarray | None = None,
    agent_byzantine: np.ndarray | None = None,
) -> pd.DataFrame:
    """One row per episode: agent, seed, net, byzantine (0/1), goal, attempt and the per-episode
    measurements."""
    A, G, K = result.shape
    a, g, k = np.meshgrid(np.arange(A), np.arange(G), np.arange(K), indexing="ij")
    seed = np.zeros(A, int) if agent_seed is None else np.asarray(agent_seed)
    net = np.arange(A) if agent_net is None else np.asarray(agent_net)
    byz = np.zeros(A, int) if agent_byzantine is None else np.asarray(agent_byzantine).astype(int)
    goal_row = result.goal_index[g.ravel()]
    outcome = np.where(
        result.success, "success", np.where(result.collision, "collision", np.where(result.timeout, "timeout", "other"))
    )
    return pd.DataFrame(
        {
            "agent": a.ravel(),
            "seed": seed[a.ravel()],
            "net": net[a.ravel()],
            "byzantine": byz[a.ravel()],
            "goal": goal_row,
            "attempt": k.ravel(),
            "goal_x": result.goals[g.ravel(), 0],
            "goal_y": result.goals[g.ravel(), 1],
            "success": result.success.ravel().astype(int),
            "collision": result.collision.ravel().astype(int),
            "timeout": result.timeout.ravel().astype(int),
            "outcome": outcome.ravel(),
            "steps": result.steps.ravel(),
            "time_s": result.time_s.ravel(),
            "path_length": result.path_length.ravel().astype(np.float64),
            "start_goal_distance": result.start_goal_distance[g.ravel()],
            "straight_line": result.straight_line[g.ravel()],
            "efficiency": result.efficiency.ravel(),
        }
    )


def _stats(df: pd.DataFrame) -> dict:
    """Success rate; time and efficiency mean/std (ddof=0) over successful episodes."""
    ok = df[df["success"] == 1]
    n, s = len(df), len(ok)

    def ms(col):
        if s == 0:
            return None, None
        x = ok[col].to_numpy(np.float64)
        return float(np.mean(x)), float(np.std(x))

    tm, ts = ms("time_s")
    em, es = ms("efficiency")
    return {
        "episodes": int(n),
        "successes": int(s),
        "collisions": int(df["collision"].sum()),
        "timeouts": int(df["timeout"].sum()),
        "success_rate": float(s / n) if n else None,
        "time_mean": tm,
        "time_std": ts,
        "efficiency_mean": em,
        "efficiency_std": es,
    }


def _block(df: pd.DataFrame) -> dict:
    per_goal = []
    for g, sub in df.groupby("goal", sort=True):
        per_goal.append(
            {"goal": int(g), "xy": [float(sub["goal_x"].iloc[0]), float(sub["goal_y"].iloc[0])], **_stats(sub)}
        )
    per_seed = df.groupby("seed")["success"].mean()
    out = {
        "overall": _stats(df),
        "per_goal": per_goal,
        "success_per_seed": {str(int(k)): float(v) for k, v in per_seed.items()},
    }
    out["overall"]["success_seed_std"] = float(np.std(per_seed.to_numpy())) if len(per_seed) else None
    return out


def best_agents(df: pd.DataFrame) -> list[int]:
    """The best agent of each seed: highest success rate, then shortest mean successful time,
    then lowest index. Chosen on the evaluation episodes themselves (see SELECTED_NOTE)."""
    per = df.groupby("agent").agg(seed=("seed", "first"), success=("success", "mean"))
    t = df[df["success"] == 1].groupby("agent")["time_s"].mean()
    per["time"] = t.reindex(per.index).fillna(np.inf)
    per = per.reset_index().sort_values(["seed", "success", "time", "agent"], ascending=[True, False, True, True])
    return [int(a) for a in per.groupby("seed")["agent"].first()]


def summarize(df: pd.DataFrame) -> dict:
    """The two aggregations: every agent (the headline) and the best agent per seed; with
    Byzantine agents in the frame also the honest and the Byzantine agents apart (the best agent
    per seed is then chosen among the honest ones)."""
    if "byzantine" not in df:  # frames written before the column existed
        df = df.assign(byzantine=0)
    byz = df["byzantine"].astype(bool)
    best = best_agents(df[~byz] if byz.any() else df)
    per_agent = df.groupby("agent").agg(
        seed=("seed", "first"), net=("net", "first"), byzantine=("byzantine", "first"), success_rate=("success", "mean")
    )
    out = {
        "all_agents": _block(df),
        "best_agent_per_seed": {"note": SELECTED_NOTE, "agents": best, **_block(df[df["agent"].isin(best)])},
        "per_agent": [
            {
                "agent": int(a),
                "seed": int(r.seed),
                "net": int(r.net),
                "byzantine": bool(r.byzantine),
                "success_rate": float(r.success_rate),
            }
            for a, r in per_agent.iterrows()
        ],
    }
    if byz.any():
        out["honest_agents"] = _block(df[~byz])
        out["byzantine_agents"] = _block(df[byz])
    return out
