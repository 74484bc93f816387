"""Figures of the evaluation: the thesis's Figure 18-style bars and trajectories over the arena.

- `bars(summaries, path)`: success rate, completion time and trajectory efficiency (mean +- std
  over successful episodes) for every agent (solid) beside the best agent per seed (hatched,
  selected on evaluation data). One run with `per_goal=True`: one group per goal plus "all";
  several runs: one group per run (their overall numbers), the comparison figure.
- `trajectories(evaluation, path)`: one panel per goal, every agent's attempts over the world,
  a colour per agent, a gold star where an attempt reached the goal and a cross at a collision.
- `room_trajectories(worst, path)`: one panel per room of a suite (the worst rooms of a held-out
  suite evaluation, `worst_rooms.WorstRooms`), every agent's attempts to each goal, a colour per goal.

No pyplot: `matplotlib.figure.Figure` saved with the Agg canvas (the user's backend is untouched).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fedjax_nav import rundir

_ALL = "#1f77b4"
_BEST = "#ff7f0e"
# a colour per goal, none of the room's own (blue starts, green goals, brown boxes, red collisions)
_GOAL_COLORS = ("tab:orange", "tab:purple", "tab:pink", "tab:cyan", "tab:olive", "tab:gray", "gold", "black")


def _figure(w: float, h: float):
    from matplotlib.figure import Figure

    return Figure(figsize=(w, h), layout="constrained")


def _save(fig, path: Path, dpi: int = 100) -> Path:
    return rundir.save_figure(fig, path, dpi)


def _num(x) -> float:
    return np.nan if x is None else float(x)


def bars(summaries: dict[str, dict], path: str | Path, per_goal: bool = False, title: str = "") -> Path:
    """Figure 18-style bars. summaries: label -> an eval.json dict (several for a comparison)."""
    groups = []  # (name, all-agents stats, best-per-seed stats)
    if per_goal and len(summaries) == 1:
        s = next(iter(summaries.values()))
        best_goals = {g["goal"]: g for g in s["best_agent_per_seed"]["per_goal"]}
        for g in s["all_agents"]["per_goal"]:
            groups.append((f"G{g['goal']}", g, best_goals.get(g["goal"], {})))
        groups.append(("all", s["all_agents"]["overall"], s["best_agent_per_seed"]["overall"]))
    else:
        for label, s in summaries.items():
            groups.append((label, s["all_agents"]["overall"], s["best_agent_per_seed"]["overall"]))

    fig = _figure(max(9.0, 1.2 * len(groups) + 6.0), 3.4)
    axes = fig.subplots(1, 3)
    x = np.arange(len(groups))
    w = 0.38
    panels = [
        ("success_rate", None, "success rate", (0, 1.1)),
        ("time_mean", "time_std", "completion time (s)\n(successful runs)", None),
        ("efficiency_mean", "efficiency_std", "trajectory efficiency\n(successful runs)", (0, 1.05)),
    ]
    for ax, (key, err, ylabel, ylim) in zip(axes, panels):
        for j, (label, color, hatch) in enumerate([("all agents", _ALL, None), ("best agent per seed*", _BEST, "//")]):
            vals = np.array([_num(g[1 + j].get(key)) for g in groups])
            if err is not None:
                errs = np.array([_num(g[1 + j].get(err)) for g in groups])
            else:  # success: the spread over seeds (overall groups only)
                errs = np.array([_num(g[1 + j].get("success_seed_std")) for g in groups])
            ax.bar(
                x + (j - 0.5) * w,
                np.nan_to_num(vals),
                w,
                color=color,
                alpha=0.9 if j == 0 else 0.55,
                hatch=hatch,
                edgecolor="black",
                lw=0.5,
                label=label,
            )
            has = np.isfinite(errs) & np.isfinite(vals)  # error bars only where there is a spread
            if has.any():
                ax.errorbar(
                    (x + (j - 0.5) * w)[has], vals[has], yerr=errs[has], fmt="none", ecolor="black", capsize=3, lw=1
                )
            if key == "success_rate":
                for xi, v in zip(x + (j - 0.5) * w, vals):
                    if np.isfinite(v):
                        ax.annotate(
                            f"{v:.2f}",
                            (xi, v),
                            xytext=(0, 2),
                            textcoords="offset points",
                            ha="center",
                            va="bottom",
                            fontsize=6,
                        )
        ax.set_xticks(x, [g[0] for g in groups], fontsize=8, rotation=20 if len(groups) > 5 else 0)
        ax.set_ylabel(ylabel, fontsize=9)
        if ylim:
            ax.set_ylim(*ylim)
        ax.grid(axis="y", alpha=0.3)
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncol=2, fontsize=8)
    s0 = next(iter(summaries.values()))
    n = s0["noise"]
    fig.suptitle(
        (title + "\n" if title else "")
        + f"error bars: std (success: over seeds); noise range {n['range_noise']:g} m, action {n['action_noise']:g}; "
        "* selected on evaluation data",
        fontsize=8,
    )
    return _save(fig, path)


def _draw_world(ax, world, meta):
    try:
        from fedjax_nav.env.render import draw_world
    except ImportError:  # a minimal fallback: segments and circles
        from matplotlib.patches import Circle

        segs = np.asarray(world.segments).reshape(-1, 4)
        for x1, y1, x2, y2 in segs:
            if (x1, y1) != (x2, y2):
                ax.plot([x1, x2], [y1, y2], color="0.25", lw=1.5)
        for cx, cy, r in np.asarray(world.circles).reshape(-1, 3):
            if r > 0:
                ax.add_patch(Circle((cx, cy), r, color="0.5"))
        for gx, gy in np.asarray(world.goals)[: int(world.num_goals)]:
            ax.add_patch(Circle((gx, gy), 0.5, color="green", alpha=0.25))
        ax.set_aspect("equal")
        return ax
    return draw_world(ax, world, meta, title=False)


def _draw_paths(ax, paths, colors, outcomes):
    try:
        from fedjax_nav.env.render import draw_trajectories
    except ImportError:
        for p, c, o in zip(paths, colors, outcomes):
            ax.plot(p[:, 0], p[:, 1], color=c, lw=0.8, alpha=0.8)
            if o == "success":
                ax.plot([p[-1, 0]], [p[-1, 1]], marker="*", color="gold", mec="black", ms=9)
            elif o == "collision":
                ax.plot([p[-1, 0]], [p[-1, 1]], marker="X", color="red", mec="black", ms=6)
        return ax
    return draw_trajectories(ax, paths, colors=colors, outcomes=outcomes, lw=0.8, alpha=0.7)


def _episodes(r, idx, colors) -> tuple[list, list, list]:
    """The drawn paths of episodes `idx` (index tuples into r.poses' leading axes, r holding poses,
    steps, success, collision), their colours and outcomes (success, collision or time-out)."""
    paths = [r.poses[j][: int(r.steps[j]) + 1, :2] for j in idx]
    outcomes = ["success" if r.success[j] else "collision" if r.collision[j] else "timeout" for j in idx]
    return paths, colors, outcomes


def trajectories(ev, path: str | Path, max_agents: int | None = None) -> Path:
    """One panel per goal with every agent's attempts (a colour per agent). `ev` is a
    `runs.RunEvaluation`; max_agents draws only the first agents (default all)."""
    from matplotlib import colormaps

    r = ev.result
    A, G, K = r.shape
    A_draw = A if max_agents is None else min(A, max_agents)
    cmap = colormaps["viridis" if A_draw > 10 else "tab10"]
    agent_colors = [cmap(i / max(A_draw - 1, 1)) if A_draw > 10 else cmap(i % 10) for i in range(A_draw)]
    cols = min(G, 4)
    rows = -(-G // cols)
    from fedjax_nav.env.render import panel_inches, wrapped

    w_in, h_in = panel_inches(ev.world.size)
    fig = _figure(w_in * cols, h_in * rows + 0.9)
    axes = np.atleast_1d(fig.subplots(rows, cols)).ravel()
    s = ev.summary
    per_goal = {g["goal"]: g for g in s["all_agents"]["per_goal"]}
    for gi in range(G):
        ax = axes[gi]
        _draw_world(ax, ev.world, ev.world_meta)
        idx = [(a, gi, k) for a in range(A_draw) for k in range(K)]
        _draw_paths(ax, *_episodes(r, idx, [agent_colors[a] for a, _, _ in idx]))
        st = per_goal.get(int(r.goal_index[gi]), {})
        ax.set_title(
            f"goal G{int(r.goal_index[gi])} ({r.goals[gi, 0]:g}, {r.goals[gi, 1]:g}): "
            f"success {st.get('success_rate', float('nan')):.2f}",
            fontsize=9,
        )
    for ax in axes[G:]:
        ax.set_visible(False)
    n = s["noise"]
    title = (
        f"{s['method']} on {s['world']}: {A_draw} of {A} agent(s) x {K} attempts per goal "
        f"(colour = agent; * goal, x collision, o time-out); noise range {n['range_noise']:g} m, "
        f"action {n['action_noise']:g}"
    )
    fig.suptitle(wrapped(title, w_in * cols), fontsize=9)
    return _save(fig, path, dpi=90)


def room_trajectories(w, path: str | Path, max_agents: int | None = None, chosen: str = "of lowest success") -> Path:
    """One panel per room of `w` (a `worst_rooms.WorstRooms`): the room and every agent's attempts
    to each of its goals, a colour per goal (* goal reached, x collision, o time-out), titled with
    the room's family, room seed and its success, collision and time-out rates in the evaluation.
    max_agents draws only the first agents (default all); `chosen` says how the rooms were chosen."""
    from matplotlib.lines import Line2D

    n, A, G, K = w.success.shape
    A_draw = A if max_agents is None else min(A, max_agents)
    color = lambda g: _GOAL_COLORS[g % len(_GOAL_COLORS)]  # noqa: E731
    cols = min(n, 3)
    rows = -(-n // cols)
    fig = _figure(3.6 * cols, 3.6 * rows + 0.8)
    axes = np.atleast_1d(fig.subplots(rows, cols)).ravel()
    for i, room in enumerate(w.rooms.itertuples()):
        ax = axes[i]
        _draw_world(ax, w.room(i), None)
        idx = [(i, a, g, k) for a in range(A_draw) for g in range(int(w.num_goals[i])) for k in range(K)]
        _draw_paths(ax, *_episodes(w, idx, [color(g) for _, _, g, _ in idx]))
        seed = f", room seed {room.room_seed}" if room.room_seed >= 0 else ""
        ax.set_title(
            f"{room.family}{seed} (room {room.room})\nsuccess {room.success:.2f}, collision "
            f"{room.collision:.2f}, time-out {room.timeout:.2f}",
            fontsize=8,
        )
    for ax in axes[n:]:
        ax.set_visible(False)
    goals = [Line2D([], [], color=color(g), label=f"G{g}") for g in range(int(np.max(w.num_goals)))]
    fig.legend(handles=goals, loc="outside lower center", ncol=len(goals), fontsize=8, title="colour = goal")
    s = w.summary
    fig.suptitle(
        f"{s['method']} on suite '{s['suite']}': the {n} rooms {chosen} of {s['rooms']} (rates of the "
        f"evaluation: {s['attempts_per_agent']} attempt(s), T = {s['max_steps']})\n{A_draw} of {A} agent(s) x "
        f"{K} attempt(s) per goal replayed; * goal reached, x collision, o time-out",
        fontsize=8,
    )
    return _save(fig, path, dpi=90)
