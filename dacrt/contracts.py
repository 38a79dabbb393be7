"""Array contracts shared by the engine: dtypes, the layout of inputs, the miss marker,
strategies, float32 constants, the stats layout and the answer types."""

from dataclasses import dataclass

import numpy as np

FLOAT = np.float32
INDEX = np.int32
MISS = -1


def kernel_input(array, dtype):
    """``array`` as the kernels receive every input array: ``dtype`` (None: its own), a base
    ndarray, C-contiguous, aligned and writable; the array itself where it already is, else a
    copy. Each of these is part of a kernel's argument type, so every input gives one signature;
    read-only arrays (a server's bodies) are copied, as Numba's code reads them more slowly."""
    return np.require(array, dtype, "CAWE")


STRATEGIES = ("sampling", "sah", "middle", "rayspace")
# The kernels' codes of the strategies.
MIDDLE, SAH, SAMPLING, RAYSPACE = range(4)
STRATEGY_CODES = {"middle": MIDDLE, "sah": SAH, "sampling": SAMPLING, "rayspace": RAYSPACE}

# float32 scalars for the kernels: a float64 constant would turn float32 arithmetic into float64.
INF32 = FLOAT(np.inf)
NEG_INF32 = FLOAT(-np.inf)
NAN32 = FLOAT(np.nan)
ONE32 = FLOAT(1.0)

# Order of the counters in a kernel's stats array. ray_box_tests counts every ray-box test,
# sample_box_tests the part of them that ray sampling made (Algorithm 2 of Nabata et al.).
STAT_NAMES = (
    "rays",
    "triangles",
    "ray_box_tests",
    "ray_triangle_tests",
    "nodes",
    "leaves",
    "sampled_nodes",
    "skipped_filterings",
    "max_depth",
    "sample_box_tests",
)
(
    STAT_RAYS,
    STAT_TRIANGLES,
    STAT_BOX_TESTS,
    STAT_TRIANGLE_TESTS,
    STAT_NODES,
    STAT_LEAVES,
    STAT_SAMPLED,
    STAT_SKIPPED,
    STAT_MAX_DEPTH,
    STAT_SAMPLE_BOX_TESTS,
) = range(len(STAT_NAMES))

# Order of the counters of a point query (``points``): seed_tests counts the point-triangle
# distances measured for the first radii, triangle_tests those measured in leaves.
POINT_STAT_NAMES = (
    "points",
    "triangles",
    "point_box_tests",
    "point_triangle_tests",
    "seed_tests",
    "nodes",
    "leaves",
    "max_depth",
)
(
    STAT_POINTS,
    STAT_POINT_TRIANGLES,
    STAT_POINT_BOX_TESTS,
    STAT_POINT_TRIANGLE_TESTS,
    STAT_POINT_SEED_TESTS,
    STAT_POINT_NODES,
    STAT_POINT_LEAVES,
    STAT_POINT_MAX_DEPTH,
) = range(len(POINT_STAT_NAMES))


@dataclass
class Hits:
    """Closest hit of each ray.

    t : (n,) float32, inf on a miss
    mesh, prim : (n,) int32, -1 on a miss
    u, v : (n,) float32 barycentrics, hit = (1-u-v)*p0 + u*p1 + v*p2; 0 on a miss
    normal : (n, 3) float32 unit geometric normal (p1-p0)x(p2-p0); 0 on a miss
    stats : dict of counters when asked for, else None
    """

    t: np.ndarray
    mesh: np.ndarray
    prim: np.ndarray
    u: np.ndarray
    v: np.ndarray
    normal: np.ndarray
    stats: dict[str, int] | None = None

    def __len__(self) -> int:
        return len(self.t)


@dataclass
class Occlusion:
    """Whether each ray is blocked.

    occluded : (n,) bool, true where the ray hits something with tmin <= t <= tmax
    stats : dict of counters when asked for, else None
    """

    occluded: np.ndarray
    stats: dict[str, int] | None = None

    def __len__(self) -> int:
        return len(self.occluded)


@dataclass
class HitList:
    """Every hit of each ray, nearest first, in CSR form.

    offsets : (n + 1,) int64; ray i's hits are rows offsets[i]:offsets[i + 1] of the arrays below
    t : (m,) float32, sorted within each ray, ties by (mesh, prim)
    mesh, prim : (m,) int32
    u, v : (m,) float32 barycentrics, hit = (1-u-v)*p0 + u*p1 + v*p2
    normal : (m, 3) float32 unit geometric normal (p1-p0)x(p2-p0)
    truncated : (n,) bool, true where a ray had more hits than max_hits (the nearest are kept)
    stats : dict of counters when asked for, else None
    """

    offsets: np.ndarray
    t: np.ndarray
    mesh: np.ndarray
    prim: np.ndarray
    u: np.ndarray
    v: np.ndarray
    normal: np.ndarray
    truncated: np.ndarray
    stats: dict[str, int] | None = None

    def __len__(self) -> int:
        return len(self.truncated)

    @property
    def counts(self) -> np.ndarray:
        """(n,) int64: the hits held for each ray."""
        return np.diff(self.offsets)


@dataclass
class Counts:
    """How many triangles each ray crosses.

    count : (n,) int32
    stats : dict of counters when asked for, else None
    """

    count: np.ndarray
    stats: dict[str, int] | None = None

    def __len__(self) -> int:
        return len(self.count)


@dataclass
class Nearest:
    """The closest point on the scene's triangles to each query point.

    distance : (n,) float32, inf where no triangle is within max_distance (or none is seen)
    point : (n, 3) float32, the closest point; inf where there is none
    mesh, prim : (n,) int32, its triangle; -1 where there is none
    u, v : (n,) float32 barycentrics of the closest point, point = (1-u-v)*p0 + u*p1 + v*p2;
        0 where there is none
    stats : dict of counters when asked for, else None
    """

    distance: np.ndarray
    point: np.ndarray
    mesh: np.ndarray
    prim: np.ndarray
    u: np.ndarray
    v: np.ndarray
    stats: dict[str, int] | None = None

    def __len__(self) -> int:
        return len(self.distance)
