"""The host side of the breadth-first traversal: one frontier of nodes at a time.

Each frontier runs its leaves, splits its inner nodes and builds the next frontier by prefix
sums over its children's counts (NumPy on the host for now: the counts are a few numbers a node,
copied back once a level). A next frontier with more ray slots than ``max_pairs`` is cut into
runs of whole nodes of at most ``max_pairs`` each (a single node holds each ray once, so at
most n rays), kept on a stack: every frontier holds at most max(max_pairs, n) ray slots and the
next one twice that.
"""

from dataclasses import dataclass

import numpy as np
from numba import config, cuda

from . import kernels

# The simulator starts a Python thread per thread of a block: small blocks waste fewer.
THREADS = 16 if config.ENABLE_CUDASIM else 128
# Nodes with this many triangles or fewer are leaves.
LEAF_TRIANGLES = 8
# Nodes this deep are leaves, whatever they hold.
MAX_DEPTH = 64
# Ray slots a frontier may hold, by default (4 + 4 bytes each on the device).
MAX_PAIRS = 1 << 24


@dataclass
class Frontier:
    """Nodes of one level: host arrays per node, device arrays per slot."""

    depth: int
    tri_lo: np.ndarray  # (N,) int64
    tri_n: np.ndarray  # (N,) int64
    ray_lo: np.ndarray  # (N,) int64
    ray_n: np.ndarray  # (N,) int64
    boxes: np.ndarray  # (N, 6) float32
    rows: object  # (T,) int32 device: kernel rows
    tri_node: object  # (T,) int32 device
    ray_ids: object  # (P,) int32 device
    ray_node: object  # (P,) int32 device


