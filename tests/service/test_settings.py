"""Settings from DACRT_* environment variables, with sizes in units."""
from __future__ import annotations

import pytest
from pydantic import ValidationError

from service.settings import MiB, Settings, parse_size


def test_defaults_are_sane(monkeypatch):
    for name in ("TOKEN", "MAX_BODY_BYTES", "MAX_RAYS_PER_REQUEST", "MAX_TRIANGLES_PER_SCENE",
                 "MAX_SCENE_BYTES", "LOAD_DEMO", "HOST", "PORT"):
        monkeypatch.delenv(f"DACRT_{name}", raising=False)
    settings = Settings()
    assert settings.token is None and settings.load_demo is False
    assert settings.max_body_bytes == 512 * MiB and settings.max_rays_per_request == 16 * MiB
    assert settings.max_triangles_per_scene == 32 * MiB and settings.max_scene_bytes == 4 * 2**30
    assert (settings.host, settings.port) == ("127.0.0.1", 8000)


def test_environment_sets_everything(monkeypatch):
    monkeypatch.setenv("DACRT_TOKEN", "s3cret")
    monkeypatch.setenv("DACRT_MAX_BODY_BYTES", "64MiB")
    monkeypatch.setenv("DACRT_MAX_RAYS_PER_REQUEST", "1000")
    monkeypatch.setenv("DACRT_LOAD_DEMO", "true")
    monkeypatch.setenv("DACRT_PORT", "9001")
    settings = Settings()
    assert settings.token.get_secret_value() == "s3cret" and "s3cret" not in repr(settings)
    assert settings.max_body_bytes == 64 * MiB and settings.max_rays_per_request == 1000
    assert settings.load_demo and settings.port == 9001


def test_empty_token_means_no_token(monkeypatch):
    monkeypatch.setenv("DACRT_TOKEN", "")
    assert Settings().token is None


@pytest.mark.parametrize("text, value", [("10", 10), ("10k", 10240), ("2 MiB", 2 * MiB), ("1GB", 10**9),
                                         ("4GiB", 4 * 2**30), ("1_000", 1000)])
def test_sizes_take_units(text, value):
    assert parse_size(text) == value


@pytest.mark.parametrize("field, value", [("max_body_bytes", "0"), ("max_rays_per_request", "-5"),
                                          ("max_scene_bytes", "lots"), ("port", "70000")])
def test_bad_values_are_refused(field, value):
    with pytest.raises(ValidationError):
        Settings(**{field: value})


def test_demo_scene_is_found_in_the_checkout(monkeypatch, tmp_path):
    monkeypatch.delenv("DACRT_DEMO_SCENE", raising=False)
    monkeypatch.chdir(tmp_path)  # not in the working directory: found next to the package
    assert Settings().demo_path().name == "teapot.npz"
