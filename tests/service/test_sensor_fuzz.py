"""Random JSON bodies for /render, /camera and /lidar on a scene that exists (the schema fuzzing of
test_fuzz.py mostly meets unknown scenes): none gets a 5xx, every refusal is a ``{"detail": str}``
with a 4xx the contract names and none names the engine's arrays, and a rejected request changes
nothing. Every bad value of hostile_bodies.BAD_SENSOR_VALUES is a 422 naming its key."""

from __future__ import annotations

import json
import re

import pytest
from hostile_bodies import BAD_SENSOR_VALUES, INTERNAL_NAMES
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from sensor_helpers import put_room

numbers = st.one_of(
    st.integers(-3, 64),
    st.floats(-1e3, 1e3, allow_nan=False),
    st.sampled_from([0, 1e30, -1e30, 1e-30, 2**63, 0.5]),
    # beyond float32, at its edge, and subnormal
    st.sampled_from([1e39, -1e39, 3.5e38, 3.4e38, 1e-39, 1e-45, 5e-324, 1e-300]),
)
values = st.recursive(
    st.one_of(numbers, st.none(), st.booleans(), st.text(max_size=4)),
    lambda inner: st.lists(inner, max_size=5),
    max_leaves=20,
)
vector = st.lists(numbers, min_size=3, max_size=3)
matrix = st.lists(st.lists(numbers, min_size=4, max_size=4), min_size=4, max_size=4)
pose = st.one_of(
    matrix,
    st.just([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 1], [0, 0, 0, 1]]),
    st.just([[0, 0, 1, 0], [-1, 0, 0, 0], [0, -1, 0, 1], [0, 0, 0, 1]]),
)
size = st.one_of(st.integers(1, 24), numbers)
#: The physics of API.md "Lidar physics", sub-rays kept few: each example is traced.
PHYSICS = {
    "return_mode": st.sampled_from(["first", "last", "strongest", "dual", "all", "both"]),
    "beam_divergence_deg": numbers,
    "beam_samples": st.one_of(st.integers(-1, 6), st.sampled_from([65, 2.5, True])),
    "range_resolution": numbers,
    "attenuation": numbers,
    "noise": st.fixed_dictionaries(
        {},
        optional={
            "range_sigma": numbers,
            "range_sigma_per_m": numbers,
            "angle_sigma_deg": numbers,
            "seed": numbers,
        },
    ),
    "dropout": st.fixed_dictionaries(
        {}, optional={"rate": numbers, "min_intensity": numbers, "seed": numbers}
    ),
    "non_hits": st.sampled_from(["drop", "keep", "x"]),
    "organized": st.sampled_from([True, False, 1]),
}
LOOK_AT = {"width": size, "height": size, "eye": vector, "target": vector}
#: (required keys, optional keys) of the bodies of each route, and of each kind of camera.
SHAPES = {
    "render": [
        (LOOK_AT, {"up": vector, "fov_deg": numbers, "shading": st.sampled_from(["depth", "x"])})
    ],
    "camera": [
        (LOOK_AT, {"up": vector, "fov_deg": numbers, "near": numbers, "far": numbers}),
        (
            {
                "width": size,
                "height": size,
                "fx": numbers,
                "fy": numbers,
                "cx": numbers,
                "cy": numbers,
                "pose": pose,
            },
            {"near": numbers, "far": numbers, "eye": vector},
        ),
    ],  # fmt: skip
    "lidar": [
        (
            {"pose": pose, "model": st.sampled_from(["VLP-16", "HDL-64E", "OS1-128", "?"])},
            {
                "horizontal_steps": size,
                "min_range": numbers,
                "max_range": numbers,
                "max_returns": numbers,
                "vertical_angles_deg": st.lists(numbers, max_size=6),
                **PHYSICS,
            },
        ),
        (
            {"pose": pose, "vertical_angles_deg": st.lists(numbers, max_size=6)},
            {
                "horizontal_steps": size,
                "min_range": numbers,
                "max_range": numbers,
                "max_returns": numbers,
                **PHYSICS,
            },
        ),
    ],  # fmt: skip
    "sensors": [
        (
            {
                "sensors": st.dictionaries(
                    st.sampled_from(["roof", "front", "a.b", "?"]),
                    st.one_of(
                        st.fixed_dictionaries(
                            {"kind": st.just("lidar"), "pose": pose, "model": st.just("VLP-16")},
                            optional={"horizontal_steps": size, **PHYSICS},
                        ),
                        st.fixed_dictionaries(
                            {"kind": st.sampled_from(["camera", "radar"]), **LOOK_AT},
                            optional={"fov_deg": numbers, "far": numbers},
                        ),
                    ),
                    max_size=3,
                )
            },
            {},
        ),
    ],
}


def bodies(route: str):
    """Objects with the route's required keys (mostly well-typed values) and some optional ones,
    or any of its keys with any JSON values, now and then with a stray key."""
    typed = [
        st.fixed_dictionaries(required, optional=optional) for required, optional in SHAPES[route]
    ]
    keys = sorted({k for required, optional in SHAPES[route] for k in [*required, *optional]})
    loose = st.dictionaries(st.sampled_from([*keys, "zoom"]), values, max_size=len(keys))
    return st.one_of(*typed, *typed, loose)


@pytest.fixture(scope="module")
def fuzz_room(app_client):
    from service.client import Client

    put_room(Client(http=app_client), "fuzz-room")
    return "fuzz-room"


@pytest.mark.parametrize("route", list(SHAPES))
def test_no_body_gets_a_server_error(app_client, fuzz_room, route):
    version = app_client.get(f"/v1/scenes/{fuzz_room}").json()["version"]

    @given(body=bodies(route))
    @settings(
        max_examples=200,
        deadline=None,
        derandomize=True,
        database=None,
        suppress_health_check=list(HealthCheck),
    )
    def call(body):
        response = app_client.post(f"/v1/scenes/{fuzz_room}/{route}", json=body)
        assert response.status_code in (200, 400, 413, 422), (body, response.text[:300])
        if response.status_code != 200:
            assert list(response.json()) == ["detail"], response.text
            assert not re.search(INTERNAL_NAMES, response.json()["detail"]), (body, response.text)

    call()
    assert app_client.get(f"/v1/scenes/{fuzz_room}").json()["version"] == version


@pytest.mark.parametrize(
    "route, body, phrase",
    BAD_SENSOR_VALUES,
    ids=[
        f"{route}-{phrase.split(':')[0]}-{i}"
        for i, (route, _, phrase) in enumerate(BAD_SENSOR_VALUES)
    ],
)
def test_every_bad_sensor_value_is_a_422_naming_its_key(app_client, fuzz_room, route, body, phrase):
    response = app_client.post(
        f"/v1/scenes/{fuzz_room}/{route}",
        content=json.dumps(body),  # NaN and Infinity as Python's json writes them
        headers={"Content-Type": "application/json"},
    )
    detail = response.json()["detail"]
    assert response.status_code == 422 and phrase in detail, detail
    assert not re.search(INTERNAL_NAMES, detail), detail
