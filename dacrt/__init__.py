"""dacrt: divide-and-conquer ray casting without an acceleration structure.

scene = dacrt.Scene([(vertices, faces), ...])
hits = scene.closest(origins, directions)
blocked = scene.occluded(origins, directions, tmax=distances).occluded
every = scene.hits(origins, directions, max_hits=16)      # CSR: every.offsets, every.t, ...
crossings = scene.count(origins, directions).count
"""

from .contracts import MISS, STRATEGIES, Counts, HitList, Hits, Occlusion
from .query import CULL_MODES
from .scene import Scene
from .validation import check_transform
from .warmup import warmup

__all__ = [
    "Scene",
    "Hits",
    "Occlusion",
    "HitList",
    "Counts",
    "MISS",
    "STRATEGIES",
    "CULL_MODES",
    "warmup",
    "check_transform",
]
__version__ = "0.1.0"
