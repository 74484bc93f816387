"""The statistics of a suite evaluation's episodes (evaluation.suite writes them): per family and
over all rooms, the success with 95 % bootstrap intervals over rooms and over training seeds, the
tail (the worst 10 % of rooms with its interval, collision and time-out rates, the path-length ratio
to the shortest safe path) and the split by detour (success where the goal lies on a clear straight
line and where it needs a detour); docs/generalization.md, "Tail metrics"."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

RESAMPLES = 10_000
WORST = 0.10  # the tail: the worst 10 % of rooms
DETOUR = 1.05  # a goal whose shortest safe path is longer than 1.05 x the straight line needs a detour
TAIL = (
    "worst10: mean success of the worst ceil(10%) of rooms (rooms ranked by their success over agents, "
    "goals, attempts), worst10_ci_* its 95% percentile bootstrap interval over rooms; collision, timeout: "
    "shares of episodes; path_ratio_median: median over successful episodes of path_length / shortest_path "
    "(the shortest path from the start into the goal disk keeping the collision distance: an 8-connected "
    "grid search, then the string pulled tight with exact clearance checks; fedjax_nav.evaluation.paths); "
    "success_direct, success_detour: success over the episodes whose goal's shortest_path is at most / more "
    "than 1.05 x straight_line (|goal - start| - goal radius), detour_share: the share of the latter"
)


def worst_mean(x, axis: int = -1):
    """The mean of the lowest ceil(WORST * n) of the n values along `axis` (at least one): the
    worst 10 % of rooms' success. Vectorised over the other axes (scipy.stats.bootstrap)."""
    x = np.sort(np.asarray(x, np.float64), axis=axis)
    k = max(1, math.ceil(WORST * x.shape[axis] - 1e-9))
    return np.take(x, np.arange(k), axis=axis).mean(axis=axis)


def bootstrap_ci(x, confidence: float = 0.95, seed: int = 0, statistic=np.mean) -> tuple[float, float]:
    """95 % percentile bootstrap interval of `statistic` (default the mean; vectorised, with an
    `axis` argument) of `x` (scipy.stats.bootstrap); (nan, nan) for fewer than two values, (m, m)
    when every value is m."""
    from scipy import stats

    x = np.asarray(x, np.float64)
    if len(x) < 2:
        return float("nan"), float("nan")
    if np.all(x == x[0]):
        return float(x[0]), float(x[0])
    res = stats.bootstrap(
        (x,),
        statistic,
        confidence_level=confidence,
        n_resamples=RESAMPLES,
        method="percentile",
        random_state=np.random.default_rng(seed),
    )
    return float(res.confidence_interval.low), float(res.confidence_interval.high)


def family_row(name: str, ep: pd.DataFrame) -> dict:
    per_room = ep.groupby("room")["success"].mean().to_numpy()
    per_seed = ep.groupby("seed")["success"].mean().to_numpy()
    lo_r, hi_r = bootstrap_ci(per_room)
    lo_s, hi_s = bootstrap_ci(per_seed)
    lo_w, hi_w = bootstrap_ci(per_room, statistic=worst_mean)
    ratio = ep["path_ratio"].to_numpy(np.float64)
    ratio = ratio[np.isfinite(ratio)]
    return {
        "family": name,
        "rooms": int(len(per_room)),
        "episodes": int(len(ep)),
        "success": float(ep["success"].mean()),
        "ci_rooms_low": lo_r,
        "ci_rooms_high": hi_r,
        "seeds": int(len(per_seed)),
        "ci_seeds_low": lo_s,
        "ci_seeds_high": hi_s,
        "collision": float(ep["collision"].mean()),
        "timeout": float(ep["timeout"].mean()),
        # the honest agents' success when the run had Byzantine robots (fed.byzantine), else NaN
        "success_honest": float(ep.loc[ep.byzantine == 0, "success"].mean()) if ep.byzantine.any() else float("nan"),
        "worst10": float(worst_mean(per_room)) if len(per_room) else float("nan"),
        "worst10_rooms": max(1, math.ceil(WORST * len(per_room) - 1e-9)) if len(per_room) else 0,
        "worst10_ci_low": lo_w,
        "worst10_ci_high": hi_w,
        "path_ratio_median": float(np.median(ratio)) if len(ratio) else float("nan"),
        "path_ratio_episodes": int(len(ratio)),
        **detour_split(ep),
    }


def detour_split(ep: pd.DataFrame) -> dict:
    """Success where the goal is reached by (nearly) the straight line and where it needs a detour."""
    detour = (ep["shortest_path"] > DETOUR * ep["straight_line"]).to_numpy()
    mean = lambda x: float(x.mean()) if len(x) else float("nan")  # noqa: E731
    sx = ep["success"].to_numpy()
    return {"detour_share": mean(detour), "success_direct": mean(sx[~detour]), "success_detour": mean(sx[detour])}


def pool_seeds(named: list[tuple[str, pd.DataFrame]]) -> pd.DataFrame:
    """The episodes of several evaluations whose runs trained other seeds of one config (e.g. seeds
    0-1 and 2-3), or the same seeds with other robots per room (a shared-room evaluation's K = 4 in
    one folder and K = 1, 2, 8 in another), as one frame; ValueError naming the first evaluation
    whose seeds are pooled already (for one of its K, where the frames have robots_per_room)."""
    seen: set = set()
    for name, ep in named:
        keys = set(zip(ep["seed"], ep["robots_per_room"] if "robots_per_room" in ep else [None] * len(ep)))
        if seen & keys:
            raise ValueError(f"{name}: its seeds {sorted({s for s, _ in seen & keys})} are pooled already")
        seen |= keys
    return pd.concat([ep for _, ep in named], ignore_index=True)
