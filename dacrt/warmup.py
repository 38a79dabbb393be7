"""Compile (or load from the cache) every kernel by running each query kind on a tiny scene."""

import time

import numpy as np

from .contracts import STRATEGIES
from .scene import DENSITY_GRID, Scene, centre_counts, origin_weights, slab_ids


def warmup():
    """Compile every kernel; returns the seconds it took."""
    start = time.perf_counter()
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], np.float32)
    faces = np.array([[0, 1, 2], [1, 3, 2]], np.int32)
    Scene([(vertices, faces.astype(np.int64))])
    scene = Scene([(vertices, faces)])
    origins = np.tile(np.array([[0.25, 0.25, 1.0]], np.float32), (4, 1))
    directions = np.tile(np.array([[0.0, 0.0, -1.0]], np.float32), (4, 1))
    for strategy in STRATEGIES:
        scene.closest(origins, directions, strategy=strategy, threads=1)
        scene.occluded(origins, directions, strategy=strategy, threads=1)
    # Rays as the columns of one read-only (n, 6) array, as a server decodes them from a body.
    rays = np.hstack([origins, directions])
    rays.flags.writeable = False
    scene.closest(rays[:, :3], rays[:, 3:], threads=1)
    # Incoherent batches on several threads are cut into slabs of origins, at weighted
    # quantiles of a strided sample of them (writable, or read-only as from a server's body).
    slab_ids(np.ascontiguousarray(origins[:, 0]), np.zeros(1, np.float32), 0)
    counts = centre_counts(scene._tri_bounds, scene._box, DENSITY_GRID)
    for sample in (origins[::2], rays[::2, :3]):
        origin_weights(sample, counts, scene._box, DENSITY_GRID)
    return time.perf_counter() - start
