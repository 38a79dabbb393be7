"""Scenes for the engine tests: the shared real scenes, and named, seeded procedural ones.

Each procedural builder takes a seed and returns a list of meshes ``[(vertices, faces), ...]``;
``mixed_rays`` takes the meshes and a seed and returns ``(origins, directions)``, (n, 3) float32.
``load_shared(name)`` reads ``../shared/scenes/{name}.npz`` or skips the calling test.

(The loader lives here rather than in conftest.py: test modules must not import a conftest, since
``tests/service/conftest.py`` takes the module name ``conftest`` too.)
"""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np
import procedural as pg
import pytest

# ../shared/scenes relative to the repository root (tests/ -> repo -> its parent).
SHARED_SCENES = Path(__file__).resolve().parents[2] / "shared" / "scenes"


@functools.cache
def _read_npz(path: str):
    with np.load(path) as z:
        vertices, faces = z["vertices"], z["faces"]
    # Read-only, since several tests share one cached copy.
    vertices.flags.writeable = False
    faces.flags.writeable = False
    return vertices, faces


def load_shared(name: str):
    """Vertices (v, 3) float32 and faces (f, 3) int32 of ``../shared/scenes/{name}.npz`` (cached,
    read-only).

    Skips the calling test when the folder or the file is absent.
    """
    if not SHARED_SCENES.is_dir():
        pytest.skip("../shared/scenes not present")
    path = SHARED_SCENES / f"{name}.npz"
    if not path.is_file():
        pytest.skip(f"../shared/scenes/{name}.npz not present")
    return _read_npz(str(path))


def soup(seed):
    """1500 random triangles in the unit cube."""
    return [pg.triangle_soup(1500, np.random.default_rng(seed))]


def sphere(seed):
    """A radially perturbed icosphere (1280 faces), closed."""
    v, f = pg.icosphere(3)
    return [(pg.perturb_radially(v, np.random.default_rng(seed), 0.1), f)]


def tilted_grid(seed):
    """A 24 x 24 grid with alternating diagonals, rotated and shifted out of the axis planes."""
    rng = np.random.default_rng(seed)
    v, f = pg.grid(24, 2.0, alternate=True)
    return [
        (
            pg.transform(
                v, pg.rotation(rng.normal(size=3), rng.uniform(0.3, 1.2)), (0.3, -0.2, 0.1)
            ),
            f,
        )
    ]


def degenerate_mix(seed):
    """A soup of 300 triangles with 100 exactly degenerate ones shuffled in."""
    v, f, _, _ = pg.with_degenerates(np.random.default_rng(seed))
    return [(v, f)]


def multi(seed):
    """Four meshes of different kinds (grid, perturbed icosphere, soup, UV sphere)."""
    return pg.multi_mesh(np.random.default_rng(seed))


def pinwheel(seed):
    """800 triangles sharing one centroid (no centroid extent to split on)."""
    return [pg.pinwheel(800, np.random.default_rng(seed))]


SCENES = {
    "pinwheel": pinwheel,
    "soup": soup,
    "sphere": sphere,
    "tilted_grid": tilted_grid,
    "degenerate_mix": degenerate_mix,
    "multi": multi,
}


def mixed_rays(meshes, seed, n=1500):
    """Half random rays around the scene, half rays aimed into its bounding box."""
    vertices, _, _ = pg.concat(meshes)
    return pg.mixed_rays(pg.bounds(vertices), n, np.random.default_rng(seed + 1000))
