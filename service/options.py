"""What a request asks of the engine: one options record for every query and sensor, built once
per request from its query string (``params`` declares the parameters and the routes'
dependencies), and the one place where ``?fields=`` is read and an answer's arrays are picked.

What only the service knows (the kinds, their fields, ``max_hits`` within DACRT_MAX_HITS) is
checked here; what the engine owns (strategy, culling) is checked by the engine, whose
``InputError`` is 422 through ``errors``' one table.
"""

from __future__ import annotations

from collections.abc import Callable, Collection
from dataclasses import dataclass, replace
from enum import Enum

import numpy as np

import dacrt
from dacrt.sensors import CAMERA_FIELDS, LIDAR_FIELDS
from dacrt.sensors.pcd import VECTOR_FIELDS
from dacrt.validation import check_cull, check_strategy

from . import footprint
from .errors import Invalid
from .wire import ANSWER_FORMATS, JSON, NPZ, cut, quoted


class Query(str, Enum):  # noqa: UP042 - StrEnum would change str() and format() of members
    """Kinds of query: a batch of rays sent by the client."""

    CLOSEST = "closest"
    OCCLUDED = "occluded"
    HITS = "hits"
    COUNT = "count"


class Sensor(str, Enum):  # noqa: UP042 - as Query
    """Kinds of sensor: rays the server makes from a few numbers and traces as a query."""

    RENDER = "render"
    CAMERA = "camera"
    LIDAR = "lidar"
    RIG = "sensors"


#: The answer keys of each query, in answer order; ``?fields=`` picks a subset.
FIELDS: dict[Query, tuple[str, ...]] = {
    Query.CLOSEST: ("t", "mesh", "prim", "u", "v", "normal"),
    Query.OCCLUDED: ("occluded",),
    Query.HITS: ("offsets", "t", "mesh", "prim", "u", "v", "normal", "truncated"),
    Query.COUNT: ("count",),
}
#: The answer keys of each sensor, in answer order (the engine's): a camera's are (height, width)
#: (``normal`` (height, width, 3)), a lidar's one row per point (``time`` for a pattern with
#: times only), a picture is one PNG (no keys), and a rig's sensors answer those of their kind.
SENSOR_FIELDS: dict[Sensor, tuple[str, ...]] = {
    Sensor.RENDER: (),
    Sensor.CAMERA: CAMERA_FIELDS,
    Sensor.LIDAR: LIDAR_FIELDS,
    Sensor.RIG: LIDAR_FIELDS + tuple(name for name in CAMERA_FIELDS if name not in LIDAR_FIELDS),
}
#: The names a lidar's PCD answer takes in ``?fields=`` besides the keys: each column of a vector
#: key (``x`` of ``xyz``, ``velocity_x`` of ``velocity``), as ``dacrt.sensors.pcd`` names them,
#: and the key it stands for.
PCD_COLUMNS: dict[str, str] = {
    column: key for key, columns in VECTOR_FIELDS.items() for column in columns
}
#: The keys of a hits answer with one value per hit: they come with ``offsets`` (CSR), listed in
#: ``?fields=`` or not.
PER_HIT_FIELDS = ("t", "mesh", "prim", "u", "v", "normal")
#: What a sensor asks of the engine's ``closest`` (or, with ``offsets``, ``hits``) for each ray.
HIT_FIELDS = ("t", "mesh", "prim", "normal")
#: ``max_hits`` of a hits query that does not give it (API.md).
DEFAULT_MAX_HITS = 16


def strategies() -> tuple[str, ...]:
    """The engine's partitioning strategies; the first is the default."""
    return tuple(dacrt.STRATEGIES)


#: Face culling modes: the engine's (none, back, front).
CULL_MODES = tuple(dacrt.CULL_MODES)


