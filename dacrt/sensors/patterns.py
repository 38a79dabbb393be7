"""Scan patterns: a lidar's rays listed one by one (a non-repetitive Livox-like scan, a unit's own
firing table), each by its azimuth and elevation in the sensor frame, with when it fires and the
channel (ring) that fires it.

Ray m runs along ``(cos e cos a, cos e sin a, sin e)`` in the sensor frame (x forward, y left,
z up; azimuth from +x toward +y, elevation above the xy-plane), with ``a = radians(azimuth_deg[m])``
and ``e = radians(elevation_deg[m])``: the spinning lidar's rule, so a pattern listing a spinning
lidar's angles makes its rays.
"""

from __future__ import annotations

import zipfile
from dataclasses import dataclass

import numpy as np

from ..validation import InputError
from .checks import FLOAT32_MAX

#: The largest channel: a point's ring is uint16, as lidar drivers (Velodyne, Ouster) write it.
MAX_CHANNEL = np.iinfo(np.uint16).max


@dataclass(frozen=True, eq=False)
class Pattern:
    """The rays of a scan pattern, M of them (module docstring).

    azimuth_deg : (M,) float64 degrees, any value within float32's range
    elevation_deg : (M,) float64 degrees in [-90, 90]
    time_s : (M,) float64 seconds from the start of the sweep when each ray fires, or None
    channel : (M,) uint16: each ray's ring (0 to MAX_CHANNEL), or None (every ray ring 0)
    Bad input raises InputError naming the key (``elevation_deg[3] must be in [-90, 90]``).
    """

    azimuth_deg: np.ndarray
    elevation_deg: np.ndarray
    time_s: np.ndarray | None = None
    channel: np.ndarray | None = None

    def __post_init__(self) -> None:
        azimuth = _angles(self.azimuth_deg, "azimuth_deg")
        elevation = _angles(self.elevation_deg, "elevation_deg")
        if len(elevation) != len(azimuth):
            raise InputError(
                f"elevation_deg has {len(elevation)} rays and azimuth_deg {len(azimuth)}: give "
                "one of each per ray"
            )
        _first_bad(np.abs(elevation) > 90, "elevation_deg", "must be in [-90, 90]")
        object.__setattr__(self, "azimuth_deg", azimuth)
        object.__setattr__(self, "elevation_deg", elevation)
        if self.time_s is not None:
            time = _angles(self.time_s, "time_s", len(azimuth))
            _first_bad(time < 0, "time_s", "must be >= 0")
            object.__setattr__(self, "time_s", time)
        if self.channel is not None:
            object.__setattr__(self, "channel", _channels(self.channel, len(azimuth)))

    @property
    def n_rays(self) -> int:
        return len(self.azimuth_deg)

    @classmethod
    def load(cls, file) -> Pattern:
        """The pattern of an ``.npz`` file (a path or a binary file) with keys ``azimuth_deg``,
        ``elevation_deg`` and optional ``time_s``, ``channel``; InputError for other keys."""
        keys = ("azimuth_deg", "elevation_deg", "time_s", "channel")
        try:
            archive = np.load(file, allow_pickle=False)
            if not isinstance(archive, np.lib.npyio.NpzFile):
                raise InputError("a pattern file is an .npz archive of arrays, got one array")
            with archive:
                unknown = [key for key in archive.files if key not in keys]
                if unknown:
                    raise InputError(f"{unknown[0]} is not a key of a pattern; its keys are {keys}")
                for key in keys[:2]:
                    if key not in archive.files:
                        raise InputError(f"a pattern needs {key}")
                arrays = {key: archive[key] for key in archive.files}
        except InputError:
            raise
        except (ValueError, OSError, EOFError, zipfile.BadZipFile) as error:
            raise InputError(
                f"a pattern file is an .npz archive of numeric arrays: {error}"
            ) from None
        return cls(**arrays)

    def save(self, file) -> None:
        """Write the pattern as ``load`` reads it."""
        arrays = {"azimuth_deg": self.azimuth_deg, "elevation_deg": self.elevation_deg}
        if self.time_s is not None:
            arrays["time_s"] = self.time_s
        if self.channel is not None:
            arrays["channel"] = self.channel.astype(np.uint16)
        np.savez(file, **arrays)


def _first_bad(bad: np.ndarray, key: str, words: str) -> None:
    rows = np.flatnonzero(bad)
    if len(rows):
        raise InputError(f"{key}[{rows[0]}] {words} ({len(rows)} rays are not)")


def _angles(values, key: str, n: int | None = None) -> np.ndarray:
    """(M,) finite float64 of at least one entry (exactly ``n`` when given)."""
    array = np.asarray(values)
    if array.ndim != 1 or len(array) == 0 or (n is not None and len(array) != n):
        wanted = "at least one" if n is None else f"{n}, one per ray"
        raise InputError(f"{key} must be a list of numbers ({wanted}), got shape {array.shape}")
    if array.dtype.kind not in "fiu":
        raise InputError(f"{key} must hold numbers, got dtype {array.dtype}")
    array = array.astype(np.float64)
    # the points carry them as float32: beyond its range they would read inf
    _first_bad(~(np.abs(array) <= FLOAT32_MAX), key, "must be a finite number within float32")
    return array


def _channels(values, n: int) -> np.ndarray:
    array = np.asarray(values)
    if array.shape != (n,):
        raise InputError(f"channel must have one entry per ray ({n}), got shape {array.shape}")
    if array.dtype.kind not in "iu":
        raise InputError(f"channel must hold integers, got dtype {array.dtype}")
    _first_bad((array < 0) | (array > MAX_CHANNEL), "channel", f"must be in [0, {MAX_CHANNEL}]")
    return array.astype(np.uint16)
