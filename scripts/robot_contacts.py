"""How robots that share a room touch (docs/shared_rooms.md, "How the robots touch"): a run's
agents evaluated with K robots per room (the protocol of `fedjax-nav evaluate --robots-per-room`,
the same keys), every robot-robot collision taken apart from the trajectories: how the two robots
were heading (head-on, crossing, the same way), where the other robot was (in front, beside,
behind), how fast each drove over the last second, and for how many steps the other had been
within 1 m before the contact, and the room the two had to pass (the contact midpoint's distance
to the nearest wall or obstacle: under 2 D_c two discs cannot stand abreast there). Writes
`contacts.csv` (one row per robot-robot collision), `contacts.json` (the shares) and
`contacts.png` (the last 6 s of the first contacts). The obstacle contacts too, one row each in
`obstacles.csv`: which other robot was nearest and how near, and whether the robot had given way
(stood and turned right at full rate, `env.give_way`) within the last 3 s, and `obstacles.png` (the
last 6 s of the first eight with another robot within 1 m, over the walls). With --collect, the
table of several such folders (one row each) instead.

    python scripts/robot_contacts.py RUN --set env.plan_margin=0.3 --set env.plan_lookahead=0.5 \
        --set env.plan_cells=128 --suite mixture-50 --robots-per-room 4 --out runs/x/contacts
    python scripts/robot_contacts.py --collect "alone"=runs/x/a "shared"=runs/x/b --csv results/robot_contacts.csv
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from fedjax_nav.deploy.policy_inputs import wrap_angle

NEAR = 1.0  # m: "the other robot is near" (two discs of 0.25 m and a robot's length)
SPEED_WINDOW = 10  # steps over which a robot's speed is measured before the contact
HEADINGS = ((45.0, "same way"), (135.0, "crossing"), (180.0, "head-on"))  # |heading difference| <= deg
BEARINGS = ((45.0, "in front"), (135.0, "beside"), (180.0, "behind"))  # |the other's bearing| <= deg
STILL = 0.02  # m/s: a robot slower than this over the window stood still
# The room to pass: two robots abreast, each D_c from the walls and 2 D_c apart, need a way 4 D_c
# wide, a midpoint at least 2 D_c from the nearest wall when centred (worlds.CLEARANCE = D_c).
ABREAST = 2.0
GAVE_WAY_WINDOW = 30  # steps (3 s) before an obstacle contact searched for a give-way step


def _wrap_deg(a: np.ndarray) -> np.ndarray:
    """|a| in degrees, a wrapped to [-pi, pi] as the simulator wraps it."""
    return np.abs(np.degrees(wrap_angle(a)))


def _bin(value: float, bins) -> str:
    return next(name for hi, name in bins if value <= hi + 1e-9)


def _still_in_room(steps: np.ndarray, i: int, s: int) -> list[int]:
    """The robots other than `i` whose episodes had not ended before step `s`."""
    return [j for j in range(len(steps)) if j != i and steps[j] >= s]


def contacts(poses: np.ndarray, steps: np.ndarray, robot_collision: np.ndarray, dt: float) -> pd.DataFrame:
    """One row per robot whose episode ended in a robot-robot collision, for one room's fleet:
    `poses` [T + 1, k, 3] (poses[t] after step t), `steps` [k] (a robot's last step), `robot_collision`
    bool [k]. The partner is the nearest robot still in the room at that step."""
    rows = []
    for i in np.flatnonzero(robot_collision):
        s = int(steps[i])
        live = _still_in_room(steps, i, s)
        if not live:  # cannot happen: a contact needs another robot in the room
            continue
        d = np.linalg.norm(poses[s, live, :2] - poses[s, i, :2], axis=-1)
        j = live[int(np.argmin(d))]
        pi, pj = poses[s, i], poses[s, j]
        heading = float(_wrap_deg(pj[2] - pi[2]))
        bearing = float(_wrap_deg(np.arctan2(pj[1] - pi[1], pj[0] - pi[0]) - pi[2]))
        w = min(SPEED_WINDOW, s)
        speed = np.linalg.norm(poses[s, :, :2] - poses[s - w, :, :2], axis=-1) / (max(w, 1) * dt)  # [k] m/s
        gap = np.linalg.norm(poses[: s + 1, j, :2] - poses[: s + 1, i, :2], axis=-1)
        far = np.flatnonzero(gap >= NEAR)
        rows.append(
            {
                "robot": int(i),
                "other": int(j),
                "step": s,
                "heading_diff_deg": heading,
                "kind": _bin(heading, HEADINGS),
                "bearing_deg": bearing,
                "where": _bin(bearing, BEARINGS),
                "speed": float(speed[i]),
                "other_speed": float(speed[j]),
                "near_steps": s - int(far[-1]) if far.size else s,
                "distance": float(np.min(d)),
            }
        )
    return pd.DataFrame(rows)


def wall_contacts(poses: np.ndarray, steps: np.ndarray, collision: np.ndarray, turn: float) -> pd.DataFrame:
    """One row per robot whose episode ended in an obstacle collision, for one room's fleet (as
    `contacts`): `other_distance`, m between its centre and the nearest other robot's still in
    the room (inf: none), and `gave_way_steps`, its steps within the last GAVE_WAY_WINDOW in which
    it stood still and turned right by at least 0.9 `turn` (omega_max dt: the move of
    `env.give_way`)."""
    rows = []
    for i in np.flatnonzero(collision):
        s = int(steps[i])
        live = _still_in_room(steps, i, s)
        d = np.linalg.norm(poses[s, live, :2] - poses[s, i, :2], axis=-1) if live else np.array([np.inf])
        seg = poses[max(s - GAVE_WAY_WINDOW, 0) : s + 1, i]
        stood = np.linalg.norm(np.diff(seg[:, :2], axis=0), axis=-1) < 1e-4
        right = wrap_angle(np.diff(seg[:, 2])) < -0.9 * turn
        other = int(live[int(np.argmin(d))]) if live else -1
        rows.append(
            {"robot": int(i), "step": s, "other": other, "other_distance": float(d.min())}
            | {"gave_way_steps": int((stood & right).sum())}
        )
    return pd.DataFrame(rows, columns=["robot", "step", "other", "other_distance", "gave_way_steps"])


def wall_shares(df: pd.DataFrame) -> dict:
    """The obstacle contacts' count, the share with another robot within NEAR, the share after giving way."""
    if df.empty:
        return {"obstacle_contacts": 0}
    return {
        "obstacle_contacts": len(df),
        "obstacle_other_near": round(float((df.other_distance < NEAR).mean()), 3),
        "obstacle_after_giving_way": round(float((df.gave_way_steps > 0).mean()), 3),
    }


