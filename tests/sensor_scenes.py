"""The scenes and poses of the dacrt.sensors tests (plain NumPy; nothing here imports dacrt)."""

from __future__ import annotations

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
