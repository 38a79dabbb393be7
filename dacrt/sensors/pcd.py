"""Point clouds as binary PCD v0.7 files, as PCL, Open3D and CloudCompare read them.

The header names the fields asked (``x y z`` are the columns of ``xyz``; every other field is
the point array of that name), each with its size and type from the array's dtype (float32:
``4 F``, int16: ``2 I``, uint32: ``4 U``, ...), one count each. An organized answer of shape
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


def available_fields(points: Mapping[str, np.ndarray]) -> tuple[str, ...]:
    """Every field a PCD file of ``points`` can hold: x y z, then the other one-value arrays."""
    others = tuple(name for name in points if name != "xyz" and _is_scalar(points, name))
    return ("x", "y", "z") + others if "xyz" in points else others


def pcd_bytes(points: Mapping[str, np.ndarray], fields: Sequence[str] | None = None) -> bytes:
    """The binary PCD v0.7 file of ``points`` (a lidar's answer, or any mapping of arrays of one
    row per point with ``xyz`` (..., 3)) with ``fields`` (default: ``available_fields``);
    InputError naming a field that ``points`` lack."""
    known = available_fields(points)
    fields = known if fields is None else tuple(fields)
    for name in fields:
        if name not in known:
            raise InputError(
                f"fields: {name!r} is not a field of these points; choose from {', '.join(known)}"
            )
    if not fields:
        raise InputError("fields: name at least one field")
    columns = {name: _column(points, name) for name in fields}
    shape = points["xyz"].shape[:-1] if "xyz" in points else next(iter(points.values())).shape
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


def _is_scalar(points: Mapping[str, np.ndarray], name: str) -> bool:
    """Whether ``points[name]`` holds one value a point (its shape is the points' shape)."""
    shape = points["xyz"].shape[:-1] if "xyz" in points else points[name].shape
    return points[name].shape == shape and points[name].dtype.kind in TYPE_LETTERS


def _column(points: Mapping[str, np.ndarray], name: str) -> np.ndarray:
    if name in ("x", "y", "z") and "xyz" in points:
        return points["xyz"][..., "xyz".index(name)].reshape(-1)
    values = points[name].reshape(-1)
    return values.astype(np.uint8) if values.dtype.kind == "b" else values
