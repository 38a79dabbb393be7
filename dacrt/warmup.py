"""Compile (or load from the cache) every kernel by running each query kind on a tiny scene: the
public checks hand the kernels one layout whatever the caller's arrays (``validation``), so these
calls compile every kernel a query can reach."""

import time

import numpy as np

from .chunks import MIN_RAYS_PER_THREAD, SPLIT_TRIANGLES_RAYS_PER_TRIANGLE, splits_triangles
from .compiling import warming_up
from .contracts import STRATEGIES
from .scene import Scene


@warming_up()
def warmup() -> float:
    """Compile every kernel (or load it from Numba's cache: ``dacrt.cache``); returns the seconds
    it took."""
    start = time.perf_counter()
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], np.float32)
    faces = np.array([[0, 1, 2], [1, 3, 2]], np.int32)
    Scene([(vertices, faces.astype(np.int64))])
    scene = Scene([(vertices, faces)])
    Scene([(vertices, faces)], order="morton")  # the storage order's sort
    origins = np.tile(np.array([[0.25, 0.25, 1.0]], np.float32), (4, 1))
    directions = np.tile(np.array([[0.0, 0.0, -1.0]], np.float32), (4, 1))
    for strategy in STRATEGIES:
        scene.closest(origins, directions, strategy=strategy, threads=1)
        scene.occluded(origins, directions, strategy=strategy, threads=1)
        scene.hits(origins, directions, strategy=strategy, threads=1)
        scene.count(origins, directions, strategy=strategy, threads=1)
    # Two instances of the mesh beside it, and a version that moves one (``with_changes``).
    moved = np.eye(4)
    moved[:3, 3] = (2.0, 0.0, 0.0)
    placed = Scene([(vertices, faces)] * 3, transforms=[None, moved, np.diag([-1.0, 1, 1, 1])])
    placed = placed.with_changes(transforms={1: moved @ moved}, vertices={2: vertices})
    masks = np.array([1, 2, 3, 1], np.uint32)
    # Rays onto the mesh as given, the mirrored instance (x in [-1, 0]) and the moved one (x in
    # [4, 5], moving to [2, 3]): the instances' kernels run too.
    spread = origins.copy()
    spread[:, 0] = (0.25, -0.75, 4.25, 2.25)
    for mask in (None, masks):
        placed.closest(spread, directions, mask=mask, threads=1)
        placed.occluded(spread, directions, mask=mask, threads=1)
        placed.hits(spread, directions, mask=mask, threads=1)
        placed.count(spread, directions, mask=mask, threads=1)
    # A moving instance and rays at their own times (``rays_to_mesh_space_at``).
    moving = placed.with_changes(transforms_end={1: moved})
    times = np.linspace(0.0, 1.0, len(origins), dtype=np.float32)
    moving.closest(spread, directions, time=times, threads=1)
    moving.hits(spread, directions, time=times, threads=1)
    # A deforming mesh beside a static one: the traversals with the deforming leaf, for
    # every strategy, with a mask per ray too.
    lifted = vertices + np.float32([0.0, 0.0, 0.5])
    deforming = Scene([(vertices, faces)] * 2, vertices_end=[None, lifted])
    for strategy in STRATEGIES:
        deforming.closest(origins, directions, time=times, strategy=strategy, threads=1)
    deforming.hits(origins, directions, time=times, mask=masks, threads=1)
    # Point queries: one mask for the batch, a mask per point, and the parity of crossings.
    scene.nearest(origins, threads=1)
    scene.nearest(origins, mask=np.arange(1, 5, dtype=np.uint32), threads=1)
    scene.contains(origins, threads=1)
    placed.nearest(spread, threads=1)  # the instances placed in scene space
    # Incoherent batches on two threads are cut into slabs of origins.
    n_rays = 2 * MIN_RAYS_PER_THREAD
    scattered = np.random.default_rng(0).uniform(-1.0, 2.0, (n_rays, 6)).astype(np.float32)
    scene.closest(scattered[:, :3], scattered[:, 3:], threads=2)
    # Few rays a triangle on two threads: halves of the triangles (a grid of small quads).
    side = int(np.sqrt(n_rays / SPLIT_TRIANGLES_RAYS_PER_TRIANGLE / 2)) + 1
    ticks = np.arange(side + 1, dtype=np.float32) / side
    grid = np.stack(np.meshgrid(ticks, ticks, indexing="ij"), axis=-1).reshape(-1, 2)
    grid_vertices = np.hstack([grid, np.zeros((len(grid), 1), np.float32)])
    corner = (np.arange(side)[:, None] * (side + 1) + np.arange(side)[None, :]).ravel()
    quads = np.stack([corner, corner + 1, corner + side + 1, corner + side + 2], axis=1)
    grid_faces = np.vstack([quads[:, [0, 1, 2]], quads[:, [1, 3, 2]]]).astype(np.int32)
    grid_scene = Scene([(grid_vertices, grid_faces)])
    assert splits_triangles(n_rays, grid_scene.n_triangles, 2)
    grid_scene.closest(scattered[:, :3], scattered[:, 3:], threads=2)
    grid_scene.occluded(scattered[:, :3], scattered[:, 3:], threads=2)
    # ... and of a deforming grid's.
    bent = Scene([(grid_vertices, grid_faces)], vertices_end=[grid_vertices * np.float32(1.5)])
    bent.closest(scattered[:, :3], scattered[:, 3:], threads=2)
    return time.perf_counter() - start
