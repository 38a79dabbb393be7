"""Preparing a scene's triangles: gathered corners, degenerate flags and boxes, in one pass.

This is all a Scene derives from its meshes (O(F), a few milliseconds per 100K triangles);
nothing here outlives the Scene or depends on the rays.
"""

from collections import namedtuple

import numpy as np

from .config import inline, jit
from .geometry import triangle_normal

# A static level's end corners and ray times: empty, so both kinds of level are one record type
# and every traversal compiles once for both.
NO_END_CORNERS = np.empty((0, 9), np.float32)
NO_TIMES = np.empty(0, np.float32)

Triangles = namedtuple(
    "Triangles",
    ["verts", "bounds", "ids", "verts_end", "times"],
    defaults=(NO_END_CORNERS, NO_TIMES),
)
Triangles.__doc__ = """The triangles of one trace, as the kernels receive them: one record.

verts : (F, 9) float32, each kernel row's corners p0, p1, p2 (a deforming level's at the start)
bounds : (F, 6) float32, each kernel row's box [x0, y0, z0, x1, y1, z1] (a deforming level's
    over the whole interval)
ids : (k,) int32, the kernel rows traced; the partitions permute them in place
verts_end : (F, 9) float32, a deforming level's corners at the end; (0, 9) for a static level
times : (n,) float32, a deforming level's instant of each ray by its id in the batch; (0,) for
    a static level
"""


@jit
def faces_in_range(faces, n_vertices):
    """True if every index of ``faces`` (F, 3) lies in [0, n_vertices)."""
    for f in range(faces.shape[0]):
        for k in range(3):
            if faces[f, k] < 0 or faces[f, k] >= n_vertices:
                return False
    return True


@jit
def all_finite(values):
    """True if every entry of the (n, 3) float array is finite."""
    for i in range(values.shape[0]):
        for k in range(3):
            if not np.isfinite(values[i, k]):
                return False
    return True


@jit
def gather_triangles(
    vertices, faces, first_row, n_live, tri_verts, tri_bounds, tri_global, corner_box, box
):
    """Append the triangles of ``faces`` that are not degenerate (edge cross product exactly
    zero in float64) from row ``n_live`` on: their corners to ``tri_verts`` (F, 9), their boxes
    to ``tri_bounds`` (F, 6) and ``box`` (6,), and their row in the meshes' numbering
    (``first_row`` + face) to ``tri_global``. Returns the rows now filled.

    ``corner_box`` (6,) grows to cover every corner, degenerate triangles included. One pass,
    writing each row in place: no mask, no second copy of the corners."""
    row = n_live
    for f in range(faces.shape[0]):
        for c in range(3):
            v = faces[f, c]
            for a in range(3):
                x = vertices[v, a]
                tri_verts[row, 3 * c + a] = x
                corner_box[a] = min(corner_box[a], x)
                corner_box[a + 3] = max(corner_box[a + 3], x)
        nx, ny, nz = triangle_normal(tri_verts, row)
        if nx != 0.0 or ny != 0.0 or nz != 0.0:
            grow_triangle_box(tri_verts, row, tri_bounds, box)
            tri_global[row] = first_row + f
            row += 1
    return row


@inline
def grow_triangle_box(tri_verts, row, tri_bounds, box):
    """Box of triangle ``row`` into ``tri_bounds[row]``, and ``box`` (6,) grown to hold it."""
    for a in range(3):
        lo = min(tri_verts[row, a], tri_verts[row, 3 + a], tri_verts[row, 6 + a])
        hi = max(tri_verts[row, a], tri_verts[row, 3 + a], tri_verts[row, 6 + a])
        tri_bounds[row, a] = lo
        tri_bounds[row, a + 3] = hi
        box[a] = min(box[a], lo)
        box[a + 3] = max(box[a + 3], hi)


@jit
def triangle_boxes(tri_verts, tri_bounds, box):
    """Box of each triangle into ``tri_bounds`` (F, 6) and of them all into ``box`` (6,)."""
    for a in range(3):
        box[a] = np.inf
        box[a + 3] = -np.inf
    for row in range(tri_verts.shape[0]):
        grow_triangle_box(tri_verts, row, tri_bounds, box)
