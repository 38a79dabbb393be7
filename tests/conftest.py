"""Shared fixtures of the engine tests: the shared scene files, and one engine warm-up per
session."""

from __future__ import annotations

from pathlib import Path

import pytest
import sample_scenes


@pytest.fixture(scope="session")
def shared_scenes() -> Path:
    """Path of ``../shared/scenes`` beside the repository (it may be absent: ``load_shared`` skips
    then)."""
    return sample_scenes.SHARED_SCENES


@pytest.fixture(scope="session")
def load_shared():
    """``load_shared(name) -> (vertices, faces)``; skips the test when
    ``../shared/scenes/{name}.npz`` is absent."""
    return sample_scenes.load_shared


@pytest.fixture(scope="session", autouse=True)
def warm_engine():
    """Compile every engine kernel once, before the first test, so that no test pays for it;
    kept where the service keeps them, so that a ``python -m service.warmup`` before (as in CI)
    has compiled them already."""
    import dacrt  # Lazily: collection must work without importing the engine.
    import dacrt.cache

    dacrt.cache.use_cache_dir()
    return dacrt.warmup()
