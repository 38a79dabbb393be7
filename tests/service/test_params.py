"""service.params: what the OpenAPI document declares of each parameter is what the service's own
checks accept (names, masks, the engine's strategies and culling modes, the body formats), and
the query string reaches the one options record unchanged, the mask parsed."""

from __future__ import annotations

import re
from typing import Any, get_args

import pytest

from service import footprint, options, params, wire
from service.errors import Invalid
from service.options import Options, Query, Sensor, make_options
from service.settings import Settings
from service.store import check_name


def declared(parameter: Any) -> dict:
    """The JSON-schema extras of an ``Annotated[..., Query(...)]`` or ``Path(...)``."""
    return get_args(parameter)[1].json_schema_extra


NAMES = ["demo", "a", "A-z_0.9", "x" * 64, "x" * 65, "", "bad/name", "sp ace", ".", "..", "é"]


@pytest.mark.parametrize("parameter", [params.SceneName, params.MeshName])
@pytest.mark.parametrize("name", NAMES)
def test_every_name_the_store_accepts_matches_the_declared_pattern(parameter, name):
    pattern = declared(parameter)["pattern"]
    try:
        check_name("scene", name)
    except Invalid:
        # refused: by the pattern, or ('.' and '..') by the store's one extra rule
        assert not re.fullmatch(pattern, name) or name in (".", "..")
    else:
        assert re.fullmatch(pattern, name)


MASKS = ["0", "255", "0xff", "0XFF", "0xFFFFFFFF", "4294967295", "-1", "1.5", "ff", "0x", "x1"]


@pytest.mark.parametrize("text", MASKS)
def test_every_mask_the_service_parses_matches_the_declared_pattern(text):
    pattern = declared(params.RayMask)["pattern"]
    try:
        wire.parse_mask(text, "?mask")
    except Invalid:
        return
    assert re.fullmatch(pattern, text)


def test_the_declared_choices_are_the_engines_and_the_services():
    assert declared(params.Strategy)["enum"] == list(options.strategies())
    assert declared(params.Cull)["enum"] == list(options.CULL_MODES)
    assert declared(params.QueryKind)["enum"] == [q.value for q in Query]
    formats = {
        params.RayFormat: wire.RAY_FORMATS,
        params.MeshFormat: wire.MESH_FORMATS,
        params.VertexFormat: wire.VERTEX_FORMATS,
        params.FrameFormat: wire.FRAME_FORMATS,
        params.TraceFormat: wire.TRACE_FORMATS,
    }
    for parameter, accepted in formats.items():
        assert declared(parameter)["enum"] == list(accepted)


def test_the_options_default_to_the_engines_defaults():
    settings = Settings()
    options = params.hits_options(settings)
    assert options == make_options("hits", threads=settings.threads)
    assert params.render_options(settings) == make_options(Sensor.RENDER)


def test_the_query_string_reaches_the_options_with_the_mask_parsed():
    settings = Settings(threads=2, max_hits=8)
    options = params.hits_options(
        settings, fields="t", strategy="rayspace", stats=True, cull="back", mask="0x10", max_hits=3
    )
    assert options == Options(
        Query.HITS, ("offsets", "t"), "rayspace", True, 2, "back", 3, 0x10, asked=("t",)
    )
    with pytest.raises(Invalid, match=r"1 to 8 \(DACRT_MAX_HITS\)"):
        params.hits_options(settings, max_hits=9)


def test_the_one_shot_trace_takes_a_query_by_name_only():
    settings = Settings()
    assert params.trace_options(settings, query="count").kind is Query.COUNT
    with pytest.raises(Invalid, match="unknown query 'camera'"):
        params.trace_options(settings, query="camera")


@pytest.mark.parametrize("mask", ["0x1FFFFFFFF", "-1", "twelve"])
def test_a_bad_mask_is_a_422_naming_the_query_parameter(mask):
    with pytest.raises(Invalid, match=r"\?mask="):
        params.hits_options(Settings(), mask=mask)


def test_a_hits_query_keeps_16_hits_a_ray_by_default():
    assert make_options("hits").max_hits == 16
    assert params.hits_options(Settings()).max_hits == 16


def test_hit_buffers_hold_max_hits_plus_one_slots_a_ray():
    assert (
        make_options("hits", max_hits=3).hit_buffer_bytes(10) == 10 * 4 * footprint.HIT_SLOT_BYTES
    )
    assert make_options("closest").hit_buffer_bytes(10) == 0


def test_a_pictures_cull_reaches_its_options():
    assert params.render_options(Settings(), cull="back").cull == "back"


def test_the_one_shot_trace_answers_closest_by_default():
    assert params.trace_options(Settings()).kind is Query.CLOSEST
