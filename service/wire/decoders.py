"""Request decoders: a body in a known format -> checked rays, meshes, vertices or frames."""

from __future__ import annotations

import json
import re
import sys
from collections.abc import Iterable, Mapping
from typing import Any, NamedTuple

import numpy as np

import dacrt
import dacrt.sensors
from dacrt.validation import check_transforms

from ..errors import BadBody, Invalid, TooLarge, UnsupportedMediaType
from .arrays import (
    MeshArrays,
    Rays,
    check_faces,
    check_json_numbers,
    check_vertices,
    float_array,
    index_array,
    mask_array,
    mesh_arrays,
)
from .formats import MESH_FILE_FORMATS, Buffer
from .npy import read_npy
from .npz_reader import read_npz


def cut(text: str, most: int) -> str:
    """``text`` for a message: its first ``most`` characters and its length when longer."""
    return text if len(text) <= most else f"{text[:most]}... ({len(text)} characters)"


def quoted(text: str, most: int = 80) -> str:
    """``text`` (a key, a name from a request) quoted for a message, cut to its first ``most``
    characters."""
    return repr(text) if len(text) <= most else f"{text[:most]!r}... ({len(text)} characters)"


class _RepeatedKey(ValueError):
    """A JSON object that names a key twice (``json`` keeps the last silently)."""


def _unique_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    """An object's pairs as a dict; _RepeatedKey naming the first key given twice."""
    mapping = dict(pairs)
    if len(mapping) < len(pairs):
        seen: set[str] = set()
        repeated = next(key for key, _ in pairs if key in seen or seen.add(key))
        raise _RepeatedKey(repeated)
    return mapping


def parse_json(text: bytes, what: str, unique_keys: bool = True) -> Any:
    """``json.loads`` of ``text``, or 400 saying what is wrong with ``what`` (the body, a GLB's
    JSON chunk) in its own terms. With ``unique_keys`` a key given twice in one object is
    refused, not resolved to its last value (a file from elsewhere is read as its readers
    read it: the last). An integer of more digits than Python converts is 422 naming where it
    is (valid JSON, but beyond every number a request or file may hold)."""
    hook = _unique_keys if unique_keys else None
    try:
        try:
            return json.loads(text, object_pairs_hook=hook)
        except ValueError as exc:
            if "integer string conversion" not in str(exc):  # Python's guard on slow int parsing
                raise
        doc = json.loads(text, object_pairs_hook=hook, parse_int=_integer_or_long)
    except _RepeatedKey as exc:
        raise BadBody(
            f"{what} gives the key {quoted(str(exc.args[0]))} twice in one object"
        ) from None
    except RecursionError:
        raise BadBody(f"{what} is not valid JSON: it is nested too deeply") from None
    except ValueError as exc:  # JSONDecodeError, bad UTF-8
        raise BadBody(f"{what} is not valid JSON: {exc}") from None
    where, digits = _first_long_integer(doc)
    place = f"{what}'s {where}" if where else what
    raise Invalid(f"{place} is an integer of {digits} digits, out of every range (beyond float64)")


class _LongInteger:
    """A JSON integer of more digits than ``sys.get_int_max_str_digits()``, in place of its
    value (Python refuses to convert it)."""

    def __init__(self, digits: int) -> None:
        self.digits = digits


def _integer_or_long(text: str) -> int | _LongInteger:
    digits = len(text.lstrip("-"))
    limit = sys.get_int_max_str_digits()
    return _LongInteger(digits) if limit and digits > limit else int(text)


def _first_long_integer(doc: Any) -> tuple[str, int]:
    """(where, its digits) of the first _LongInteger in ``doc``: ``width``, ``pose[1][2]``,
    ``sensors.front.width`` ('' for the document itself)."""
    pending = [("", doc)]
    while pending:
        where, value = pending.pop()
        if isinstance(value, _LongInteger):
            return where, value.digits
        if isinstance(value, dict):
            items = [(f"{where}.{key}" if where else str(key), v) for key, v in value.items()]
        elif isinstance(value, list):
            items = [(f"{where}[{i}]", v) for i, v in enumerate(value)]
        else:
            continue
        pending.extend(reversed(items))
    return "", 0  # not reached: the first parse met an integer too long to convert


