"""The scenes and poses of the dacrt.sensors tests (plain NumPy; nothing here imports dacrt)."""

from __future__ import annotations

import numpy as np
import procedural
from sensor_reference import rigid_pose

_GRID, _BALL = procedural.grid(8, 16.0), procedural.icosphere(2, 1.0)
#: A z-up room: a floor (mesh 0) and two balls (meshes 1 and 2).
ROOM = [
    (procedural.transform(_GRID[0], offset=(-8.0, -8.0, 0.0)), _GRID[1]),
    (procedural.transform(_BALL[0], offset=(3.0, 1.0, 1.0)), _BALL[1]),
    (procedural.transform(_BALL[0] * 2, offset=(-4.0, 3.0, 0.5)), _BALL[1]),
]
POSES = [rigid_pose(0, 0, (0.0, -3.0, 1.2)), rigid_pose(35, -10, (-2.0, -1.0, 1.8))]


def box_mesh(lo, hi):
    """A closed axis-aligned box (8 vertices, 12 triangles, outward normals)."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    v = np.array([[(lo, hi)[k >> a & 1][a] for a in range(3)] for k in range(8)], np.float32)
    f = np.array(
        [
            [0, 2, 1], [1, 2, 3], [4, 5, 6], [5, 7, 6],  # z = lo, z = hi
            [0, 1, 4], [1, 5, 4], [2, 6, 3], [3, 6, 7],  # y = lo, y = hi
            [0, 4, 2], [2, 4, 6], [1, 3, 5], [3, 7, 5],  # x = lo, x = hi
        ],
        np.int32,
    )  # fmt: skip
    return v, f
