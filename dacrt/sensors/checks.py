"""Checks of a sensor's options: each bad value raises ``dacrt.InputError`` naming its key as the
HTTP body names it (``noise.range_sigma must be >= 0, got -1``), so the service answers 422 with
the same words."""

from __future__ import annotations

import math
import numbers

import numpy as np

from ..validation import InputError

#: The largest float32: sensors' rays and points are float32.
FLOAT32_MAX = float(np.finfo(np.float32).max)


def number(
    value,
    key: str,
    *,
    at_least: float | None = None,
    above: float | None = None,
    at_most: float | None = None,
    below: float | None = None,
    infinite: bool = False,
) -> float:
    """``value`` as a float within the bounds given; finite unless ``infinite`` (then +inf too)."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise InputError(f"{key} must be a number, got {value!r}")
    try:
        value = float(value)
    except OverflowError:  # an int beyond float64, whose digits may be too many to show
        raise InputError(f"{key} must be a finite number, got an integer beyond 1.8e308") from None
    if math.isnan(value) or (math.isinf(value) and not (infinite and value > 0)):
        raise InputError(f"{key} must be a finite number, got {value!r}")
    for bound, holds, words in (
        (at_least, lambda b: value >= b, ">="),
        (above, lambda b: value > b, ">"),
        (at_most, lambda b: value <= b, "<="),
        (below, lambda b: value < b, "<"),
    ):
        if bound is not None and not holds(bound):
            raise InputError(f"{key} must be {words} {bound:g}, got {value!r}")
    return value


def integer(value, key: str, *, at_least: int, at_most: int | None = None) -> int:
    """``value`` as an int in ``[at_least, at_most]``; booleans and floats are refused."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise InputError(f"{key} must be an integer, got {value!r}")
    value = int(value)
    if value < at_least or (at_most is not None and value > at_most):
        upper = "" if at_most is None else f" and <= {at_most}"
        shown = value if abs(value) < 10**30 else f"an integer of {value.bit_length()} bits"
        raise InputError(f"{key} must be >= {at_least}{upper}, got {shown}")
    return value


def float_array(value, key: str, shape: tuple, error: type = InputError) -> np.ndarray:
    """``value`` as a finite float64 array of ``shape``; ``error`` names ``key`` when it is not
    numbers (text, complex, booleans), has another shape or a NaN or infinite entry."""
    try:
        array = np.asarray(value)
    except (ValueError, TypeError):  # ragged nesting
        raise error(f"{key} must be numbers of shape {shape}, got {value!r:.80}") from None
    if array.dtype.kind not in "fiu":
        raise error(f"{key} must be numbers of shape {shape}, got {array.dtype} values")
    if array.shape != shape:
        raise error(f"{key} must have shape {shape}, got shape {array.shape}")
    array = array.astype(np.float64)
    if not np.isfinite(array).all():
        raise error(f"{key} has non-finite entries: {array.tolist()}")
    return array


def choice(value, key: str, choices: tuple[str, ...]) -> str:
    if value not in choices:
        raise InputError(f"{key} must be one of {', '.join(choices)}, got {value!r}")
    return value


def flag(value, key: str) -> bool:
    if not isinstance(value, bool):
        raise InputError(f"{key} must be true or false, got {value!r}")
    return value


def known_keys(given: dict, key: str, keys: tuple[str, ...]) -> None:
    """InputError naming the first key of ``given`` not in ``keys``."""
    for name in given:
        if name not in keys:
            raise InputError(f"{key}.{name} is not an option; {key}'s keys are {', '.join(keys)}")