def room_to_pass(df: pd.DataFrame, poses: np.ndarray, world) -> pd.DataFrame:
    """`df` with `wall_clearance` (m from the contact's midpoint, between the two robots' centres,
    to the nearest wall or obstacle of its room; the env's exact distance) and `narrow` (that
    clearance under ABREAST x D_c). `poses` [rooms, agents, T + 1, k, 3]; `world` World [rooms]."""
    if df.empty:
        return df.assign(wall_clearance=[], narrow=[])
    import jax

    from fedjax_nav.env.geometry import nearest_distance
    from fedjax_nav.worlds import CLEARANCE

    r, a, s, i, j = (df[c].to_numpy(np.int64) for c in ("room", "agent", "step", "robot", "other"))
    mid = (poses[r, a, s, i, :2] + poses[r, a, s, j, :2]) / 2
    rows = jax.tree.map(lambda x: x[r], world)
    d = jax.vmap(lambda w, p: nearest_distance(w.segments, p, w.circles))(rows, mid.astype(np.float32))
    d = np.asarray(jax.device_get(d), np.float64)
    return df.assign(wall_clearance=d, narrow=d < ABREAST * CLEARANCE)


def shares(df: pd.DataFrame) -> dict:
    """The shares of the contacts by kind, by where the other was, by who stood still."""
    if df.empty:
        return {"contacts": 0}
    still = (df.speed < STILL) | (df.other_speed < STILL)
    return {
        "contacts": len(df),
        "kind": df.kind.value_counts(normalize=True).round(3).to_dict(),
        "where": df["where"].value_counts(normalize=True).round(3).to_dict(),
        "one_stood_still": round(float(still.mean()), 3),
        "near_steps_median": float(df.near_steps.median()),
        **({"narrow": round(float(df.narrow.mean()), 3)} if "narrow" in df else {}),
        "speed_median": round(float(df.speed.median()), 3),  # both robots of a contact: one row each
    }