def read_json(buf: Buffer, expected: str) -> dict[str, Any]:
    """A JSON object; anything else is 400 naming the ``expected`` keys."""
    doc = parse_json(buf if isinstance(buf, (bytes, bytearray)) else bytes(buf), "body")
    if not isinstance(doc, dict):
        raise BadBody(f"JSON body must be an object with {expected}, got {type(doc).__name__}")
    return doc


def read_mapping(
    body: Buffer, fmt: str, expected: str, max_bytes: int | None = None
) -> dict[str, Any]:
    """The key -> value mapping of an npz or JSON body."""
    if fmt == "npz":
        return read_npz(body, max_bytes)
    if fmt == "json":
        return read_json(body, expected)
    raise UnsupportedMediaType(f"{fmt} bodies hold no keys; send {expected} as .npz or JSON")


#: The unknown keys a message names; the others are counted.
SHOWN_KEYS = 5


def check_keys(
    mapping: Mapping[str, Any], required: Iterable[str], optional: Iterable[str] = ()
) -> None:
    """400 for missing or unknown keys, listing what is expected."""
    required, optional = tuple(required), tuple(optional)
    if required:
        expected = ", ".join(required) + (f" (optional: {', '.join(optional)})" if optional else "")
    else:
        expected = f"{', '.join(optional)} (each optional)"
    missing = [k for k in required if k not in mapping]
    unknown = [k for k in mapping if k not in required and k not in optional]
    if missing:
        raise BadBody(f"body lacks {', '.join(map(repr, missing))}; expected keys {expected}")
    if unknown:
        # a few named, the others counted: a body may hold any number of keys of any length
        named = ", ".join(quoted(key) for key in unknown[:SHOWN_KEYS])
        more = f" and {len(unknown) - SHOWN_KEYS:,} more" if len(unknown) > SHOWN_KEYS else ""
        raise BadBody(f"body has unknown keys {named}{more}; expected keys {expected}")


def decode_rays(
    body: Buffer, fmt: str, max_rays: int | None = None, max_bytes: int | None = None
) -> Rays:
    """A ray batch from an npy, npz or JSON body (see the module docstring)."""
    if fmt == "npy":
        array = read_npy(body, "rays body")
        if array.ndim != 2 or array.shape[1] not in (6, 8):
            raise Invalid(f"a .npy ray body must have shape (N, 6) or (N, 8), got {array.shape}")
        _check_ray_count(len(array), max_rays)
        array = float_array(array, "rays", array.shape[1])
        has_t = array.shape[1] == 8
        return Rays(
            array[:, 0:3],
            array[:, 3:6],
            array[:, 6] if has_t else None,
            array[:, 7] if has_t else None,
        )
    mapping = read_mapping(body, fmt, "origins, directions", max_bytes)
    check_keys(mapping, ("origins", "directions"), RAY_OPTIONAL_KEYS)
    return rays_from_mapping(mapping, max_rays)


def decode_points(
    body: Buffer, fmt: str, max_points: int | None = None, max_bytes: int | None = None
) -> np.ndarray:
    """Query points, float32 (N, 3), from an npy, npz or JSON body (see the module docstring).
    Their values (finite) are checked by the engine, which names the first bad point."""
    if fmt == "npy":
        points = read_npy(body, "points body")
    else:
        mapping = read_mapping(body, fmt, "points", max_bytes)
        check_keys(mapping, ("points",))
        points = mapping["points"]
    n = (
        points.shape[0]
        if isinstance(points, np.ndarray) and points.ndim
        else (len(points) if isinstance(points, list) else 0)
    )
    if max_points is not None and n > max_points:
        raise TooLarge(
            f"{n} points in one request, over the limit of {max_points} "
            "(DACRT_MAX_RAYS_PER_REQUEST); split the batch"
        )
    return float_array(points, "points", 3)


#: The optional keys of a ray batch in an npz or JSON body.
RAY_OPTIONAL_KEYS = ("tmin", "tmax", "mask", "time")


