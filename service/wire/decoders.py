"""Request decoders: a body in a known format -> checked rays, meshes, vertices or frames."""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np

from ..errors import BadBody, Invalid, TooLarge, UnsupportedMediaType
from .arrays import (
    MeshArrays,
    Rays,
    check_faces,
    check_vertices,
    float_array,
    index_array,
    mask_array,
    mesh_arrays,
)
from .formats import MESH_FILE_FORMATS, Buffer
from .npy import read_npy
from .npz_reader import read_npz


def read_json(buf: Buffer, expected: str) -> dict[str, Any]:
    """A JSON object; anything else is 400 naming the ``expected`` keys."""
    try:
        doc = json.loads(buf if isinstance(buf, (bytes, bytearray)) else bytes(buf))
    except RecursionError:
        raise BadBody("body is not valid JSON: it is nested too deeply") from None
    except ValueError as exc:  # JSONDecodeError, bad UTF-8, integers of over 4300 digits
        raise BadBody(f"body is not valid JSON: {exc}") from None
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


def check_keys(
    mapping: Mapping[str, Any], required: Iterable[str], optional: Iterable[str] = ()
) -> None:
    """400 for missing or unknown keys, listing what is expected."""
    required, optional = tuple(required), tuple(optional)
    expected = ", ".join(required) + (f" (optional: {', '.join(optional)})" if optional else "")
    missing = [k for k in required if k not in mapping]
    unknown = [k for k in mapping if k not in required and k not in optional]
    if missing:
        raise BadBody(f"body lacks {', '.join(map(repr, missing))}; expected keys {expected}")
    if unknown:
        raise BadBody(
            f"body has unknown keys {', '.join(map(repr, unknown))}; expected keys {expected}"
        )


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


#: The optional keys of a ray batch in an npz or JSON body.
RAY_OPTIONAL_KEYS = ("tmin", "tmax", "mask")


def rays_from_mapping(mapping: Mapping[str, Any], max_rays: int | None) -> Rays:
    """Rays from the keys origins, directions, tmin, tmax, mask of an npz or JSON body."""
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
    for key in ("tmin", "tmax"):
        value = mapping.get(key)
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
    return Rays(origins, directions, *bounds, mask)


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


def decode_frame(
    body: Buffer, fmt: str, max_bytes: int | None = None
) -> dict[str, tuple[np.ndarray, np.ndarray | None]]:
    """mesh name -> (vertices, faces or None) from ``MESH.vertices`` / ``MESH.faces`` keys.

    Only shapes and dtypes are checked here; face indices are checked against the vertex count
    of the mesh they end up with (``check_faces``) by the store.
    """
    mapping = read_mapping(body, fmt, "MESH.vertices (and optionally MESH.faces) keys", max_bytes)
    parts: dict[str, dict[str, Any]] = {}
    for key, value in mapping.items():
        mesh, _, kind = key.rpartition(".")
        if not mesh or kind not in ("vertices", "faces"):
            raise BadBody(f"frame key {key!r} is not MESH.vertices or MESH.faces")
        parts.setdefault(mesh, {})[kind] = value
    if not parts:
        raise BadBody("frame body holds no MESH.vertices keys")
    frame = {}
    for mesh, arrays in parts.items():
        if "vertices" not in arrays:
            raise BadBody(f"frame has {mesh}.faces but no {mesh}.vertices")
        vertices = check_vertices(
            float_array(arrays["vertices"], f"{mesh}.vertices", 3), f"{mesh}.vertices"
        )
        faces = arrays.get("faces")
        if faces is not None:
            faces = check_faces(index_array(faces, f"{mesh}.faces"), len(vertices), f"{mesh}.faces")
        frame[mesh] = (vertices, faces)
    return frame


def decode_trace(
    body: Buffer, fmt: str, max_rays: int | None = None, max_bytes: int | None = None
) -> tuple[MeshArrays, Rays]:
    """The mesh and the rays of a one-shot trace body."""
    mapping = read_mapping(body, fmt, "vertices, faces, origins, directions", max_bytes)
    check_keys(mapping, ("vertices", "faces", "origins", "directions"), RAY_OPTIONAL_KEYS)
    rays = rays_from_mapping(mapping, max_rays)
    return mesh_arrays(mapping["vertices"], mapping["faces"]), rays