@dataclass(frozen=True)
class Options:
    """What one request asks, for the whole batch: its kind, the answer's keys and how the engine
    traces its rays."""

    kind: Query | Sensor
    fields: tuple[str, ...]  #: the answer's keys, in answer order
    strategy: str
    stats: bool = False
    threads: int | None = None
    cull: str = "none"
    max_hits: int | None = None  #: hits kept per ray (hits only)
    mask: int | None = None  #: ``?mask=``: one mask for every ray of the batch
    #: DACRT_DEVICE: "cuda" traces closest, occluded, hits and count on the GPU where the CUDA
    #: backend answers them (``tracing.device_for``)
    device: str = "cpu"
    #: ``?fields=`` as asked: its names in their order, each once (None: not given)
    asked: tuple[str, ...] | None = None

    def pick(self, get: Callable[[str], np.ndarray]) -> dict[str, np.ndarray]:
        """The answer's arrays: ``get(key)`` for each of ``fields``, in answer order (``get``
        makes only the keys asked for)."""
        return {name: get(name) for name in self.fields}

    def check_columns(self, answer_format: str) -> None:
        """422 when ``?fields=`` names a PCD column (``x``) for an answer in another format,
        whose arrays are the keys (``xyz``)."""
        columns = [name for name in self.asked or () if name in PCD_COLUMNS]
        if columns and answer_format != "pcd":
            raise Invalid(
                unknown_fields(",".join(self.asked), columns, self.kind.value, keys_of(self.kind))
                + f"; {', '.join(PCD_COLUMNS)} name the columns of a PCD answer only "
                "(Accept: application/x-pcd)"
            )

    def pcd_fields(self, answered: Collection[str]) -> tuple[str, ...] | None:
        """A PCD answer's fields: each name of ``?fields=`` whose key is ``answered``, in the
        order asked, a key's columns for the key (``xyz``: ``x y z``) and each column once
        (``pcd_bytes`` of this list); None (every field) without ``?fields=``."""
        if self.asked is None:
            return None
        fields: dict[str, None] = {}
        for name in self.asked:
            if PCD_COLUMNS.get(name, name) in answered:
                fields.update(dict.fromkeys(VECTOR_FIELDS.get(name, (name,))))
        return tuple(fields)

    def traced_as(self, query: Query, max_hits: int | None = None) -> Options:
        """What a sensor asks of the engine: ``query`` (closest, or hits of at most ``max_hits``)
        for HIT_FIELDS of each ray, with this request's strategy, statistics, threads, culling
        and mask."""
        fields = ("offsets", *HIT_FIELDS) if query is Query.HITS else HIT_FIELDS
        return replace(self, kind=query, fields=fields, max_hits=max_hits)

    def hit_buffer_bytes(self, n_rays: int) -> int:
        """Bytes of the engine's hit buffers for ``n_rays`` rays (0 but for hits)."""
        if self.kind is not Query.HITS:
            return 0
        return n_rays * (self.max_hits + 1) * footprint.HIT_SLOT_BYTES

    @property
    def answer_formats(self) -> tuple[str, ...]:
        """The formats the answer can be written in: npy needs one row per ray in every array
        (a hits answer with ``offsets`` or a per-hit key is CSR: npz and JSON only)."""
        if self.kind is Query.HITS and set(self.fields) & {"offsets", *PER_HIT_FIELDS}:
            return tuple(fmt for fmt in ANSWER_FORMATS if fmt != "npy")
        return ANSWER_FORMATS

    @property
    def why_not_npy(self) -> str | None:
        """Why the answer has no npy form (None when it has one), for a 406."""
        if "npy" in self.answer_formats:
            return None
        return (
            f"a {self.kind.value} answer with {', '.join(self.fields)} is written in: its arrays "
            f"have different lengths (CSR), so use {NPZ} or {JSON}, or ?fields=truncated for an "
            ".npy"
        )


