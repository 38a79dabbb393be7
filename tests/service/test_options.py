"""service.options: what a query or sensor may ask (one record with its defaults, and 422s that
name the choices), and the one place where an answer's keys are picked."""

from __future__ import annotations

import numpy as np
import pytest

from dacrt import InputError
from service import wire
from service.errors import Invalid
from service.options import (
    DEFAULT_MAX_HITS,
    FIELDS,
    HIT_FIELDS,
    SENSOR_FIELDS,
    Query,
    Sensor,
    make_options,
    strategies,
)


@pytest.mark.parametrize("query", list(Query))
def test_defaults_ask_for_every_field_with_the_first_strategy(query):
    options = make_options(query.value)
    assert options.kind is query and options.fields == FIELDS[query]
    assert options.strategy == strategies()[0] == "sampling"
    assert options.cull == "none" and not options.stats and options.mask is None
    assert options.max_hits == (DEFAULT_MAX_HITS if query is Query.HITS else None)


@pytest.mark.parametrize("sensor", list(Sensor))
def test_a_sensor_asks_for_every_key_of_its_answer_by_default(sensor):
    options = make_options(sensor)
    assert options.kind is sensor and options.fields == SENSOR_FIELDS[sensor]
    assert options.max_hits is None


def test_fields_come_in_answer_order_whatever_order_they_are_asked_in():
    assert make_options("closest", fields=" normal, t ,mesh").fields == ("t", "mesh", "normal")
    assert make_options(Sensor.LIDAR, fields="ray,xyz").fields == ("xyz", "ray")


def test_a_lidar_takes_pcd_columns_for_their_key_and_keeps_the_order_asked():
    """A lidar's PCD answer names a vector key's columns (x y z of xyz): the engine is asked for
    the key, and the PCD gets the names in the order asked, each column once."""
    options = make_options(Sensor.LIDAR, fields=" z,ring,x ,velocity_y,z")
    assert options.fields == ("xyz", "ring", "velocity")
    assert options.asked == ("z", "ring", "x", "velocity_y")
    answered = ("xyz", "ring", "velocity")
    assert options.pcd_fields(answered) == ("z", "ring", "x", "velocity_y")
    assert options.pcd_fields(("xyz", "ring")) == ("z", "ring", "x")  # no velocity answered
    both = make_options(Sensor.LIDAR, fields="label,y,xyz")
    assert both.pcd_fields(("xyz", "label")) == ("label", "y", "x", "z")
    assert make_options(Sensor.LIDAR).pcd_fields(answered) is None  # every field
    both.check_columns("pcd")
    with pytest.raises(Invalid, match="unknown fields 'y' for lidar; choose from xyz, range"):
        both.check_columns("npz")
    make_options(Sensor.LIDAR, fields="xyz,label").check_columns("json")
    for sensor in (Sensor.CAMERA, Sensor.RIG):  # no PCD answer
        with pytest.raises(Invalid, match=f"unknown fields 'x' for {sensor.value}"):
            make_options(sensor, fields="x")


def test_hits_fields_of_one_value_per_hit_bring_their_offsets():
    assert make_options("hits", fields="prim,t").fields == ("offsets", "t", "prim")
    assert make_options("hits", fields="truncated").fields == ("truncated",)


@pytest.mark.parametrize(
    ("kwargs", "named"),
    [
        ({"kind": "nearest"}, ["closest", "occluded", "hits", "count"]),
        ({"kind": "camera"}, ["unknown query 'camera'", "closest, occluded, hits, count"]),
        ({"kind": "closest", "fields": "t,colour"}, ["'colour'", "t, mesh, prim"]),
        ({"kind": "occluded", "fields": " , "}, ["no field", "occluded"]),
        ({"kind": Sensor.CAMERA, "fields": "xyz"}, ["'xyz' for camera", "depth, range"]),
        ({"kind": "closest", "strategy": "bvh"}, ["'bvh'", "sampling, sah, middle, rayspace"]),
        ({"kind": "count", "cull": "both"}, ["'both'", "none, back, front"]),
        ({"kind": "closest", "max_hits": 4}, ["max_hits", "hits query only"]),
        ({"kind": "hits", "max_hits": 0}, ["max_hits", "at least 1"]),
        ({"kind": "hits", "max_hits": 65, "max_hits_limit": 64}, ["1 to 64 (DACRT_MAX_HITS)"]),
        ({"kind": "hits", "max_hits": True}, ["max_hits must be an integer"]),
    ],
)
def test_an_unknown_choice_is_a_422_that_names_the_choices(kwargs, named):
    """Invalid, or the engine's own InputError for its options (both 422: errors.install)."""
    with pytest.raises((Invalid, InputError)) as raised:
        make_options(**kwargs)
    for words in named:
        assert words in str(raised.value)


def test_a_csr_answer_cannot_be_one_npy():
    assert "npy" not in make_options("hits").answer_formats
    assert "npy" not in make_options("hits", fields="t").answer_formats
    assert "npy" in make_options("hits", fields="truncated").answer_formats
    assert make_options("closest").answer_formats == wire.ANSWER_FORMATS
    assert make_options("closest").why_not_npy is None
    assert "?fields=truncated" in make_options("hits").why_not_npy


def test_the_answer_holds_the_keys_asked_for_and_makes_no_other():
    made = []

    def get(name):
        made.append(name)
        return np.zeros(1)

    arrays = make_options(Sensor.CAMERA, fields="prim,depth").pick(get)
    assert list(arrays) == made == ["depth", "prim"]


@pytest.mark.parametrize(("query", "max_hits"), [(Query.CLOSEST, None), (Query.HITS, 3)])
def test_a_sensor_traces_with_its_requests_engine_options(query, max_hits):
    asked = make_options(Sensor.LIDAR, "xyz", "rayspace", True, 2, "back", mask=0x4)
    traced = asked.traced_as(query, max_hits)
    assert traced.kind is query and traced.max_hits == max_hits
    assert traced.fields == (HIT_FIELDS if max_hits is None else ("offsets", *HIT_FIELDS))
    kept = ("strategy", "stats", "threads", "cull", "mask")
    assert [getattr(traced, name) for name in kept] == ["rayspace", True, 2, "back", 0x4]