def rays_from_mapping(mapping: Mapping[str, Any], max_rays: int | None) -> Rays:
    """Rays from the keys origins, directions, tmin, tmax, mask, time of an npz or JSON body
    (time's values, finite and in [0, 1], are checked by the engine)."""
    origins = mapping["origins"]
    n = (
        origins.shape[0]
        if isinstance(origins, np.ndarray) and origins.ndim
        else (len(origins) if isinstance(origins, list) else 0)
    )
    _check_ray_count(n, max_rays)
    origins = float_array(origins, "origins", 3)
    directions = float_array(mapping["directions"], "directions", 3)
    if len(directions) != len(origins):
        raise Invalid(f"origins has {len(origins)} rays but directions has {len(directions)}")
    bounds = []
    for key in ("tmin", "tmax", "time"):
        value = mapping.get(key)
        if key == "time" and value is not None and not isinstance(value, np.ndarray):
            check_json_times(value)
        if value is not None:
            value = float_array(value, key, None)
            if value.ndim == 0:
                value = float(value)
            elif len(value) != len(origins):
                raise Invalid(f"{key} has {len(value)} values but there are {len(origins)} rays")
        bounds.append(value)
    mask = mapping.get("mask")
    if mask is not None:
        mask = mask_array(mask, "mask", len(origins))
    tmin, tmax, time = bounds
    return Rays(origins, directions, tmin, tmax, mask, time)


def check_json_times(value: Any) -> None:
    """422 naming ``time[i]`` for a JSON time that is null or outside [0, 1] as written: the
    engine checks the float32 it is given, into which 1.000000001 rounds as 1."""
    times = value if isinstance(value, list) else [value]
    for i, time in enumerate(times):
        if time is None:
            raise Invalid(f"time[{i}] is null: each time must be a number in [0, 1]")
        if type(time) in (int, float) and not 0 <= time <= 1:  # NaN fails too
            raise Invalid(f"time[{i}] is {time!r}: each time must be finite and in [0, 1]")


def _check_ray_count(n: int, max_rays: int | None) -> None:
    if max_rays is not None and n > max_rays:
        raise TooLarge(
            f"{n} rays in one request, over the limit of {max_rays} "
            "(DACRT_MAX_RAYS_PER_REQUEST); split the batch"
        )


def decode_mesh(body: Buffer, fmt: str, max_bytes: int | None = None) -> MeshArrays:
    """A checked mesh from an npz, JSON or mesh-file body."""
    if fmt in MESH_FILE_FORMATS:
        from .meshfile import read_mesh_file  # imports trimesh, which is slow to import

        vertices, faces = read_mesh_file(body, fmt)
        vertices = check_vertices(vertices)
        return MeshArrays(vertices, check_faces(faces, len(vertices)))
    mapping = read_mapping(body, fmt, "vertices, faces", max_bytes)
    check_keys(mapping, ("vertices", "faces"))
    return mesh_arrays(mapping["vertices"], mapping["faces"])


def decode_vertices(body: Buffer, fmt: str, max_bytes: int | None = None) -> np.ndarray:
    """Checked (V, 3) float32 vertex positions from an npy, npz or JSON body."""
    if fmt == "npy":
        value = read_npy(body, "vertices body")
    else:
        mapping = read_mapping(body, fmt, "vertices", max_bytes)
        check_keys(mapping, ("vertices",))
        value = mapping["vertices"]
    return check_vertices(float_array(value, "vertices", 3))


class FrameChange(NamedTuple):
    """What a frame changes of one mesh; None leaves a part as it is."""

    vertices: np.ndarray | None = None  #: (V, 3) float32, checked finite
    faces: np.ndarray | None = None  #: (F, 3) int32, checked against ``vertices``
    transform: np.ndarray | None = None  #: (4, 4) float64, checked by ``check_matrix``
    mask: int | None = None  #: uint32
    instance_of: str | None = None  #: the mesh whose arrays this one shares
    reflectivity: float | None = None  #: in [0, 1]
    label: int | None = None  #: uint32
    transform_end: np.ndarray | None = None  #: (4, 4) float64: the placement at the interval's end
    vertices_end: np.ndarray | None = None  #: (V, 3) float32: the vertices at the interval's end