def make_options(
    kind: Query | Sensor | str,
    fields: str | None = None,
    strategy: str | None = None,
    stats: bool = False,
    threads: int | None = None,
    cull: str = "none",
    max_hits: int | None = None,
    mask: int | None = None,
    max_hits_limit: int | None = None,
    device: str = "cpu",
) -> Options:
    """The options of one request, from its query-string values; 422 naming the choices for an
    unknown value (the engine's own checks for strategy and cull). A ``kind`` given as text is a
    query's name (``/trace?query=``).

    ``max_hits`` (hits only; default DEFAULT_MAX_HITS) must lie in [1, ``max_hits_limit``]."""
    kind = kind if isinstance(kind, (Query, Sensor)) else query_named(kind)
    known = keys_of(kind)
    # a lidar answers a PCD file too, whose fields may be a vector key's columns
    columns = PCD_COLUMNS if kind is Sensor.LIDAR else {}
    asked = None if fields is None else listed(fields)
    chosen = pick_fields(fields, asked, known, kind.value, columns)
    if kind is Query.HITS:
        if set(chosen) & set(PER_HIT_FIELDS):
            chosen = ("offsets", *(name for name in chosen if name != "offsets"))
        max_hits = check_max_hits(
            DEFAULT_MAX_HITS if max_hits is None else max_hits, max_hits_limit
        )
    elif max_hits is not None:
        raise Invalid(f"max_hits applies to the hits query only, not to {kind.value}")
    # the engine's own checks, before the body is read: its InputError is 422 (errors.install)
    strategy = strategies()[0] if strategy is None else check_strategy(strategy)
    cull = check_cull(cull)
    return Options(kind, chosen, strategy, stats, threads, cull, max_hits, mask, device, asked)


def keys_of(kind: Query | Sensor) -> tuple[str, ...]:
    """Every key of ``kind``'s answer, in answer order."""
    return FIELDS[kind] if isinstance(kind, Query) else SENSOR_FIELDS[kind]


def query_named(name: str) -> Query:
    """The query called ``name``; 422 naming the queries."""
    try:
        return Query(name)
    except ValueError:
        raise Invalid(
            f"unknown query {name!r}; choose from {', '.join(q.value for q in Query)}"
        ) from None


def pick_fields(
    fields: str | None,
    names: tuple[str, ...] | None,
    known: tuple[str, ...],
    what: str,
    columns: dict[str, str] | None = None,
) -> tuple[str, ...]:
    """``?fields=`` (``names``: its names, ``listed``) as a tuple in ``known``'s order (all of
    them if None), a name of ``columns`` (a PCD column, ``x``) standing for its key (``xyz``);
    422 naming the choices for an unknown or empty list."""
    if fields is None or names is None:
        return known
    columns = columns or {}
    unknown = [name for name in names if name not in known and name not in columns]
    if unknown or not names:
        message = unknown_fields(fields, unknown, what, known)
        if columns:
            message += f" (and, for a PCD answer, {', '.join(columns)})"
        raise Invalid(message)
    keys = {columns.get(name, name) for name in names}
    return tuple(name for name in known if name in keys)


def listed(fields: str) -> tuple[str, ...]:
    """The names of ``?fields=`` in their order, each once, spaces and empty names left out."""
    return tuple(dict.fromkeys(name.strip() for name in fields.split(",") if name.strip()))


def unknown_fields(fields: str, unknown: list[str], what: str, known: tuple[str, ...]) -> str:
    """The 422 message of ``?fields=`` naming ``unknown`` (the first five; none: an empty
    list) for ``what``, and the ``known`` choices."""
    named = "unknown fields " + ", ".join(map(quoted, unknown[:5])) if unknown else "no field"
    if len(unknown) > 5:
        named += f" and {len(unknown) - 5} more"
    return f"?fields={cut(fields, 100)} names {named} for {what}; choose from {', '.join(known)}"


def check_max_hits(max_hits: int, limit: int | None) -> int:
    """422 unless ``max_hits`` is an integer in [1, limit] (limit: DACRT_MAX_HITS)."""
    within = f"1 to {limit} (DACRT_MAX_HITS)" if limit is not None else "at least 1"
    if isinstance(max_hits, bool) or not isinstance(max_hits, int):
        raise Invalid(f"max_hits must be an integer from {within}, got {max_hits!r}")
    if max_hits < 1 or (limit is not None and max_hits > limit):
        raise Invalid(f"max_hits must be an integer from {within}, got {max_hits}")
    return max_hits
