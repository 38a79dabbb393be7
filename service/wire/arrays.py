"""Array rules: dtypes and shapes of request arrays, with messages that say how to fix them."""

from __future__ import annotations

import itertools
import json
from dataclasses import dataclass
from typing import Any

import numpy as np

from dacrt.validation import explain_bad_faces, explain_bad_vertices

from ..errors import Invalid

_F32, _I32, _U32 = np.dtype("<f4"), np.dtype("<i4"), np.dtype("<u4")


@dataclass(frozen=True)
class Rays:
    """A ray batch as the engine takes it; arrays may be read-only strided views of the body."""

    origins: np.ndarray  #: (N, 3) float32
    directions: np.ndarray  #: (N, 3) float32
    tmin: np.ndarray | float | None  #: (N,) float32, one value, or None (0)
    tmax: np.ndarray | float | None  #: (N,) float32, one value, or None (+inf)
    mask: np.ndarray | int | None = None  #: (N,) uint32, one value, or None (all ones)
    time: np.ndarray | float | None = None  #: (N,) float32 in [0, 1], one value, or None (0)

    def __len__(self) -> int:
        return len(self.origins)


@dataclass(frozen=True)
class MeshArrays:
    """A checked triangle mesh: finite vertices, every face index in [0, V)."""

    vertices: np.ndarray  #: (V, 3) float32
    faces: np.ndarray  #: (F, 3) int32


def float_array(value: Any, name: str, columns: int | None) -> np.ndarray:
    """A float32 array of shape (N, columns), or (N,)/() when ``columns`` is None."""
    if isinstance(value, np.ndarray):
        if value.dtype != _F32:
            raise Invalid(
                f"{name} must be little-endian float32, got {value.dtype.str} "
                f"({value.dtype}); convert with .astype('<f4')"
            )
        array = value
    else:
        check_json_numbers(
            value, name, (int, float, type(None)) if columns is None else (int, float)
        )
        try:
            array = np.asarray(nulls_as(value), dtype=np.float32)
        except (TypeError, ValueError, OverflowError) as exc:
            raise Invalid(f"{name} must be numbers in nested lists: {exc}") from None
    if columns is not None:
        if array.size == 0 and array.ndim == 1:
            array = array.reshape(0, columns)
        if array.ndim != 2 or array.shape[1] != columns:
            raise Invalid(f"{name} must have shape (N, {columns}), got {array.shape}")
    elif array.ndim > 1:
        raise Invalid(f"{name} must be one value or shape (N,), got {array.shape}")
    return array


def check_json_numbers(value: Any, name: str, kinds: tuple[type, ...]) -> None:
    """422 unless ``value`` is one of ``kinds``, or a list of them, or a list of such lists.

    JSON strings and booleans are not numbers, whatever NumPy would make of them.
    """
    items = value if isinstance(value, list) else [value]
    if items and all(type(item) is list for item in items):
        items = list(itertools.chain.from_iterable(items))
    if set(map(type, items)) <= set(kinds):  # exact types: bool is an int subclass
        return
    bad = next(item for item in items if type(item) not in kinds)
    wanted = "integers" if kinds == (int,) else "numbers"
    raise Invalid(f"{name} must be {wanted}, found {_json_kind(bad)}")


def _json_kind(value: Any) -> str:
    """How a JSON value is named in a message (never its whole text: it may be huge or deep)."""
    if isinstance(value, bool):
        return json.dumps(value)
    if isinstance(value, str):
        return f"the string {value[:32]!r}"
    if isinstance(value, (list, dict)):
        return "a list nested too deeply" if isinstance(value, list) else "an object"
    return "null" if value is None else f"the number {value!r:.32}"


