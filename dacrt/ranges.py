"""Halves of the storage order: the triangles' first splits, with no pass over the triangles.

A level's rows are stored in a spatially coherent order (``packed.morton_order``), so a range
of consecutive rows is a compact piece of the scene. Halving ranges gives a fixed binary
hierarchy: node k (numbered as a heap, the root 1, the children of k are 2k and 2k + 1) at depth
d, k = 2^d + j, holds rows [j·F >> d, (j + 1)·F >> d) of F. Its boxes are made per query, in
one pass over the rows' boxes and one over the nodes (``range_boxes``), and are dropped with
the query: nothing outlives it. A traversal that splits a node this way moves no triangle id
and reads no triangle: where a node has few rays a triangle, the split that partitions the
triangles costs more than the rays gain from it (``traversal.trace_object_split``).
"""

from collections import namedtuple

import numpy as np

from .config import RANGE_LEAF_ROWS, inline, jit
from .contracts import FLOAT, INF32

RangeTree = namedtuple("RangeTree", ["boxes", "n_rows", "depth", "root"])
RangeTree.__doc__ = """The boxes of a level's halved row ranges, for one query.

boxes : (2^(depth + 1), 6) float32, node k's box at row k (row 0 unused); (0, 6) for none
n_rows : the level's rows F, every one traced (the chunk's ids start as 0..F-1)
depth : the depth of the leaves, whose ranges hold at most RANGE_LEAF_ROWS rows
root : the node a trace starts at, whose rows are the trace's triangle range; 0 for no tree
"""

NO_TREE = RangeTree(np.empty((0, 6), FLOAT), 0, 0, 0)


def tree_depth(n_rows):
    """The least depth whose ranges hold at most RANGE_LEAF_ROWS of ``n_rows`` rows."""
    depth = 0
    while -(-n_rows // (1 << depth)) > RANGE_LEAF_ROWS:
        depth += 1
    return depth


def range_tree(bounds, run_parts):
    """The ``RangeTree`` of rows with boxes ``bounds`` (F, 6) float32. ``run_parts(f, n)``
    calls f(0) .. f(n - 1), on threads or not: the subtrees under the nodes of one level go to
    the parts, then the few nodes above them are joined here."""
    n_rows = len(bounds)
    depth = tree_depth(n_rows)
    boxes = np.empty((2 << depth, 6), FLOAT)
    boxes[0] = (INF32, INF32, INF32, -INF32, -INF32, -INF32)
    split = min(depth, 3)  # 8 subtrees at most, each a part
    first = 1 << split
    run_parts(lambda p: fill_subtree(bounds, boxes, depth, first + p), first)
    join_levels(boxes, split)
    return RangeTree(boxes, n_rows, depth, 1)


@inline
def node_rows(node, n_rows):
    """(lo, hi) rows of heap node ``node`` (>= 1) over ``n_rows`` rows."""
    depth = 0
    while (node >> (depth + 1)) > 0:
        depth += 1
    j = node - (1 << depth)
    return (j * n_rows) >> depth, ((j + 1) * n_rows) >> depth


@jit
def fill_subtree(bounds, boxes, depth, root):
    """Every box of the subtree under node ``root``: its leaves from ``bounds``, then each level
    above them as the union of the two below."""
    n_rows = bounds.shape[0]
    root_depth = 0
    while (root >> (root_depth + 1)) > 0:
        root_depth += 1
    levels = depth - root_depth
    first = root << levels
    for node in range(first, first + (1 << levels)):
        lo, hi = node_rows(node, n_rows)
        x0 = y0 = z0 = INF32
        x1 = y1 = z1 = -INF32
        for r in range(lo, hi):
            x0 = min(x0, bounds[r, 0])
            y0 = min(y0, bounds[r, 1])
            z0 = min(z0, bounds[r, 2])
            x1 = max(x1, bounds[r, 3])
            y1 = max(y1, bounds[r, 4])
            z1 = max(z1, bounds[r, 5])
        boxes[node, 0] = x0
        boxes[node, 1] = y0
        boxes[node, 2] = z0
        boxes[node, 3] = x1
        boxes[node, 4] = y1
        boxes[node, 5] = z1
    for level in range(levels - 1, -1, -1):
        first = root << level
        for node in range(first, first + (1 << level)):
            join_children(boxes, node)


@jit
def join_levels(boxes, depth):
    """The boxes of the nodes above ``depth``, each the union of its two children."""
    for level in range(depth - 1, -1, -1):
        for node in range(1 << level, 2 << level):
            join_children(boxes, node)


@inline
def join_children(boxes, node):
    """Box of ``node`` as the union of its children's."""
    for a in range(3):
        boxes[node, a] = min(boxes[2 * node, a], boxes[2 * node + 1, a])
        boxes[node, a + 3] = max(boxes[2 * node, a + 3], boxes[2 * node + 1, a + 3])
