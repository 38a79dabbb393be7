"""Answers: the format an ``Accept`` header asks for, and the body of an answer in it."""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Iterator, Mapping, Sequence
from typing import Any

import numpy as np

from dacrt.sensors.pcd import pcd_bytes

from ..errors import NotAcceptable
from .formats import ANSWER_FORMATS, CONTENT_TYPES, JSON, MEDIA_TYPES, NPY, NPZ, PCD, Buffer
from .npy import array_bytes, npy_header
from .npz_writer import NpzBody


def negotiate(
    accept: str | None,
    request_format: str,
    formats: tuple[str, ...] = ANSWER_FORMATS,
    why_not: str | None = None,
) -> str:
    """The answer format for an ``Accept`` header: one of ``formats`` (npz, npy or json; 406 if
    none fits, with ``why_not`` saying why the answer has no other format). The best quality
    wins, then the range listed first, then the request's own format (json for a JSON request,
    else npz), then the order of ``formats``."""
    default = "json" if request_format == "json" else "npz"
    if not accept or not accept.strip():
        return default
    ranges = media_ranges(accept)
    ranked = []
    for order, fmt in enumerate(formats):
        aliases = [media for media, known in CONTENT_TYPES.items() if known == fmt]
        q, position = quality(ranges, aliases)
        if q > 0:
            ranked.append((-q, position, fmt != default, order, fmt))
    if ranked:
        return min(ranked)[-1]
    choices = [MEDIA_TYPES[fmt] for fmt in formats]
    raise NotAcceptable(
        f"Accept: {accept} names no format {why_not}"
        if why_not
        else f"Accept: {accept} names no format this answer is written in; use "
        f"{', '.join(choices[:-1])} or {choices[-1]}"
    )


def check_accepts(accept: str | None, media: str) -> None:
    """406 unless ``Accept`` (if any) admits ``media``, the only answer of its route (a PNG)."""
    if not accept or not accept.strip():
        return
    if quality(media_ranges(accept), [media])[0] > 0:
        return
    raise NotAcceptable(f"Accept: {accept} does not admit {media}, the only answer of this route")


def media_ranges(accept: str) -> list[tuple[str, float]]:
    """The media ranges of an ``Accept`` header with their q (``q=0``: not acceptable), in the
    header's order, lower case."""
    ranges = []
    for part in accept.split(","):
        media, *params = [p.strip() for p in part.split(";")]
        q = 1.0
        for param in params:
            name, _, value = param.partition("=")
            if name.strip().lower() == "q":
                try:
                    q = float(value)
                except ValueError:
                    q = 0.0
        ranges.append((media.lower(), q))
    return ranges


def quality(ranges: list[tuple[str, float]], names: list[str]) -> tuple[float, int]:
    """(q, position) of a media type known by ``names`` (its aliases) under the most specific
    ranges that match one of them (RFC 9110 12.5.1: ``type/sub`` over ``type/*`` over
    ``*/*``): the best q of those, the first listed; (0, its length) when none matches."""
    kinds = {name.split("/", 1)[0] + "/*" for name in names}
    for patterns in (set(names), kinds, {"*/*"}):
        matches = [(-q, i) for i, (given, q) in enumerate(ranges) if given in patterns]
        if matches:
            best, position = min(matches)
            return -best, position
    return 0.0, len(ranges)


def encode_answer(
    arrays: Mapping[str, np.ndarray], fmt: str, pcd_fields: Sequence[str] | None = None
) -> tuple[Iterable[Buffer], int | None, str]:
    """(body as buffers to send in order, its length, Content-Type) of an answer: npz, npy or json,
    or a lidar's pcd of ``pcd_fields`` in their order (None: every field), as ``pcd_bytes``.

    The buffers of npy and npz bodies are mostly the answer arrays' own memory: nothing is copied.
    An npz body takes each member's CRC as it is sent (``NpzBody``). A JSON body is written piece
    by piece as it is sent, in bounded memory; its length is not known in advance (None).
    """
    if fmt == "npz":
        body = NpzBody(arrays)
        return body, body.length, NPZ
    if fmt == "npy":
        parts = npy_parts(arrays)
        return parts, sum(len(part) for part in parts), NPY
    if fmt == "json":
        return json_pieces(arrays), None, JSON
    if fmt == "pcd":
        body = pcd_bytes(arrays, pcd_fields)
        return [body], len(body), PCD
    raise ValueError(f"unknown answer format {fmt!r}")