def mask_array(value: Any, name: str, n_rays: int) -> np.ndarray | int:
    """Ray visibility masks: one value for the batch (an int) or a writable (N,) uint32 array.

    Binary: little-endian uint32 of shape (N,) or (). JSON: an integer or a list of integers,
    each in [0, 2**32) (decimal: JSON has no hex)."""
    if isinstance(value, np.ndarray):
        if value.dtype != _U32:
            raise Invalid(
                f"{name} must be little-endian uint32, got {value.dtype.str} ({value.dtype}); "
                "convert with .astype('<u4')"
            )
        array = value
    else:
        check_json_numbers(value, name, (int,))
        values = value if isinstance(value, list) else [value]
        if any(type(item) is list for item in values):
            raise Invalid(f"{name} must be one integer or a list of integers, not nested lists")
        bad = [i for i, item in enumerate(values) if not 0 <= item <= 0xFFFFFFFF]
        if bad:
            where = f"{name}[{bad[0]}]" if isinstance(value, list) else name
            raise Invalid(
                f"{where} is {values[bad[0]]}, outside the uint32 range [0, 2**32) "
                f"({len(bad)} out of range)"
            )
        array = np.asarray(value, dtype=_U32)
    if array.ndim == 0:
        return int(array)
    if array.ndim != 1:
        raise Invalid(f"{name} must be one value or shape (N,), got {array.shape}")
    if len(array) != n_rays:
        raise Invalid(f"{name} has {len(array)} values but there are {n_rays} rays")
    return np.array(array, dtype=_U32)  # a writable copy: 4 bytes a ray


def nulls_as(value: Any, fill: float = np.inf) -> Any:
    """A JSON list with null elements (+inf, or the NaN of a lidar's fill) made ``fill``;
    anything else unchanged."""
    if isinstance(value, list) and any(x is None for x in value):
        return [fill if x is None else x for x in value]
    return value


def index_array(value: Any, name: str) -> np.ndarray:
    """An (F, 3) integer array: int32/uint32 when binary, any integers when from JSON."""
    if isinstance(value, np.ndarray):
        if value.dtype not in (_I32, _U32):
            raise Invalid(
                f"{name} must be little-endian int32 or uint32, got {value.dtype.str} "
                f"({value.dtype}); convert with .astype('<i4')"
            )
        array = value
    else:
        check_json_numbers(value, name, (int,))
        try:
            array = np.asarray(value)
        except (TypeError, ValueError) as exc:
            raise Invalid(f"{name} must be integers in nested lists: {exc}") from None
        if array.size == 0:
            array = (
                array.astype(np.int32).reshape(0, 3) if array.ndim == 1 else array.astype(np.int32)
            )
        elif array.dtype.kind not in "iu":  # integers all (checked above), one beyond int64
            raise Invalid(f"{name} holds an integer beyond int64: no vertex has such an index")
    if array.ndim != 2 or array.shape[1] != 3:
        raise Invalid(f"{name} must have shape (F, 3), got {array.shape}")
    return array


def check_vertices(vertices: np.ndarray, name: str = "vertices") -> np.ndarray:
    """The engine's InputError naming ``name``'s first non-finite row and how many (422 through
    ``errors``' table) unless every vertex is finite."""
    if not np.isfinite(vertices).all():  # one flat pass; rows only to name a bad one
        explain_bad_vertices(vertices, name)
    return vertices


def check_faces(faces: np.ndarray, n_vertices: int, name: str = "faces") -> np.ndarray:
    """The engine's InputError naming ``name``'s first bad row (422 through ``errors``' table)
    unless every index is in [0, n_vertices); the answer is int32 (a view when possible)."""
    if faces.size and (faces.min() < 0 or faces.max() >= n_vertices):
        explain_bad_faces(faces, n_vertices, name)
    if faces.dtype == _I32:
        return faces
    if faces.dtype == _U32:
        return faces.view(_I32)  # every index is below n_vertices < 2**31: same bits
    return faces.astype(np.int32)


def mesh_arrays(vertices: Any, faces: Any, prefix: str = "") -> MeshArrays:
    """Check a (vertices, faces) pair from any body kind."""
    v = check_vertices(float_array(vertices, f"{prefix}vertices", 3), f"{prefix}vertices")
    f = check_faces(index_array(faces, f"{prefix}faces"), len(v), f"{prefix}faces")
    return MeshArrays(v, f)
