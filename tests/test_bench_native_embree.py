"""``bench.native_embree`` on a small closed box: it files the kernels with
``dacrt.cache.use_cache_dir()`` before the first query, and each ray set's first refit frame is
untimed as its first new-Scene frame is. Skipped where the shared anchor cannot be compiled (no
g++, no Embree 3 headers, no ../shared); nothing here is timed."""

from __future__ import annotations

import numpy as np
import pytest

import dacrt.cache
from bench import native_embree as N
from bench.world import find_shared


def closed_box(path):
    """A closed 2 m cube of 12 triangles, written as ``path`` (.npz: vertices, faces)."""
    corners = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], np.float32)
    faces = [[0, 2, 3], [0, 3, 1], [4, 5, 7], [4, 7, 6], [0, 1, 5], [0, 5, 4]]
    faces += [[2, 6, 7], [2, 7, 3], [0, 4, 6], [0, 6, 2], [1, 3, 7], [1, 7, 5]]
    np.savez(path, vertices=2 * corners - 1, faces=np.array(faces, np.int32))
    return path


@pytest.fixture(scope="module")
def anchor(tmp_path_factory):
    """(source, build folder) of the shared anchor, compiled once."""
    shared = find_shared()
    if shared is None:
        pytest.skip("no ../shared beside the repository (the anchor's source)")
    source = shared / "anchors" / "embree_native.cpp"
    folder = tmp_path_factory.mktemp("anchor")
    try:
        N.build_anchor(source, folder)
    except N.AnchorUnavailable as exc:
        pytest.skip(str(exc))
    return source, folder


def test_kernels_filed_first_and_first_refit_untimed(anchor, tmp_path, monkeypatch):
    events = []  # "cache", then "new" / "refit" of every dacrt frame, in order
    use_cache_dir, frame = dacrt.cache.use_cache_dir, N.dacrt_frame

    def noted_cache(*args, **kwargs):
        events.append("cache")
        return use_cache_dir(*args, **kwargs)

    def noted_frame(engine, vertices, faces, rays, threads, previous=None):
        events.append("new" if previous is None else "refit")
        return frame(engine, vertices, faces, rays, threads, previous)

    monkeypatch.setattr(dacrt.cache, "use_cache_dir", noted_cache)
    monkeypatch.setattr(N, "dacrt_frame", noted_frame)
    source, folder = anchor
    argv = [str(closed_box(tmp_path / "box.npz")), "--rays", "256", "--kinds", "primary,random"]
    argv += ["--repeat", "4", "--threads", "1", "--anchor", str(source), "--build-dir", str(folder)]
    assert N.main(argv) == 0
    assert events[0] == "cache" and events.count("cache") == 1
    # per ray set: 4 timed frames of each, after one untimed (the answers) of each
    assert events.count("new") == events.count("refit") == 2 * (1 + 4)