def _pair(ax, poses: np.ndarray, s: int, robot: int, other: int, back: int) -> np.ndarray:
    """The last `back` steps to step `s` of `robot` (solid) and `other` (dashed) on `ax`, centred on
    the robot at `s` (returned), each a disc of D_c with its heading; a window of 3.2 m."""
    from matplotlib.patches import Circle

    from fedjax_nav.evaluation.shared_rooms import ROBOT_DISC

    c = poses[s, robot, :2]
    for r, style in ((robot, "-"), (other, "--")):
        xy = poses[max(0, s - back) : s + 1, r, :2] - c
        (line,) = ax.plot(xy[:, 0], xy[:, 1], style, lw=1.5)
        ax.add_patch(Circle(tuple(xy[-1]), ROBOT_DISC, alpha=0.3, color=line.get_color()))
        ahead = xy[-1] + 0.35 * np.array([np.cos(poses[s, r, 2]), np.sin(poses[s, r, 2])])
        ax.annotate("", ahead, xy[-1], arrowprops={"arrowstyle": "->", "color": line.get_color()})
    ax.set_aspect("equal")
    ax.set_xlim(-1.6, 1.6)
    ax.set_ylim(-1.6, 1.6)
    return c


def figure(panels: list, out: Path, dt: float) -> Path:
    """The last 6 s before each of the first contacts, the two robots' paths (the robot solid,
    the other dashed) centred on the contact, each robot a disc of D_c with its heading."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(3.0 * min(len(panels), 4), 3.0 * ((len(panels) + 3) // 4)), layout="constrained")
    back = int(round(6.0 / dt))
    for n, (row, poses) in enumerate(panels):
        ax = fig.add_subplot((len(panels) + 3) // 4, min(len(panels), 4), n + 1)
        _pair(ax, poses, int(row.step), int(row.robot), int(row.other), back)
        ax.set_title(f"{row.kind}, other {row['where']}", fontsize=9)
    path = out / "contacts.png"
    fig.savefig(path, dpi=100)
    return path


def wall_figure(panels: list, out: Path, dt: float) -> Path:
    """The last 6 s before each of the first obstacle contacts with another robot within 1 m: the
    robot (solid) and the nearest other (dashed), discs of D_c with their headings, centred on the
    robot at the contact, over the room's walls and obstacles (grey)."""
    from matplotlib.figure import Figure
    from matplotlib.patches import Circle

    rows_n, cols = (len(panels) + 3) // 4, min(len(panels), 4)
    fig = Figure(figsize=(3.0 * cols, 3.0 * rows_n), layout="constrained")
    back = int(round(6.0 / dt))
    for n, (row, poses, segments, circles) in enumerate(panels):
        ax = fig.add_subplot(rows_n, cols, n + 1)
        c = _pair(ax, poses, int(row.step), int(row.robot), int(row.other), back)
        for x1, y1, x2, y2 in segments:
            ax.plot([x1 - c[0], x2 - c[0]], [y1 - c[1], y2 - c[1]], color="0.4", lw=2)
        for cx, cy, r in circles[circles[:, 2] > 0]:
            ax.add_patch(Circle((cx - c[0], cy - c[1]), r, color="0.6"))
        ax.set_title(f"room {int(row.room)}, gave way {int(row.gave_way_steps)} steps", fontsize=9)
    path = out / "obstacles.png"
    fig.savefig(path, dpi=100)
    return path


def table(folders: dict) -> pd.DataFrame:
    """One row per LABEL -> folder written by this script: contacts per robot-episode and their shares."""
    rows = []
    for label, folder in folders.items():
        s = json.loads((Path(folder) / "contacts.json").read_text())
        kind, where = s.get("kind", {}), s.get("where", {})
        zero = 0.0 if s["contacts"] else float("nan")  # the shares of no contacts: none
        rows.append(
            {
                "policy": label,
                "robots_per_room": s["robots_per_room"],
                "robot_episodes": s["robot_episodes"],
                "robot_robot": round(s["contacts"] / s["robot_episodes"], 3),
                **{f"other_{w.replace(' ', '_')}": where.get(w, zero) for _, w in BEARINGS},
                **{k.replace(" ", "_").replace("-", "_"): kind.get(k, zero) for _, k in HEADINGS},
                "one_stood_still": s.get("one_stood_still", zero),
                "speed_median": s.get("speed_median", zero),
                "near_steps_median": s.get("near_steps_median", zero),
                "narrow": s.get("narrow", float("nan")),  # folders written before the measure: NaN
                "obstacle": round(s["obstacle_contacts"] / s["robot_episodes"], 3)
                if "obstacle_contacts" in s
                else np.nan,
                "obstacle_other_near": s.get("obstacle_other_near", float("nan")),
                "obstacle_after_giving_way": s.get("obstacle_after_giving_way", float("nan")),
            }
        )
    return pd.DataFrame(rows)


