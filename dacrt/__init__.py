"""dacrt: divide-and-conquer ray casting without an acceleration structure.

scene = dacrt.Scene([(vertices, faces), ...])
hits = scene.closest(origins, directions)
blocked = scene.occluded(origins, directions, tmax=distances).occluded
"""

from .contracts import MISS, STRATEGIES, Hits, Occlusion
from .query import CULL_MODES
from .scene import Scene
from .warmup import warmup

__all__ = ["Scene", "Hits", "Occlusion", "MISS", "STRATEGIES", "CULL_MODES", "warmup"]
__version__ = "0.1.0"
