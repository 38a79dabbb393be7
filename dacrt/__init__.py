"""dacrt: divide-and-conquer ray casting without an acceleration structure.

scene = dacrt.Scene([(vertices, faces), ...])
hits = scene.closest(origins, directions)
blocked = scene.occluded(origins, directions, tmax=distances).occluded
every = scene.hits(origins, directions, max_hits=16)      # CSR: every.offsets, every.t, ...
crossings = scene.count(origins, directions).count
points = dacrt.sensors.Lidar("HDL-64E", horizontal_steps=2048).scan(scene, pose)  # a lidar
closest = scene.nearest(points)                           # distance, point, mesh, prim, u, v
inside = scene.contains(points)

The first queries of a process compile the engine's kernels with Numba (minutes, once per
machine and version; a warning says so); ``dacrt.warmup()`` compiles them all up front, and
``dacrt.cache.use_cache_dir(path)`` chooses where they are kept. Importing changes nothing
outside the package.
"""

from importlib.metadata import PackageNotFoundError, version

from . import cache, sensors
from .contracts import MISS, STRATEGIES, Counts, HitList, Hits, Nearest, Occlusion
from .query import CULL_MODES
from .scene import Scene
from .validation import InputError, MeshSpaceError, check_transform
from .warmup import warmup

__all__ = [
    "InputError",
    "MeshSpaceError",
    "Scene",
    "Hits",
    "Occlusion",
    "HitList",
    "Counts",
    "Nearest",
    "MISS",
    "STRATEGIES",
    "CULL_MODES",
    "warmup",
    "check_transform",
    "sensors",
    "cache",
]

try:
    __version__: str = version("dacrt-service")  # pyproject.toml's, the one place it is written
except PackageNotFoundError:  # sources on sys.path, not installed
    __version__ = "0+unknown"