def collect(pairs: list, csv: str | None) -> int:
    folders = {}
    for pair in pairs:
        label, sep, folder = pair.partition("=")
        if not sep or not (Path(folder) / "contacts.json").exists():
            print(f"error: --collect {pair!r}: LABEL=FOLDER, a folder this script wrote", file=sys.stderr)
            return 2
        folders[label] = folder
    df = table(folders)
    print(df.to_string(index=False))
    if csv:
        df.to_csv(csv, index=False)
        print("wrote", csv)
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("run", nargs="?", help="a run directory (its agents and config.yaml)")
    ap.add_argument("--collect", nargs="+", metavar="LABEL=FOLDER", help="tabulate folders this script wrote")
    ap.add_argument("--csv", help="with --collect: write the table here")
    ap.add_argument("--set", action="append", default=[], help="traced overrides, as scripts/suite_with.py")
    ap.add_argument("--suite", default="mixture-50")
    ap.add_argument("--robots-per-room", type=int, default=4)
    ap.add_argument("--max-steps", type=int, default=None, help="time-out T (default: the run's episode_length)")
    ap.add_argument("--out", help="a new folder")
    a = ap.parse_args(argv)
    if a.collect:
        return collect(a.collect, a.csv)
    if not (a.run and a.out):
        ap.error("RUN and --out are needed (or --collect)")

    import jax

    from fedjax_nav.config import ConfigError, load_config
    from fedjax_nav.evaluation import ACTION_NOISE, RANGE_NOISE
    from fedjax_nav.evaluation.limits import EvalError
    from fedjax_nav.evaluation.runs import load_run
    from fedjax_nav.evaluation.shared_rooms import shared_protocol

    out, k = Path(a.out), a.robots_per_room
    if (out / "contacts.csv").exists():
        print(f"error: {out / 'contacts.csv'} exists: choose another --out", file=sys.stderr)
        return 2
    try:
        cfg = load_config(Path(a.run) / "config.yaml", a.set)
        run = dataclasses.replace(load_run(a.run), cfg=cfg)
        pr = shared_protocol(run, a.suite, None, 1, [k], RANGE_NOISE, ACTION_NOISE, a.max_steps)
    except (ConfigError, EvalError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    res = jax.device_get(pr.program(k, trajectories=True)(run.actor_params, pr.rooms, pr.keys(0, k)))
    frames, walls, panels, near = [], [], [], []
    R, A = res["steps"].shape[:2]
    turn = float(cfg.env.omega_max * cfg.env.dt)
    for r in range(R):
        for g in range(A):
            poses, steps = res["poses"][r, g], res["steps"][r, g]
            df = contacts(poses, steps, res["robot_collision"][r, g], float(cfg.env.dt))
            frames.append(df.assign(room=r, family=pr.families[r], agent=g))
            walls.append(wall_contacts(poses, steps, res["collision"][r, g], turn).assign(room=r, agent=g))
            segs, circles = np.asarray(pr.world.segments[r]), np.asarray(pr.world.circles[r])
            close = [(w, poses, segs, circles) for _, w in walls[-1].iterrows() if w.other_distance < 1.0]
            near += close[: 8 - len(near)]
            panels += [(row, poses) for _, row in df.iterrows() if row.robot < row.other][: 8 - len(panels)]
    df = room_to_pass(pd.concat(frames, ignore_index=True), res["poses"], pr.world)
    out.mkdir(parents=True, exist_ok=True)
    df.to_csv(out / "contacts.csv", index=False)
    obstacles = pd.concat(walls, ignore_index=True)
    obstacles.to_csv(out / "obstacles.csv", index=False)
    summary = {"run": str(a.run), "suite": a.suite, "robots_per_room": k, "robot_episodes": int(R * A * k)}
    summary |= shares(df) | wall_shares(obstacles)
    (out / "contacts.json").write_text(json.dumps(summary, indent=1))
    print(json.dumps(summary, indent=1))
    if panels:
        print("wrote", figure(panels, out, float(cfg.env.dt)))
    if near:
        print("wrote", wall_figure(near, out, float(cfg.env.dt)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