def launch(kernel, n, *args):
    """Run ``kernel`` on n threads (none for n == 0)."""
    if n:
        kernel[(n + THREADS - 1) // THREADS, THREADS](*args)


def root(n_rows, n_rays, box):
    """The frontier of one node: every row, every ray."""
    zero = np.zeros(1, np.int64)
    return Frontier(
        0, zero, np.array([n_rows]), zero.copy(), np.array([n_rays]), box.reshape(1, 6),
        cuda.to_device(np.arange(n_rows, dtype=np.int32)),
        cuda.to_device(np.zeros(n_rows, np.int32)),
        cuda.to_device(np.arange(n_rays, dtype=np.int32)),
        cuda.to_device(np.zeros(n_rays, np.int32)),
    )  # fmt: skip


def traverse(scene_arrays, ray_arrays, run_leaves, max_pairs=MAX_PAIRS):
    """Visit every node that some ray reaches, from the root; ``run_leaves(frontier, kind)``
    tests each frontier's leaves. ``scene_arrays``: (centroids, tri_box, box) with the first two
    on the device; ``ray_arrays``: (origins, inv_dirs, tmin, tmax) on the device."""
    centroids, tri_box, box = scene_arrays
    n_rays = ray_arrays[0].shape[0]
    limit = max(max_pairs, n_rays)
    stack = [root(tri_box.shape[0], n_rays, box)]
    levels = 0
    while stack:
        frontier = stack.pop()
        levels += 1
        kind, axis, middle = plan(frontier)
        kind_d = cuda.to_device(kind)
        run_leaves(frontier, kind_d)
        if (kind == kernels.LEAF).all():
            continue
        children = split(frontier, kind, kind_d, axis, middle, centroids, tri_box, ray_arrays)
        stack.extend(reversed(cut(children, limit)))
    return levels


def plan(frontier):
    """Each node's kind (leaf, or split at the middle of the longest axis of its box), and
    that axis and middle."""
    boxes = frontier.boxes
    extent = boxes[:, 3:] - boxes[:, :3]
    axis = np.argmax(extent, axis=1).astype(np.int32)
    lo = boxes[np.arange(len(boxes)), axis]
    hi = boxes[np.arange(len(boxes)), 3 + axis]
    middle = (np.float32(0.5) * (lo + hi)).astype(np.float32)
    leaf = (frontier.tri_n <= LEAF_TRIANGLES) | (frontier.depth >= MAX_DEPTH)
    kind = np.where(leaf, kernels.LEAF, kernels.SPLIT_MIDDLE).astype(np.int8)
    return kind, axis, middle


def split(frontier, kind, kind_d, axis, middle, centroids, tri_box, ray_arrays):
    """The next frontier: each inner node's two children, those that hold rays kept."""
    origins, inv_dirs, tmin, tmax = ray_arrays
    n_nodes = len(kind)
    n_tri = frontier.rows.shape[0]
    n_slots = frontier.ray_ids.shape[0]
    tri_lo = cuda.to_device(frontier.tri_lo.astype(np.int64))
    tri_n = cuda.to_device(frontier.tri_n.astype(np.int64))
    axis_d = cuda.to_device(axis)
    middle_d = cuda.to_device(middle)
    tri_args = (frontier.rows, frontier.tri_node, kind_d, tri_lo, tri_n, axis_d, middle_d)
    first = cuda.to_device(np.zeros(n_nodes, np.int64))
    launch(kernels.count_first_side, n_tri, *tri_args, centroids, first)
    first_n = first.copy_to_host()
    # A middle that leaves one side empty (a node of coincident centres) splits by position.
    stuck = (kind == kernels.SPLIT_MIDDLE) & ((first_n == 0) | (first_n == frontier.tri_n))
    kind[stuck] = kernels.SPLIT_HALVES
    first_n[stuck] = frontier.tri_n[stuck] // 2
    kind_d = cuda.to_device(kind)
    tri_args = (frontier.rows, frontier.tri_node, kind_d, tri_lo, tri_n, axis_d, middle_d)
    boxes0 = np.empty((2 * n_nodes, 6), np.float32)
    boxes0[:, :3] = np.inf
    boxes0[:, 3:] = -np.inf
    boxes = cuda.to_device(boxes0)
    launch(kernels.child_boxes, n_tri, *tri_args, centroids, tri_box, boxes)
    reach = cuda.device_array(n_slots, np.int8)
    ray_n = cuda.to_device(np.zeros(2 * n_nodes, np.int64))
    launch(
        kernels.count_child_rays, n_slots, frontier.ray_ids, frontier.ray_node, kind_d,
        origins, inv_dirs, tmin, tmax, boxes, reach, ray_n,
    )  # fmt: skip
    child_tri_n = np.stack([first_n, frontier.tri_n - first_n], axis=1).reshape(-1)
    child_ray_n = ray_n.copy_to_host()
    inner = np.repeat(kind != kernels.LEAF, 2)
    kept = inner & (child_ray_n > 0) & (child_tri_n > 0)
    new_index = np.full(2 * n_nodes, -1, np.int64)
    new_index[kept] = np.arange(kept.sum())
    tri_counts = child_tri_n[kept]
    ray_counts = child_ray_n[kept]
    # Prefix sums place each kept child's slots.
    tri_lo_new = np.concatenate([[0], np.cumsum(tri_counts)[:-1]]).astype(np.int64)
    ray_lo_new = np.concatenate([[0], np.cumsum(ray_counts)[:-1]]).astype(np.int64)
    new_index_d = cuda.to_device(new_index)
    new_rows = cuda.device_array(int(tri_counts.sum()), np.int32)
    new_tri_node = cuda.device_array(int(tri_counts.sum()), np.int32)
    launch(
        kernels.scatter_triangles, n_tri, *tri_args, centroids, new_index_d,
        cuda.to_device(tri_lo_new), cuda.to_device(np.zeros(len(tri_counts), np.int64)),
        new_rows, new_tri_node,
    )  # fmt: skip
    new_ray_ids = cuda.device_array(int(ray_counts.sum()), np.int32)
    new_ray_node = cuda.device_array(int(ray_counts.sum()), np.int32)
    launch(
        kernels.scatter_rays, n_slots, frontier.ray_ids, frontier.ray_node, reach, new_index_d,
        cuda.to_device(ray_lo_new), cuda.to_device(np.zeros(len(ray_counts), np.int64)),
        new_ray_ids, new_ray_node,
    )  # fmt: skip
    return Frontier(
        frontier.depth + 1, tri_lo_new, tri_counts, ray_lo_new, ray_counts,
        boxes.copy_to_host()[kept], new_rows, new_tri_node, new_ray_ids, new_ray_node,
    )  # fmt: skip


def cut(frontier, limit):
    """``frontier`` as runs of whole nodes of at most ``limit`` ray slots (one if it fits)."""
    total = int(frontier.ray_n.sum())
    if total <= limit or len(frontier.ray_n) == 1:
        return [frontier]
    runs = []
    start = 0
    held = 0
    for k, n in enumerate(frontier.ray_n):
        if held + n > limit and k > start:
            runs.append(piece(frontier, start, k))
            start, held = k, 0
        held += n
    runs.append(piece(frontier, start, len(frontier.ray_n)))
    return runs


def piece(frontier, a, b):
    """Nodes a:b of ``frontier`` as a frontier of their own (slot arrays copied, renumbered)."""
    t0 = int(frontier.tri_lo[a])
    t1 = int(frontier.tri_lo[b - 1] + frontier.tri_n[b - 1])
    r0 = int(frontier.ray_lo[a])
    r1 = int(frontier.ray_lo[b - 1] + frontier.ray_n[b - 1])
    tri_node = frontier.tri_node[t0:t1].copy_to_host() - a
    ray_node = frontier.ray_node[r0:r1].copy_to_host() - a
    return Frontier(
        frontier.depth, frontier.tri_lo[a:b] - t0, frontier.tri_n[a:b],
        frontier.ray_lo[a:b] - r0, frontier.ray_n[a:b], frontier.boxes[a:b],
        cuda.to_device(frontier.rows[t0:t1].copy_to_host()), cuda.to_device(tri_node),
        cuda.to_device(frontier.ray_ids[r0:r1].copy_to_host()), cuda.to_device(ray_node),
    )  # fmt: skip
