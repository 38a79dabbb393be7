"""Loading a benchmark scene (mesh + camera view) from a path.

A scene path is an ``.npz`` with ``vertices`` (V,3) and ``faces`` (F,3), or any mesh file trimesh
reads (several objects are merged). Its view comes from ``scenes/views.json`` by file stem; a
scene with no entry gets an automatic view from outside its bounds.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

VIEWS_PATH = Path(__file__).resolve().parent.parent / "scenes" / "views.json"


def load_mesh(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """(vertices (V,3) float32, faces (F,3) int32), C-contiguous."""
    path = Path(path)
    if path.suffix.lower() == ".npz":
        with np.load(path) as z:
            vertices, faces = z["vertices"], z["faces"]
    else:
        import trimesh  # only for mesh files

        mesh = trimesh.load(path, force="mesh", process=False)
        vertices, faces = mesh.vertices, mesh.faces
    vertices = np.ascontiguousarray(vertices, dtype=np.float32).reshape(-1, 3)
    faces = np.ascontiguousarray(faces, dtype=np.int32).reshape(-1, 3)
    if len(faces) == 0:
        raise SystemExit(f"{path}: no triangles")
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise SystemExit(f"{path}: face indices out of range [0, {len(vertices)})")
    return vertices, faces


def mesh_bounds(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(2, 3) float64 [[min], [max]] of the vertices the faces use."""
    used = vertices[np.unique(faces)].astype(np.float64)
    return np.stack([used.min(axis=0), used.max(axis=0)])


def auto_view(bounds: np.ndarray) -> dict:
    """A view from outside the bounds, seeing all of them; Y up; light above the camera."""
    centre = bounds.mean(axis=0)
    radius = 0.5 * float(np.linalg.norm(bounds[1] - bounds[0]))
    fov = 40.0
    direction = np.array([0.55, 0.45, 0.7])
    direction /= np.linalg.norm(direction)
    eye = centre + direction * radius / np.sin(np.radians(fov / 2.0))
    light = centre + np.array([0.3, 1.2, 0.6]) * radius
    return {
        "eye": eye.tolist(),
        "target": centre.tolist(),
        "up": [0.0, 1.0, 0.0],
        "fov_deg": fov,
        "light": light.tolist(),
        "note": "automatic view (no entry in views.json)",
    }


def load_view(
    scene_path: str | Path,
    bounds: np.ndarray,
    name: str | None = None,
    views_path: str | Path = VIEWS_PATH,
) -> tuple[str, dict]:
    """(key used, view dict) for the scene: the entry ``name`` or the file stem, else automatic."""
    key = name or Path(scene_path).stem
    views = {}
    if Path(views_path).exists():
        views = {
            k: v
            for k, v in json.loads(Path(views_path).read_text()).items()
            if not k.startswith("_")
        }
    if key in views:
        return key, views[key]
    if name is not None:
        raise SystemExit(f"no view {name!r} in {views_path}; have {sorted(views)}")
    return "auto", auto_view(bounds)
