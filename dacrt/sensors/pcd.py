"""Point clouds as binary PCD v0.7 files, as PCL, Open3D and CloudCompare read them.

The header names the fields asked: ``x y z`` are the columns of ``xyz``, ``velocity_x
velocity_y velocity_z`` those of ``velocity`` (PCL's naming, as ``normal_x``), every other field
is the point array of that name; each with its size and type from the array's dtype (float32:
``4 F``, uint16: ``2 U``, uint32: ``4 U``, ...), one count each. An organized answer of shape
(rings, steps[, returns]) is ``HEIGHT rings`` and ``WIDTH steps[ * returns]``, row-major; a list
of points is ``HEIGHT 1``. ``DATA binary``: the points one after another, each field's bytes
little-endian in header order, no padding.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from ..validation import InputError

#: PCD's TYPE letter of a NumPy dtype kind.
TYPE_LETTERS = {"f": "F", "i": "I", "u": "U", "b": "U"}
#: The point arrays of three values a point, and the three fields each is written as.
VECTOR_FIELDS = {"xyz": ("x", "y", "z"), "velocity": ("velocity_x", "velocity_y", "velocity_z")}


def available_fields(points: Mapping[str, np.ndarray]) -> tuple[str, ...]:
    """Every field a PCD file of ``points`` can hold: x y z, then the other arrays' fields (a
    vector array's three, a one-value array's one)."""
    shape = _points_shape(points)
    fields = list(VECTOR_FIELDS["xyz"]) if _is_vector(points, "xyz", shape) else []
    for name, array in points.items():
        if name != "xyz" and _is_vector(points, name, shape):
            fields += VECTOR_FIELDS[name]
        elif array.shape == shape and array.dtype.kind in TYPE_LETTERS:
            fields.append(name)
    return tuple(fields)


def pcd_bytes(points: Mapping[str, np.ndarray], fields: Sequence[str] | None = None) -> bytes:
    """The binary PCD v0.7 file of ``points`` (a lidar's answer, or any mapping of arrays of one
    row per point with ``xyz`` (..., 3)) with ``fields`` (default: ``available_fields``);
    InputError naming a field that ``points`` lack."""
    known = available_fields(points)
    # a vector array's name stands for its three fields
    fields = known if fields is None else tuple(_expanded(fields))
    for name in fields:
        if name not in known:
            raise InputError(
                f"fields: {name!r} is not a field of these points; choose from {', '.join(known)}"
            )
    if not fields:
        raise InputError("fields: name at least one field")
    repeated = [name for k, name in enumerate(fields) if name in fields[:k]]
    if repeated:
        raise InputError(f"fields: {repeated[0]!r} is named more than once")
    columns = {name: _column(points, name) for name in fields}
    shape = _points_shape(points)
    height = shape[0] if len(shape) >= 2 else 1
    n = int(np.prod(shape))
    record = np.dtype([(name, columns[name].dtype.newbyteorder("<")) for name in fields])
    table = np.empty(n, record)
    for name in fields:
        table[name] = columns[name]
    header = "\n".join(
        [
            "# .PCD v0.7 - Point Cloud Data file format",
            "VERSION 0.7",
            "FIELDS " + " ".join(fields),
            "SIZE " + " ".join(str(columns[name].dtype.itemsize) for name in fields),
            "TYPE " + " ".join(TYPE_LETTERS[columns[name].dtype.kind] for name in fields),
            "COUNT " + " ".join("1" for _ in fields),
            f"WIDTH {n // height if height else 0}",
            f"HEIGHT {height}",
            "VIEWPOINT 0 0 0 1 0 0 0",
            f"POINTS {n}",
            "DATA binary",
        ]
    )
    return (header + "\n").encode("ascii") + table.tobytes()


def write_pcd(file, points: Mapping[str, np.ndarray], fields: Sequence[str] | None = None) -> None:
    """Write ``pcd_bytes(points, fields)`` to ``file`` (a path or a binary file)."""
    data = pcd_bytes(points, fields)
    if hasattr(file, "write"):
        file.write(data)
    else:
        with open(file, "wb") as out:
            out.write(data)


def _points_shape(points: Mapping[str, np.ndarray]) -> tuple[int, ...]:
    """The shape of the points: a one-value array's, a vector array's less its last axis."""
    for name, array in points.items():
        return array.shape[:-1] if name in VECTOR_FIELDS else array.shape
    return (0,)


def _is_vector(points: Mapping[str, np.ndarray], name: str, shape: tuple[int, ...]) -> bool:
    """Whether ``points[name]`` is a vector array of three values a point."""
    return (
        name in VECTOR_FIELDS
        and name in points
        and points[name].shape == shape + (3,)
        and points[name].dtype.kind in TYPE_LETTERS
    )


def _expanded(fields: Sequence[str]) -> list[str]:
    """``fields`` with each vector array's name replaced by its three fields."""
    return [field for name in fields for field in VECTOR_FIELDS.get(name, (name,))]


def _column(points: Mapping[str, np.ndarray], name: str) -> np.ndarray:
    for vector, components in VECTOR_FIELDS.items():
        if name in components and vector in points:
            return points[vector][..., components.index(name)].reshape(-1)
    values = points[name].reshape(-1)
    return values.astype(np.uint8) if values.dtype.kind == "b" else values
