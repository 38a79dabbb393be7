"""Answers of the service against Embree (through embreex) on real scenes from ../shared/scenes."""

from __future__ import annotations

import numpy as np
import pytest
from service_helpers import SHARED_SCENES, rays_at

from oracles.embree import Embree

pytest.importorskip("embreex")

SCENES = ["bunny", "sibenik"]


def random_rays(vertices, n, seed):
    """Origins anywhere in the bounds, directions uniform on the sphere: hits and misses, inside and
    out."""
    rng = np.random.default_rng(seed)
    lo, hi = vertices.min(0), vertices.max(0)
    origins = rng.uniform(lo, hi, (n, 3)).astype(np.float32)
    directions = rng.normal(size=(n, 3)).astype(np.float32)
    return origins, directions


@pytest.mark.parametrize("name", SCENES)
def test_closest_agrees_with_embree(client, scene_name, name):
    path = SHARED_SCENES / f"{name}.npz"
    if not path.is_file():
        pytest.skip(f"{path} is absent (the shared scenes live beside the repository)")
    with np.load(path) as archive:
        vertices, faces = archive["vertices"], archive["faces"]
    client.put_mesh(scene_name, name, vertices, faces)
    aimed, random = (
        rays_at(vertices, faces, 10_000, seed=11),
        random_rays(vertices, 10_000, seed=12),
    )
    origins = np.concatenate([aimed[0], random[0]])
    directions = np.concatenate([aimed[1], random[1]])

    ours = client.closest(scene_name, origins, directions)
    t, prim = Embree([(vertices, faces)]).closest_t(origins, directions)

    both = np.isfinite(ours.t) & np.isfinite(t)
    assert np.mean(np.isfinite(ours.t) == np.isfinite(t)) > 0.999  # grazing edges may differ
    assert both.mean() > 0.5
    close = np.isclose(ours.t[both], t[both], rtol=1e-4, atol=1e-6 * np.ptp(vertices))
    assert close.mean() > 0.999
    assert np.mean(ours.prim[both] == prim[both]) > 0.99  # coplanar ties and shared edges aside
    assert (ours.mesh[both] == 0).all()