#: The parts of a mesh a frame can set, as the suffixes of its keys.
FRAME_PARTS = FrameChange._fields


def decode_frame(
    body: Buffer, fmt: str, max_bytes: int | None = None, max_meshes: int | None = None
) -> dict[str, FrameChange]:
    """mesh name -> FrameChange from ``MESH.vertices``, ``MESH.faces``, ``MESH.transform``,
    ``MESH.mask`` and ``MESH.instance_of`` keys (``instance_of`` only in JSON: it is text); 413
    for a frame naming more than ``max_meshes`` meshes, before any change is made.

    Values are checked here; face indices against the frame's vertices (``check_faces``), and
    which meshes exist by the store.
    """
    mapping = read_mapping(body, fmt, "MESH.vertices (and optionally MESH.faces) keys", max_bytes)
    # a mesh has at most one key a part: refused before a mesh's parts are gathered
    if max_meshes is not None and len(mapping) > max_meshes * len(FRAME_PARTS):
        _too_many_meshes(f"at least {-(-len(mapping) // len(FRAME_PARTS))}", max_meshes)
    parts: dict[str, dict[str, Any]] = {}
    for key, value in mapping.items():
        mesh, _, kind = key.rpartition(".")
        if not mesh or kind not in FRAME_PARTS:
            raise BadBody(
                f"frame key {key!r} is not MESH.vertices or MESH.faces, nor MESH.transform, "
                "MESH.transform_end, MESH.vertices_end, MESH.mask, MESH.instance_of, "
                "MESH.reflectivity or MESH.label"
            )
        parts.setdefault(mesh, {})[kind] = value
    if not parts:
        raise BadBody("frame body holds no MESH.vertices (or other MESH.*) keys")
    if max_meshes is not None and len(parts) > max_meshes:
        _too_many_meshes(str(len(parts)), max_meshes)
    changes = {mesh: _frame_change(mesh, arrays) for mesh, arrays in parts.items()}
    return _checked_placements(changes)


def _checked_placements(changes: dict[str, FrameChange]) -> dict[str, FrameChange]:
    """``changes`` with every transform and transform_end checked by the engine at once (a frame
    places many meshes): its InputError names the first bad one's key (422)."""
    given = [
        (mesh, part)
        for mesh, change in changes.items()
        for part in ("transform", "transform_end")
        if getattr(change, part) is not None
    ]
    matrices = [getattr(changes[mesh], part) for mesh, part in given]
    checked = check_transforms(matrices, lambda k: f"{given[k][0]}.{given[k][1]}")
    for (mesh, part), matrix in zip(given, checked):
        changes[mesh] = changes[mesh]._replace(**{part: matrix})
    return changes


def _too_many_meshes(count: str, max_meshes: int) -> None:
    raise TooLarge(
        f"frame names {count} meshes, over the limit of {max_meshes} meshes in a scene "
        "(DACRT_MAX_MESHES_PER_SCENE)"
    )


def _frame_change(mesh: str, arrays: dict[str, Any]) -> FrameChange:
    if "faces" in arrays and "vertices" not in arrays:
        raise BadBody(f"frame has {mesh}.faces but no {mesh}.vertices")
    if "instance_of" in arrays and ("vertices" in arrays or "faces" in arrays):
        raise BadBody(
            f"frame has {mesh}.instance_of and {mesh}.vertices: an instance shares its "
            "source's arrays, so send one or the other"
        )
    vertices = faces = transform = transform_end = mask = source = None
    if "vertices" in arrays:
        vertices = check_vertices(
            float_array(arrays["vertices"], f"{mesh}.vertices", 3), f"{mesh}.vertices"
        )
    if "faces" in arrays:
        faces = index_array(arrays["faces"], f"{mesh}.faces")
        faces = check_faces(faces, len(vertices), f"{mesh}.faces")
    if "transform" in arrays:  # checked by the engine with the frame's others
        transform = matrix_value(arrays["transform"], f"{mesh}.transform")
    if "transform_end" in arrays:
        transform_end = matrix_value(arrays["transform_end"], f"{mesh}.transform_end")
    vertices_end = None
    if "vertices_end" in arrays:
        name = f"{mesh}.vertices_end"
        vertices_end = check_vertices(float_array(arrays["vertices_end"], name, 3), name)
        if vertices is not None and len(vertices_end) != len(vertices):
            raise Invalid(
                f"{name} has {len(vertices_end)} rows but {mesh}.vertices has {len(vertices)}"
            )
    if "mask" in arrays:
        mask = parse_mask(arrays["mask"], f"{mesh}.mask")
    if "instance_of" in arrays:
        source = arrays["instance_of"]
        if not isinstance(source, str):
            raise Invalid(
                f"{mesh}.instance_of must be a mesh name (a JSON string); an .npz frame cannot "
                "hold one: send it in a JSON frame or PUT the instance"
            )
    reflectivity = label = None
    if "reflectivity" in arrays:
        reflectivity = parse_reflectivity(arrays["reflectivity"], f"{mesh}.reflectivity")
    if "label" in arrays:
        label = parse_label(arrays["label"], f"{mesh}.label")
    return FrameChange(
        vertices, faces, transform, mask, source, reflectivity, label, transform_end, vertices_end
    )


