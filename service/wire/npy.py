"""The .npy format: a zero-copy reader of whole bodies, and the header and data of an answer."""

from __future__ import annotations

import functools
import io
import math
import tokenize

import numpy as np

from ..errors import BadBody, Invalid
from .formats import Buffer

#: The longest .npy header read (numpy itself refuses headers over 10,000 bytes).
MAX_NPY_HEADER_BYTES = 65536 + 16
#: The most axes a NumPy array has.
MAX_NPY_AXES = 64
#: The most bytes a NumPy array's shape may span, zero-length axes left out.
MAX_NPY_BYTES = np.iinfo(np.intp).max


def read_npy(buf: bytes | memoryview, name: str = "body", structured: bool = False) -> np.ndarray:
    """View a whole .npy held in ``buf`` as an array without copying its data (read-only).

    Requests hold plain numeric arrays; answers (``structured``) may hold a record per ray.
    """
    view = memoryview(buf)
    prefix = bytes(view[:12])
    try:
        # Magic string, version, then the header's length: 2 bytes in version 1.0, 4 after.
        version = np.lib.format.read_magic(io.BytesIO(prefix))
        if version not in ((1, 0), (2, 0), (3, 0)):
            raise ValueError(f"unsupported .npy version {version}")
        size = (
            10 + int.from_bytes(prefix[8:10], "little")
            if version == (1, 0)
            else 12 + int.from_bytes(prefix[8:12], "little")
        )
        if size > MAX_NPY_HEADER_BYTES:
            raise ValueError(
                f"its header claims {size} bytes, over the {MAX_NPY_HEADER_BYTES} read"
            )
        shape, fortran, dtype = _npy_header(bytes(view[:size]))
        if any(length < 0 for length in shape):
            raise ValueError(f"its shape {shape} has a negative length")
    # numpy parses the header as a Python literal: a broken one raises tokenize's error too
    except (
        ValueError,
        SyntaxError,
        TypeError,
        OverflowError,
        RecursionError,
        tokenize.TokenError,
    ) as exc:
        # numpy's literal parser names an expression (2**62) by its Python object
        reason = "its header holds an expression, not literals" if "<ast." in str(exc) else exc
        raise BadBody(f"{name} is not a readable .npy: {reason}") from None
    if dtype.hasobject:
        raise Invalid(
            f"{name} holds Python objects ({dtype}); only numeric arrays are accepted "
            "(they are never unpickled)"
        )
    plain = dtype.fields is None and dtype.subdtype is None and dtype.kind in "biufc"
    if not (plain or structured and dtype.fields and dtype.itemsize):
        raise Invalid(
            f"{name} has dtype {dtype!s}; only plain "
            "numeric arrays (no structured, subarray or void dtypes) are accepted"
        )
    offset = size
    count = math.prod(shape)  # Python integers: a hostile shape cannot overflow
    expected = count * dtype.itemsize
    if len(view) - offset != expected:
        problem = "truncated" if len(view) - offset < expected else "longer than its header says"
        raise BadBody(
            f"{name} is {problem}: its header promises {dtype} {shape} = {expected} "
            f"bytes of data, but {len(view) - offset} follow"
        )
    # a shape of no elements (a zero length) carries no data, yet numpy cannot make every such shape
    if len(shape) > MAX_NPY_AXES:
        raise BadBody(
            f"{name} is not a readable .npy: its shape has {len(shape)} axes, "
            f"over the {MAX_NPY_AXES} numpy holds"
        )
    if math.prod(length for length in shape if length) * dtype.itemsize > MAX_NPY_BYTES:
        raise BadBody(f"{name} is not a readable .npy: its shape {shape} is too big for an array")
    array = np.frombuffer(view, dtype=dtype, count=count, offset=offset)
    return array.reshape(shape, order="F" if fortran else "C")


@functools.lru_cache(maxsize=256)
def _npy_header(header: bytes) -> tuple[tuple[int, ...], bool, np.dtype]:
    """(shape, Fortran order, dtype) of a whole .npy header, magic string included.

    numpy evaluates the header as a Python literal, and batches of one size repeat the same
    header, so each is parsed once."""
    stream = io.BytesIO(header)
    if np.lib.format.read_magic(stream) == (1, 0):
        return np.lib.format.read_array_header_1_0(stream)
    return np.lib.format.read_array_header_2_0(stream)


def npy_header(dtype: np.dtype, shape: tuple[int, ...]) -> bytes:
    """The .npy header (format 1.0, C order) of an array of ``dtype`` and ``shape``."""
    out = io.BytesIO()
    np.lib.format.write_array_header_1_0(
        out, {"descr": np.lib.format.dtype_to_descr(dtype), "fortran_order": False, "shape": shape}
    )
    return out.getvalue()


def array_bytes(array: np.ndarray) -> Buffer:
    """The bytes of an array in C order: a view of its memory when it is C-contiguous."""
    array = np.ascontiguousarray(array)
    return memoryview(array.reshape(-1)).cast("B") if array.size else b""
