"""dacrt: divide-and-conquer ray casting without an acceleration structure.

scene = dacrt.Scene([(vertices, faces), ...])
hits = scene.closest(origins, directions)
blocked = scene.occluded(origins, directions, tmax=distances)
"""

from .contracts import MISS, STRATEGIES, Hits
from .scene import Scene
from .warmup import warmup

__all__ = ["Scene", "Hits", "MISS", "STRATEGIES", "warmup"]
__version__ = "0.1.0"