#: What ``_one_value``'s dtype kinds are, for its messages: a noun and a dtype of the kind.
_KINDS = {"iu": ("an integer", "uint32"), "fiu": ("a number", "float32")}


def _one_value(value: Any, name: str, kinds: str, fix: str = "") -> Any:
    """A JSON scalar, or the one element of an npz array of a dtype kind in ``kinds``; 422
    saying which is wrong, the array's dtype or its size (then ``fix``, where given)."""
    if not isinstance(value, np.ndarray):
        return value
    if value.dtype.kind not in kinds:
        noun, example = _KINDS[kinds]
        problem = f"must be {noun} (an array of dtype {example}, say), got {value.dtype}"
    elif value.size != 1:
        problem = f"must be one value, got {value.size} values of shape {value.shape}"
    else:
        return value.ravel()[0].item()
    raise Invalid(f"{name} {problem}" + (f"; {fix}" if fix else ""))


def _shown(value: Any, most: int = 60) -> str:
    """``value`` for a message: a huge integer by its size, other text cut to ``most``."""
    if isinstance(value, int) and not isinstance(value, bool) and abs(value) >= 10**30:
        return f"an integer of {value.bit_length()} bits"
    return cut(repr(value), most)


def parse_reflectivity(value: Any, name: str) -> float:
    """A mesh's reflectivity: a number in [0, 1] (JSON number or one-element npz array)."""
    value = _one_value(value, name, "fiu")
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 <= value <= 1:
        raise Invalid(f"{name} must be a number in [0, 1], got {_shown(value)}")
    return float(value)


def parse_label(value: Any, name: str) -> int:
    """A mesh's label: an integer in [0, 2**32) (JSON integer or one-element npz array)."""
    value = _one_value(value, name, "iu")
    if type(value) is not int or not 0 <= value <= MAX_MASK:
        raise Invalid(f"{name} must be an integer from 0 to {MAX_MASK}, got {_shown(value)}")
    return value


#: What a mask may be written as, in a query string or a JSON string.
_MASK_TEXT = re.compile(r"(?:-?[0-9]{1,20}|0[xX][0-9a-fA-F]{1,16})")
MAX_MASK = 0xFFFFFFFF


def parse_mask(value: Any, name: str) -> int:
    """A uint32 visibility mask from decimal or ``0x`` hex text, a JSON integer or an integer
    array of one element; 422 naming the value otherwise."""
    fix = "a mask is a uint32, in decimal (255) or hex (0xff), from 0 to 0xFFFFFFFF"
    value = _one_value(value, name, "iu", fix)
    if isinstance(value, str):
        text = value.strip()
        if not _MASK_TEXT.fullmatch(text):
            raise Invalid(f"{name}={value[:40]!r} is not a mask; {fix}")
        value = int(text, 16 if text[:2].lower() == "0x" else 10)
    elif type(value) is not int:  # JSON: bool, float, null, list or object
        raise Invalid(f"{name} must be an integer or a string, not {type(value).__name__}; {fix}")
    if not 0 <= value <= MAX_MASK:
        raise Invalid(f"{name}={value} is {'negative' if value < 0 else 'over 0xFFFFFFFF'}; {fix}")
    return value


