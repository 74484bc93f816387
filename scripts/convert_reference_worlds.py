"""Convert the Gazebo-extracted playgrounds in ``shared/reference-worlds`` to fedjax_nav world files.

Run once (the outputs are committed under ``fedjax_nav/worlds/data``)::

    python scripts/convert_reference_worlds.py ../shared/reference-worlds

What is approximated (also in docs/worlds.md):
- Each room is moved so that its inner free space is centred on the origin; the square walls are
  regenerated from the inner size (inner faces at +-size/2). In room 0 one wall centre-line sits
  at y = 10.0501 instead of 10.0 in the Gazebo file: the 5 cm is dropped.
- Fire hydrants (meshes) become circles of radius 0.15 m.
- Static Pioneer robots become one box of 0.45 x 0.38 m (chassis with wheels), since the robot's
  body collides with the wheels even though the lidar plane (0.17 m) only sees the chassis.
  Their wheel cylinders and caster sphere, below the lidar plane, are dropped as separate objects.
- Objects entirely below or above the lidar plane (z_max < 0.17 or z_min > 0.17) are dropped.
- Start headings: the original code reset every robot with a quaternion that amounts to
  yaw = pi, whatever the launch file said; every start here has theta = pi.
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

LIDAR_Z = 0.17
HYDRANT_R = 0.15
PIONEER_SIZE = (0.45, 0.38)
START_YAW = math.pi
OUT = Path(__file__).resolve().parents[1] / "fedjax_nav" / "worlds" / "data"


def _r(x: float) -> float:
    return round(float(x), 4)


def convert_objects(objs, cx, cy):
    boxes, circles = [], []
    for o in objs:
        name, kind = o["name"], o["type"]
        if name.startswith("brick_box"):  # room walls: regenerated from the size
            continue
        if kind == "mesh" and "fire_hydrant" in o.get("uri", name):
            circles.append([_r(o["x"] - cx), _r(o["y"] - cy), HYDRANT_R])
            continue
        if "z_min" in o and (o["z_max"] < LIDAR_Z or o["z_min"] > LIDAR_Z):
            continue  # wheels, casters: not in the lidar plane
        if kind == "box":
            sx, sy = PIONEER_SIZE if name.startswith("pioneer") else (o["size_x"], o["size_y"])
            boxes.append([_r(o["x"] - cx), _r(o["y"] - cy), _r(sx), _r(sy), _r(o["yaw"])])
        elif kind == "cylinder":
            circles.append([_r(o["x"] - cx), _r(o["y"] - cy), _r(o["radius"])])
        else:
            raise ValueError(f"unhandled obstacle {name!r} of type {kind!r}")
    return boxes, circles


def main(ref: Path) -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    train = json.loads((ref / "train_frl_ma_6_playgrounds.json").read_text())
    for room in train["playgrounds"]:
        walls = [o for o in room["obstacles"] if o["name"].startswith("brick_box")]
        xs = [o["x"] for o in walls if abs(o["yaw"]) > 1.0]
        ys = [o["y"] for o in walls if abs(o["yaw"]) <= 1.0]
        cx, cy = (min(xs) + max(xs)) / 2, (min(ys) + max(ys)) / 2
        if any(abs(o["yaw"]) > 1.0 for o in walls):
            side = [o["y"] for o in walls if abs(o["yaw"]) > 1.0]
            cy = sum(side) / len(side)  # side walls give the true centre (room 0's top wall is 5 cm off)
        boxes, circles = convert_objects(room["obstacles"], cx, cy)
        starts = room["alternative_starts_TURTLEBOT_WORLD_5_STARTS"]
        assert starts[0] == room["start"]
        world = {
            "name": f"train-{room['id']}",
            "description": (
                f"Training room {room['id']} of frl_ma.world ({room['inner_size_m'][0]:g} x "
                f"{room['inner_size_m'][1]:g} m), moved by ({-cx:g}, {-cy:g}). Start 0 is the "
                "original start; the others are FLSDDPG's additional starts."
            ),
            "size": room["inner_size_m"],
            "boxes": boxes,
            "circles": circles,
            "starts": [[_r(x - cx), _r(y - cy), _r(START_YAW)] for x, y in starts],
            "goals": [[_r(room["goal"][0] - cx), _r(room["goal"][1] - cy)]],
        }
        _write(world)
    ev = json.loads((ref / "test_fl4sr_eval_thesis.json").read_text())
    boxes, circles = convert_objects(ev["obstacles"], 0.0, 0.0)
    world = {
        "name": "eval",
        "description": "The thesis's 12 x 12 m evaluation arena (fl4sr_eval.world); goals are the 4 corners.",
        "size": ev["arena"]["inner_free_space_m"],
        "boxes": boxes,
        "circles": circles,
        "starts": [[0.0, 0.0, _r(START_YAW)]],
        "goals": [ev["goals"][k] for k in sorted(ev["goals"])],
    }
    _write(world)


def _write(world: dict) -> None:
    path = OUT / f"{world['name']}.json"
    lines = ["{"]
    items = list(world.items())
    for i, (k, v) in enumerate(items):
        comma = "," if i < len(items) - 1 else ""
        if isinstance(v, list) and v and isinstance(v[0], list):
            rows = ",\n".join("    " + json.dumps(r) for r in v)
            lines.append(f'  "{k}": [\n{rows}\n  ]{comma}')
        else:
            lines.append(f'  "{k}": {json.dumps(v)}{comma}')
    lines.append("}")
    path.write_text("\n".join(lines) + "\n")
    print("wrote", path)


if __name__ == "__main__":
    main(Path(sys.argv[1] if len(sys.argv) > 1 else "../shared/reference-worlds"))