def encode_rig_answer(
    arrays: Mapping[str, np.ndarray], fmt: str
) -> tuple[Iterable[Buffer], int | None, str]:
    """A rig's answer of ``NAME.KEY`` arrays: the npz as they are named, or JSON ``{"NAME":
    {"KEY": [...]}}`` (a name may hold dots: the key is what follows the last one)."""
    if fmt != "json":
        return encode_answer(arrays, fmt)
    sensors: dict[str, dict[str, np.ndarray]] = {}
    for name, array in arrays.items():
        sensor, _, key = name.rpartition(".")
        sensors.setdefault(sensor, {})[key] = array
    return _nested_pieces(sensors), None, JSON


def _nested_pieces(sensors: Mapping[str, Mapping[str, np.ndarray]]) -> Iterator[bytes]:
    separator = "{"
    for name, arrays in sensors.items():
        yield f"{separator}{json.dumps(name)}:".encode()
        yield from json_pieces(arrays)
        separator = ","
    yield b"}" if sensors else b"{}"


def npy_parts(arrays: Mapping[str, np.ndarray]) -> list[Buffer]:
    """One .npy: the array itself if there is one field, else a structured array of all of them."""
    if len(arrays) == 1:
        (array,) = arrays.values()
        return [npy_header(array.dtype, array.shape), array_bytes(array)]
    n = len(next(iter(arrays.values()))) if arrays else 0
    records = np.empty(n, dtype=[(k, a.dtype, a.shape[1:]) for k, a in arrays.items()])
    for key, array in arrays.items():
        records[key] = array
    return [npy_header(records.dtype, records.shape), array_bytes(records)]


def encode_json(arrays: Mapping[str, np.ndarray]) -> bytes:
    """``{"key": [...], ...}`` with float32 in shortest round-trip form and null for inf/nan."""
    return _dumps({key: json_ready(array) for key, array in arrays.items()}).encode()


#: Values a piece of a JSON answer holds at the most (whole rows of an array, or of one of its
#: rows): its text and lists stay within tens of MiB however large the answer
#: (``footprint.JSON_ANSWER_BYTES``), an image's rows as a lidar's points.
JSON_PIECE_ITEMS = 16384


def json_pieces(arrays: Mapping[str, np.ndarray]) -> Iterator[bytes]:
    """``encode_json(arrays)`` as consecutive pieces of at most JSON_PIECE_ITEMS values each."""
    separator = "{"
    for key, array in arrays.items():
        yield f"{separator}{json.dumps(key)}:".encode()
        yield from _array_pieces(array)
        separator = ","
    yield b"}" if arrays else b"{}"


def _array_pieces(array: np.ndarray) -> Iterator[bytes]:
    """The JSON text of ``array`` (nested lists): runs of whole rows of at most JSON_PIECE_ITEMS
    values, or, where one row holds more, each row's own pieces in turn."""
    if array.ndim == 0:
        yield _dumps(json_ready(array)).encode()
        return
    row_values = math.prod(array.shape[1:])
    if row_values > JSON_PIECE_ITEMS:
        yield b"["
        for i, row in enumerate(array):
            if i:
                yield b","
            yield from _array_pieces(row)
        yield b"]"
        return
    rows = JSON_PIECE_ITEMS // max(row_values, 1)
    yield b"["
    for start in range(0, len(array), rows):
        piece = _dumps(json_ready(array[start : start + rows]))
        yield (piece[1:-1] if start == 0 else "," + piece[1:-1]).encode()
    yield b"]"


def _dumps(value: Any) -> str:
    """Compact JSON, refusing NaN and infinities (``json_ready`` made them null)."""
    return json.dumps(value, separators=(",", ":"), allow_nan=False)


def json_ready(array: np.ndarray) -> Any:
    """Nested lists for ``json.dumps``: shortest float32 repr, None where not finite."""
    if array.dtype.kind != "f":
        return array.tolist()
    shortest = array.astype(str).astype(np.float64)  # '0.1' for float32(0.1), not 0.10000000149
    finite = np.isfinite(array)
    if finite.all():
        return shortest.tolist()
    values = shortest.astype(object)
    values[~finite] = None
    return values.tolist()