def float32_if_shortest(value: float) -> float:
    """``value``, or the float32 it stands for where it is that float32's shortest decimal read
    as float64, as JSON answers write float32 values: a reported distance given back is then
    that distance (the float64 of ``0.054568082`` lies below the float32 written so). Any
    other number is its float64 value."""
    with np.errstate(over="ignore"):
        single = np.float32(value)
    if np.isfinite(single) and float(str(single)) == value:
        return float(single)
    return value


def check_matrix(value: Any, name: str) -> np.ndarray:
    """A (4, 4) float64 row-major affine matrix from nested JSON lists or a float array, checked
    by the engine (shape, finite, last row [0, 0, 0, 1], invertible): its InputError names
    ``name`` (422 through ``errors``' table)."""
    return dacrt.check_transform(matrix_value(value, name), name)


def matrix_value(value: Any, name: str) -> np.ndarray:
    """A matrix from nested JSON lists or a float array, as an array for the engine to check
    (``check_matrix``): 422 naming ``name`` for what is no array of numbers."""
    if isinstance(value, np.ndarray):
        if value.dtype.kind not in "fiu":
            raise Invalid(f"{name} must be a float array, got {value.dtype}")
    else:
        if not isinstance(value, list):
            raise Invalid(
                f"{name} must be a 4x4 matrix (4 rows of 4 numbers), not {type(value).__name__}"
            )
        check_json_numbers(value, name, (int, float))
        try:
            value = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError, OverflowError):
            raise Invalid(f"{name} must be a 4x4 matrix (4 rows of 4 numbers)") from None
    return value


def decode_trace(
    body: Buffer, fmt: str, max_rays: int | None = None, max_bytes: int | None = None
) -> tuple[MeshArrays, Rays]:
    """The mesh and the rays of a one-shot trace body."""
    mapping = read_mapping(body, fmt, "vertices, faces, origins, directions", max_bytes)
    check_keys(mapping, ("vertices", "faces", "origins", "directions"), RAY_OPTIONAL_KEYS)
    rays = rays_from_mapping(mapping, max_rays)
    return mesh_arrays(mapping["vertices"], mapping["faces"]), rays


#: The keys of a scan pattern's body (``dacrt.sensors.Pattern``): required, then optional.
PATTERN_KEYS = ("azimuth_deg", "elevation_deg")
PATTERN_OPTIONAL_KEYS = ("time_s", "channel")


def decode_pattern(
    body: Buffer, fmt: str, max_rays: int, max_bytes: int | None = None
) -> dacrt.sensors.Pattern:
    """A scan pattern from an npz (or JSON) body of ``azimuth_deg``, ``elevation_deg`` and
    optional ``time_s``, ``channel`` (M,) each; more than ``max_rays`` rays is 413, bad values are
    the engine's InputError naming the key (422)."""
    mapping = read_mapping(body, fmt, "azimuth_deg, elevation_deg", max_bytes)
    check_keys(mapping, PATTERN_KEYS, PATTERN_OPTIONAL_KEYS)
    arrays = {key: _pattern_array(value, key) for key, value in mapping.items()}
    n_rays = arrays["azimuth_deg"].size
    if n_rays > max_rays:
        raise TooLarge(
            f"the pattern has {n_rays} rays, over the limit of {max_rays} (DACRT_MAX_PATTERN_RAYS)"
        )
    return dacrt.sensors.Pattern(**arrays)


def _pattern_array(value: Any, key: str) -> np.ndarray:
    """An npz array as it is, or a JSON list of numbers (integers for ``channel``) as an array."""
    if isinstance(value, np.ndarray):
        return value
    integers = key == "channel"
    if not isinstance(value, list) or any(isinstance(item, list) for item in value):
        raise Invalid(f"{key} must be a list of {'integers' if integers else 'numbers'}")
    check_json_numbers(value, key, (int,) if integers else (int, float))
    try:
        return np.asarray(value, np.int64 if integers else np.float64)
    except OverflowError:
        raise Invalid(f"{key} holds a number beyond the range of its dtype") from None
