"""Draws examples/maps/flat.pgm, the example ROS map_server map of docs/worlds.md ("Maps you already
have"): a 10 x 6 m flat at 0.1 m a pixel, as map_saver writes maps (free 254, occupied 0, unknown
205; binary PGM, row 0 at the top). Run from the repository root: python examples/maps/make_flat.py"""

from pathlib import Path

import numpy as np

FREE, OCCUPIED, UNKNOWN = 254, 0, 205


def flat() -> np.ndarray:
    img = np.full((60, 100), UNKNOWN, np.uint8)  # rows (y, top first) x columns (x)
    img[2:58, 2:98] = OCCUPIED  # outer walls, 2 px thick
    img[4:56, 4:96] = FREE
    img[4:56, 60:62] = OCCUPIED  # the wall between living room and bedroom ...
    img[26:38, 60:62] = FREE  # ... with a 1.2 m door
    img[30:32, 62:96] = OCCUPIED  # the bedroom's wall to the bathroom ...
    img[30:32, 84:94] = FREE  # ... with a 1 m door
    img[12:18, 20:34] = OCCUPIED  # a table, 1.4 x 0.6 m
    img[40:44, 40:44] = OCCUPIED  # a pillar, 0.4 m square
    img[36:56, 14] = OCCUPIED  # a glass partition, one pixel thin
    img[48:56, 66:78] = UNKNOWN  # a bed the mapping run never saw under
    return img


if __name__ == "__main__":
    img = flat()
    header = b"P5\n# CREATOR: examples/maps/make_flat.py 0.100 m/pix\n%d %d\n255\n" % (img.shape[1], img.shape[0])
    Path(__file__).with_name("flat.pgm").write_bytes(header + img.tobytes())
