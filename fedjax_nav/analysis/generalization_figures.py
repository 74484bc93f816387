"""The generalization experiment's figures (docs/generalization.md), from the tables of
`fedjax_nav.analysis.generalization`:

    figure(table, families, path)       success per family and in the arena, with seed CIs; one
                                        panel per learner (or whatever else tells points apart)
    probe_figure(curves, path)          the held-out probe during training, one panel per method
    point_names / curve_names           what names a point in them: its fleet and what else tells
                                        it apart besides method, fleet and budget
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from fedjax_nav import rundir
from fedjax_nav.analysis.plots import distinct_colors


def figure(t: pd.DataFrame, families: list[str], path: str | Path, target: dict, episodes: int | None = None) -> Path:
    """Grouped bars: for each held-out family and the arena, one bar per trained point (method x
    fleet; the points of `episodes` only, when given; one panel per value of whatever else tells
    points apart, e.g. the learner (`point_names`), where each panel holds two bars or more, else
    that value in the bar's name), height the mean over seeds, whiskers the 95%
    bootstrap interval over training seeds (families) or +- the seed std (arena); the sweep's goal
    (`target`) for the families dashed, for the arena dotted. A bar keeps its colour in every panel."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = t if episodes is None else t[t.episodes == episodes]
    fleet, other = point_names(t) if len(t) else (t.point, t.point)
    bar = t.method.str.upper() + ", " + fleet + ("" if episodes is not None else ", " + t.episodes.astype(str) + " ep.")
    if (other.value_counts() < 2).any():  # a panel of one bar (a sweep of configs or levers): one panel, named bars
        bar, other = bar + other.map(lambda o: f", {o}" if o else ""), other.map(lambda o: "")
    bars, panels = list(dict.fromkeys(bar)), list(dict.fromkeys(other)) or [""]
    groups = [*families, "arena"]
    n = max((other == o).sum() for o in panels) if len(t) else 1  # bars per group in the fullest panel
    fig, axes = plt.subplots(
        len(panels),
        1,
        figsize=(max(7.0, 1.6 * len(groups) + 0.3 * n), 1.0 + 3.4 * len(panels) + 0.16 * len(bars) / 2),
        sharex=True,
        squeeze=False,
        layout="constrained",
    )
    colors = dict(zip(bars, distinct_colors(len(bars))))
    for ax, o in zip(axes[:, 0], panels):
        rows = t[other == o]
        width = 0.8 / max(len(rows), 1)
        for i, (idx, r) in enumerate(rows.iterrows()):
            x = np.arange(len(groups)) + (i - (len(rows) - 1) / 2) * width
            y = np.array([r.get(f, np.nan) for f in families] + [r.arena], float)
            lo = np.array([r.get(f"{f}_ci_seeds_low", np.nan) for f in families] + [r.arena - r.arena_seed_std], float)
            hi = np.array([r.get(f"{f}_ci_seeds_high", np.nan) for f in families] + [r.arena + r.arena_seed_std], float)
            err = np.nan_to_num(np.stack([y - lo, hi - y]).clip(min=0))
            ax.bar(x, np.nan_to_num(y), width, yerr=err, capsize=2, label=bar[idx], color=colors[bar[idx]])
        for key, ls in (("family", "--"), ("arena", ":")):
            if key in target:
                ax.axhline(target[key], ls=ls, c="gray", lw=0.8)
        ax.set_ylim(0, 1.05)
        ax.set_ylabel("success (all agents)")
        if o:
            ax.set_title(o, fontsize=9, loc="left")
    axes[-1, 0].set_xticks(range(len(groups)), groups)
    fig.suptitle("held-out families and the thesis arena" + (f", {episodes} training episodes" if episodes else ""))
    handles = {}  # each bar's name once, from whichever panel holds it
    for ax in axes[:, 0]:
        handles.update({lb: h for h, lb in zip(*ax.get_legend_handles_labels()) if lb not in handles})
    ncol = 1 if max(map(len, handles)) > 50 else 2  # long names one per line, inside the figure's width
    fig.legend(handles.values(), handles.keys(), loc="outside lower center", fontsize=7, ncol=ncol)  # never over bars
    out = rundir.save_figure(fig, path)
    plt.close(fig)
    return out


def label_parts(label: str) -> list[str]:
    """A point label's `key=value` parts; a tuple's commas stay inside its part."""
    import re

    return re.split(r", (?=[A-Za-z_][\w.]*=)", label)


def distinct_parts(labels: list[str]) -> dict[str, str]:
    """Each point label ("method=snddpg, env.room_families=('mixture',), ppo.gamma=0.99") less the
    `key=value` parts every label shares: what tells the points apart ("ppo.gamma=0.99"); a label
    with nothing of its own stays whole."""
    parts = {lbl: label_parts(lbl) for lbl in labels}
    common = set.intersection(*(set(p) for p in parts.values())) if len(labels) > 1 else set()
    return {lbl: ", ".join(x for x in p if x not in common) or lbl for lbl, p in parts.items()}


# label parts a probe curve's name leaves out: the panel's title, the fleet (named from `rooms`),
# the budget (the longest of each curve is drawn)
_PANEL_PARTS = ("method=", "env.room_families=", "run.episodes=")


def point_names(t: pd.DataFrame) -> tuple[pd.Series, pd.Series]:
    """Per row of a table or curve frame (columns point, rooms, label): its fleet ('heterogeneous',
    'procedural'; the whole `rooms` text where two fleets share the word) and what else tells its
    point apart besides the method, the fleet and the budget ('config=td3'; '' where nothing does)."""
    points = t.drop_duplicates("point")
    short = points.rooms.str.split(" (", regex=False).str[0]
    fleet = short.where(points.groupby(short).rooms.transform("nunique") == 1, points.rooms)
    rest = {lbl: ", ".join(x for x in label_parts(lbl) if not x.startswith(_PANEL_PARTS)) for lbl in points.label}
    own = distinct_parts(list(dict.fromkeys(rest.values()))) if len(set(rest.values())) > 1 else {}
    others = {pt: own.get(rest[lbl], "") for pt, lbl in zip(points.point, points.label)}
    return t.point.map(dict(zip(points.point, fleet))), t.point.map(others)


def curve_names(curves: pd.DataFrame) -> pd.Series:
    """Each probe curve's name, the same in every method's panel: its fleet and what else tells its
    point apart (`point_names`), e.g. 'heterogeneous, config=td3'."""
    fleet, other = point_names(curves)
    return fleet.str.cat(other, sep=", ").str.rstrip(", ")


def probe_figure(curves: pd.DataFrame, path: str | Path) -> Path:
    """One panel per method: the probe's success against the episode for each fleet (and whatever
    else tells points apart: `curve_names`, one colour per name in every panel), the longest budget
    of each (it holds the shorter ones' curves); band = +- seed std, dotted = training success."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    curves = curves.assign(name=curve_names(curves))
    longest = curves[curves.budget == curves.groupby(["method", "name"]).budget.transform("max")]
    methods = list(dict.fromkeys(longest.method))
    names = list(dict.fromkeys(longest.name))
    palette = distinct_colors(len(names))  # one colour per curve name in every panel
    fig, axes = plt.subplots(1, len(methods), figsize=(max(4.2 * len(methods), 6.4), 3.6), sharey=True, squeeze=False)
    for ax, m in zip(axes[0], methods):
        for name, c in longest[longest.method == m].groupby("name", sort=False):
            color = palette[names.index(name)]
            (line,) = ax.plot(c.episode + 1, c.probe, label=name, c=color)
            ax.fill_between(
                c.episode + 1, c.probe - c.probe_seed_std, c.probe + c.probe_seed_std, alpha=0.2, color=color
            )
            ax.plot(c.episode + 1, c.train, ls=":", c=line.get_color(), lw=0.8)
        ax.set_title(m.upper())
        ax.set_xlabel("episode")
        ax.set_ylim(0, 1)
    axes[0][0].set_ylabel("held-out probe success (solid),\ntraining (dotted)")
    legend = {}  # every panel's curves, each name once (a fleet may be missing from the last panel)
    for ax in axes[0]:
        legend.update({n: h for h, n in zip(*ax.get_legend_handles_labels()) if n not in legend})
    names, handles = list(legend), list(legend.values())
    if len(names) <= 4:
        axes[0][-1].legend(handles, names, fontsize=7, loc="lower right")
        fig.tight_layout()
    else:  # many curves: the legend under the panels
        fig.legend(handles, names, fontsize=7, loc="lower center", ncol=min(3, len(names)), frameon=False)
        fig.tight_layout(rect=(0, 0.05 + 0.045 * -(-len(names) // 3), 1, 1))
    out = rundir.save_figure(fig, path)
    plt.close(fig)
    return out
