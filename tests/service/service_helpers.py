"""Meshes, rays and paths shared by the service tests (a module, not a conftest, so tests import
it)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[2]
SHARED_SCENES = REPO.parent / "shared" / "scenes"
#: The second test server's bearer token and limits (tiny, so that 413s are cheap to provoke).
TOKEN = "test-token-3f9a"
SECURE_LIMITS = {
    "DACRT_MAX_BODY_BYTES": "64KiB",
    "DACRT_MAX_RAYS_PER_REQUEST": "1000",
    "DACRT_MAX_TRIANGLES_PER_SCENE": "1000",
    "DACRT_MAX_SCENE_BYTES": "200000",
}
#: The hostile corpus server's body limit: a zip bomb under it could inflate to gigabytes.
HOSTILE_BODY_LIMIT = "4MiB"


def quad(x0: float, x1: float, y0: float, y1: float, z: float) -> tuple[np.ndarray, np.ndarray]:
    """Two triangles covering [x0, x1] x [y0, y1] at height z, normals +z."""
    vertices = np.array([[x0, y0, z], [x1, y0, z], [x1, y1, z], [x0, y1, z]], np.float32)
    return vertices, np.array([[0, 1, 2], [0, 2, 3]], np.int32)


def grid(n: int, z: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """An n x n grid of quads on [0, 1]^2 at height z: 2 n^2 triangles, (n+1)^2 vertices."""
    xs = np.linspace(0.0, 1.0, n + 1, dtype=np.float32)
    x, y = np.meshgrid(xs, xs, indexing="ij")
    vertices = np.stack([x.ravel(), y.ravel(), np.full(x.size, z, np.float32)], axis=1)
    ids = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b, c, d = (
        ids[:-1, :-1].ravel(),
        ids[1:, :-1].ravel(),
        ids[1:, 1:].ravel(),
        ids[:-1, 1:].ravel(),
    )
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)]).astype(np.int32)
    return vertices, faces


def down_rays(xy: np.ndarray, z: float = 10.0) -> tuple[np.ndarray, np.ndarray]:
    """Rays from (x, y, z) straight down (-z), one per row of ``xy``."""
    xy = np.asarray(xy, np.float32)
    origins = np.column_stack([xy, np.full(len(xy), z, np.float32)])
    directions = np.tile(np.array([0, 0, -1], np.float32), (len(xy), 1))
    return origins, directions


def rays_at(
    vertices: np.ndarray, faces: np.ndarray, n: int, seed: int = 0, distance: float = 3.0
) -> tuple[np.ndarray, np.ndarray]:
    """Rays from random points outside a mesh's bounds towards random points inside its
    triangles."""
    rng = np.random.default_rng(seed)
    lo, hi = vertices.min(0), vertices.max(0)
    centre, radius = (lo + hi) / 2, np.linalg.norm(hi - lo) / 2
    tri = faces[rng.integers(0, len(faces), n)]
    w = rng.uniform(0.1, 0.45, (n, 2))
    targets = (
        vertices[tri[:, 0]] * (1 - w.sum(1, keepdims=True))
        + vertices[tri[:, 1]] * w[:, :1]
        + vertices[tri[:, 2]] * w[:, 1:]
    )
    away = rng.normal(size=(n, 3))
    origins = centre + distance * radius * away / np.linalg.norm(away, axis=1, keepdims=True)
    return origins.astype(np.float32), (targets - origins).astype(np.float32)


def npy_bytes(array) -> bytes:
    """An .npy body (pickle allowed here only so tests can send object arrays)."""
    import io

    out = io.BytesIO()
    np.save(out, array, allow_pickle=True)
    return out.getvalue()


def npz_bytes(compressed: bool = False, **arrays) -> bytes:
    import io

    out = io.BytesIO()
    (np.savez_compressed if compressed else np.savez)(out, **arrays)
    return out.getvalue()


NPY = {"Content-Type": "application/x-npy"}
NPZ = {"Content-Type": "application/x-npz"}


def metric_sample(text: str, sample: str) -> float:
    """The value of ``sample`` (a name with its labels, as Prometheus writes it) in /metrics
    text; 0 when it is absent, as for a counter nothing has counted yet."""
    for line in text.splitlines():
        if line.startswith(sample + " "):
            return float(line.split()[-1])
    return 0.0
