"""The options of one query as the kernels receive them: a flags word and one record of arrays.

A query's kind and variants travel as bits of one int (``flags``), and its per-ray and
per-triangle arrays, outputs and scratch as one ``QueryArrays``: a new variant is a bit and maybe
an array, not a copy of a kernel or another positional parameter.
"""

from collections import namedtuple

import numpy as np

from .config import inline

# Bits of the flags word.
# A ray stops at its first hit (occluded); else it keeps its closest hit.
ANY_HIT = 1
# Faces whose geometric normal points along the ray (back faces) never hit.
CULL_BACK = 2
# Faces whose geometric normal points against the ray (front faces) never hit.
CULL_FRONT = 4
# A ray sees a triangle only where ray_masks[ray id] & tri_masks[row] != 0.
MASKED = 8
# Every record of the chunk has the same origin quad (``rays.uniform_origin``).
FIXED_ORIGIN = 16
# A ray keeps its nearest hits in a sorted list (``hits``) rather than one best hit.
ALL_HITS = 32
# A ray counts its hits (``count``) rather than keeping any.
COUNT = 64
# The kinds that keep more than one hit a ray, and so count a crossing through a shared edge or
# vertex once (``geometry.crossing``).
COLLECT = ALL_HITS | COUNT
# Bits 7-8: the strategy's code (``contracts.STRATEGY_CODES``): ``strategy_of``, ``with_strategy``.
STRATEGY_SHIFT = 7
STRATEGY_BITS = 3 << STRATEGY_SHIFT

CULL_MODES = ("none", "back", "front")
CULL_FLAGS = {"none": 0, "back": CULL_BACK, "front": CULL_FRONT}

# A mask that sees everything, and the mask of a ray or mesh given none.
ALL_MASKS = np.uint32(0xFFFFFFFF)

QueryArrays = namedtuple(
    "QueryArrays",
    [
        "best_tri",
        "hit_u",
        "hit_v",
        "ray_masks",
        "tri_masks",
        "tri_keys",
        "n_hits",
        "list_t",
        "list_tri",
        "hit_mask",
        "tri_bins",
        "stats",
    ],
)
QueryArrays.__doc__ = """The arrays of one chunk's trace.

best_tri : (n,) int32 kernel row of each ray's best hit, NO_HIT for none; by ray id
hit_u, hit_v : (n,) float32 barycentrics of that hit; by ray id
ray_masks : (n,) uint32 by ray id, or (0,) when the MASKED bit is clear
tri_masks : (F,) uint32 by kernel row, or (0,) when the MASKED bit is clear
tri_keys : (F,) int32 by kernel row: its triangle in the meshes' numbering (``Packed.ids``), which
    ties in t compare, so answers do not depend on the order the rows are stored in
n_hits : (n,) int32 by ray id: hits counted (COUNT) or held in the ray's list (ALL_HITS), else (0,)
list_t, list_tri : (n, L) by ray id: each ray's nearest hits (t, kernel row) in (t, tie key)
    order, its first n_hits entries in use (ALL_HITS), else (0, 0); u and v are found when they
    are finished
hit_mask : (m,) bool scratch, one entry per record of the chunk
tri_bins : (F,) uint8 scratch, each triangle's bin from binning to partition
stats : (len(STAT_NAMES),) int64 counters
"""


@inline
def strategy_of(flags):
    """The strategy's code (``contracts.MIDDLE``, ``SAH``, ``SAMPLING``, ``RAYSPACE``) of a
    flags word."""
    return (flags >> STRATEGY_SHIFT) & 3


@inline
def with_strategy(flags, code):
    """``flags`` with the strategy ``code`` in place of its own."""
    return (flags & ~STRATEGY_BITS) | (code << STRATEGY_SHIFT)
