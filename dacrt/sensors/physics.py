"""The physics of a lidar's returns (docs/sensors.md, "Lidar physics"): materials, intensity,
beam divergence and the returns it makes, Gaussian noise and dropout.

- **Intensity** of a hit at range r with ``cos_incidence`` c on a mesh of reflectivity rho:
  ``rho * c * exp(-attenuation * r)``, in float64 from the float32 c and r. A return's intensity
  is the sum over its hits divided by ``beam_samples``, rounded to float32.
- **Beam divergence**: a beam of full cone angle ``beam_divergence_deg`` is sampled by
  ``beam_samples`` sub-rays. Sub-ray 0 is the beam's axis; sub-ray k >= 1 leans from it by
  ``(beam_divergence_deg / 2) * sqrt(k / (beam_samples - 1))`` toward the angle
  ``k * GOLDEN_ANGLE`` around it (a Vogel spiral: the cone's disc evenly covered, the last
  sub-ray on its edge), measured from the direction of growing azimuth toward growing elevation.
- **Returns**: with one sub-ray every hit is a return. With several, a beam's sub-ray hits sorted
  by range make one return while each is within ``range_resolution`` of the one before; a return
  is reported by its hit of the lowest sub-ray (the axis when it is in the return): its range,
  mesh, prim and cos_incidence.
- **Noise** (``numpy.random.default_rng(noise.seed)``, one generator a scan): first, when
  ``angle_sigma_deg > 0``, an (n_beams, 2) array of normal deviates of that sigma in radians,
  added to each beam's azimuth and elevation before its rays are made (the beam goes elsewhere;
  the point is reported along the nominal direction); then, when a range sigma is not 0, one
  standard normal deviate z per point in answer order: ``range + (range_sigma +
  range_sigma_per_m * range) * z``, at least 0.
- **Dropout** (``numpy.random.default_rng(dropout.seed)``): one uniform deviate u in [0, 1) per
  point in answer order; a point is kept when ``intensity >= min_intensity`` and ``u >= rate``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np

from ..validation import InputError
from .checks import integer, known_keys, number

#: The angle between successive sub-rays around a beam's axis: pi (3 - sqrt 5) radians.
GOLDEN_ANGLE = math.pi * (3 - math.sqrt(5))
#: Reflectivity and label of a mesh that the materials do not name.
DEFAULT_REFLECTIVITY = 0.5
DEFAULT_LABEL = 0
LABEL_MAX = np.iinfo(np.uint32).max


@dataclass(frozen=True, eq=False)
class Materials:
    """Each mesh's ``reflectivity`` (in [0, 1]) and ``label`` (uint32, a semantic class), by
    mesh index: None for the defaults (0.5 and 0), one number for every mesh, or one entry per
    mesh of the scene."""

    reflectivity: object = None
    label: object = None

    def __post_init__(self) -> None:
        if self.reflectivity is not None:
            values = np.asarray(self.reflectivity)
            if values.dtype.kind not in "fiu" or values.ndim > 1:
                raise InputError(f"reflectivity must be numbers, one per mesh, got {values!r}")
            values = values.astype(np.float64)
            bad = np.flatnonzero(~((values >= 0) & (values <= 1)).reshape(-1))
            if len(bad):
                raise InputError(
                    f"reflectivity must be in [0, 1], got {values.reshape(-1)[bad[0]].item()!r}"
                )
            object.__setattr__(self, "reflectivity", values)
        if self.label is not None:
            values = np.asarray(self.label)
            if values.dtype.kind not in "iu" or values.ndim > 1:
                raise InputError(f"label must be integers, one per mesh, got {values!r}")
            bad = np.flatnonzero(((values < 0) | (values > LABEL_MAX)).reshape(-1))
            if len(bad):
                raise InputError(
                    f"label must be in [0, {LABEL_MAX}], got {values.reshape(-1)[bad[0]].item()!r}"
                )
            object.__setattr__(self, "label", values.astype(np.uint32))

    def per_mesh(self, n_meshes: int) -> tuple[np.ndarray, np.ndarray]:
        """(reflectivity (n_meshes,) float64, label (n_meshes,) uint32) of a scene's meshes."""
        return (
            _per_mesh(
                self.reflectivity, DEFAULT_REFLECTIVITY, np.float64, n_meshes, "reflectivity"
            ),
            _per_mesh(self.label, DEFAULT_LABEL, np.uint32, n_meshes, "label"),
        )


def _per_mesh(values, default, dtype, n_meshes: int, key: str) -> np.ndarray:
    if values is None:
        return np.full(n_meshes, default, dtype)
    if values.ndim == 0:
        return np.full(n_meshes, values, dtype)
    if len(values) != n_meshes:
        raise InputError(f"{key} has {len(values)} entries for a scene of {n_meshes} meshes")
    return values


@dataclass(frozen=True)
class Noise:
    """Gaussian noise of a scan (module docstring): sigmas in metres, metres a metre, degrees."""

    range_sigma: float = 0.0
    range_sigma_per_m: float = 0.0
    angle_sigma_deg: float = 0.0
    seed: int = 0

    def __post_init__(self) -> None:
        for key in ("range_sigma", "range_sigma_per_m", "angle_sigma_deg"):
            number(getattr(self, key), f"noise.{key}", at_least=0)
        integer(self.seed, "noise.seed", at_least=0)

    @property
    def ranges(self) -> bool:
        return self.range_sigma > 0 or self.range_sigma_per_m > 0


@dataclass(frozen=True)
class Dropout:
    """Points lost (module docstring): below ``min_intensity``, and the others at ``rate``."""

    rate: float = 0.0
    min_intensity: float = 0.0
    seed: int = 0

    def __post_init__(self) -> None:
        number(self.rate, "dropout.rate", at_least=0, at_most=1)
        number(self.min_intensity, "dropout.min_intensity", at_least=0)
        integer(self.seed, "dropout.seed", at_least=0)


def options(value, kind: type, key: str):
    """``value`` (None, a ``kind``, or a dict of its keys, as the HTTP body gives it) as a
    ``kind`` or None."""
    if value is None or isinstance(value, kind):
        return value
    if not isinstance(value, dict):
        raise InputError(f"{key} must be an object of its options, got {value!r}")
    known_keys(value, key, tuple(f.name for f in fields(kind)))
    return kind(**value)


def beam_directions(pose: np.ndarray, azimuth: np.ndarray, elevation: np.ndarray) -> np.ndarray:
    """(n, 3) float32: ``cos e (cos a R[:, 0] + sin a R[:, 1]) + sin e R[:, 2]`` per beam, in
    float64 then float32 (the spinning lidar's arithmetic, beam by beam); ``pose`` (4, 4), or
    (n, 4, 4) one per beam (a sensor moving during its sweep)."""
    rotation = pose[..., :3, :3]
    r0, r1, r2 = rotation[..., :, 0], rotation[..., :, 1], rotation[..., :, 2]
    level = np.cos(azimuth)[:, None] * r0 + np.sin(azimuth)[:, None] * r1
    directions = np.cos(elevation)[:, None] * level + np.sin(elevation)[:, None] * r2
    return np.ascontiguousarray(directions, dtype=np.float32)


def subray_offsets(divergence_deg: float, samples: int) -> tuple[np.ndarray, np.ndarray]:
    """(lean, around) float64 radians of sub-rays 0 to samples - 1 (module docstring)."""
    k = np.arange(samples, dtype=np.float64)
    lean = math.radians(divergence_deg) / 2 * np.sqrt(k / max(samples - 1, 1))
    return lean, k * GOLDEN_ANGLE


def subray_directions(
    pose: np.ndarray,
    azimuth: np.ndarray,
    elevation: np.ndarray,
    axes: np.ndarray,
    divergence_deg: float,
    samples: int,
) -> np.ndarray:
    """(n_beams * samples, 3) float32, beam-major: sub-ray 0 of each beam is its axis (``axes``,
    as given); sub-ray k leans from the axis d toward ``cos(around) u + sin(around) v``, u and v
    the directions of growing azimuth and elevation: ``cos(lean) d + sin(lean) (...)``;
    ``pose`` (4, 4), or (n_beams, 4, 4) one per beam."""
    lean, around = subray_offsets(divergence_deg, samples)
    ca, sa = np.cos(azimuth)[:, None], np.sin(azimuth)[:, None]
    ce, se = np.cos(elevation)[:, None], np.sin(elevation)[:, None]
    r0, r1, r2 = pose[..., :3, 0], pose[..., :3, 1], pose[..., :3, 2]
    # the axis and its two perpendiculars, turned into the scene once a beam
    axis = (ce * ca) * r0 + (ce * sa) * r1 + se * r2
    u = -sa * r0 + ca * r1
    v = (-se * ca) * r0 + (-se * sa) * r1 + ce * r2
    weights = np.cos(lean), np.sin(lean) * np.cos(around), np.sin(lean) * np.sin(around)
    directions = weights[0][None, :, None] * axis[:, None, :]
    directions += weights[1][None, :, None] * u[:, None, :]
    directions += weights[2][None, :, None] * v[:, None, :]
    directions = directions.astype(np.float32)
    directions[:, 0] = axes
    return directions.reshape(-1, 3)


def cos_incidence(directions: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """float32 ``min(|n . d|, 1)`` per row."""
    return np.minimum(np.abs(np.einsum("ij,ij->i", directions, normal)), np.float32(1))


def contributions(reflectivity, mesh, cosine, t, attenuation: float) -> np.ndarray:
    """float64 ``reflectivity[mesh] * cosine * exp(-attenuation * t)`` per hit."""
    return (
        reflectivity[mesh] * cosine.astype(np.float64) * np.exp(-attenuation * t.astype(np.float64))
    )


@dataclass(frozen=True)
class Returns:
    """A scan's returns, beam by beam and nearest first within a beam: each the row (into the
    hits) of the hit that reports it, its beam, its rank among its beam's returns (0 the nearest),
    and its intensity (float64)."""

    hit: np.ndarray  #: int64
    beam: np.ndarray  #: int64
    rank: np.ndarray  #: int64
    intensity: np.ndarray  #: float64


def group_returns(
    beam: np.ndarray,
    subray: np.ndarray,
    t: np.ndarray,
    contribution: np.ndarray,
    samples: int,
    resolution: float,
) -> Returns:
    """The returns of hits (module docstring): hit i of sub-ray ``subray[i]`` of ``beam[i]`` at
    ``t[i]``; with one sub-ray every hit is a return (hits given beam by beam, nearest first)."""
    n = len(t)
    if samples == 1 and bool(np.all(beam[1:] > beam[:-1])):
        # At most one hit a beam (a closest query): each hit is its beam's one return.
        intensity = np.asarray(contribution, np.float64)
        return Returns(np.arange(n), beam.astype(np.int64), np.zeros(n, np.int64), intensity)
    if samples == 1:
        order = np.arange(n)
        start = np.ones(n, bool)
    else:
        # one integer key: the beam above the bits of t (t >= 0: its bits order as t does;
        # adding 0 turns -0.0 into 0.0); the hits come nearly sorted, beam by beam
        bits = (t + np.float32(0)).view(np.uint32).astype(np.uint64)
        order = np.argsort((beam.astype(np.uint64) << np.uint64(32)) | bits, kind="stable")
        sorted_beam, sorted_t = beam[order], t[order].astype(np.float64)
        start = np.ones(n, bool)
        start[1:] = (sorted_beam[1:] != sorted_beam[:-1]) | (
            sorted_t[1:] - sorted_t[:-1] > resolution
        )
    group = np.cumsum(start) - 1
    n_groups = int(group[-1]) + 1 if n else 0
    intensity = np.bincount(group, contribution[order], minlength=n_groups) / samples
    # the hit of the lowest sub-ray reports its return (the nearest of that sub-ray's hits)
    code = subray[order].astype(np.int64) * max(n, 1) + np.arange(n)
    firsts = np.minimum.reduceat(code, np.flatnonzero(start)) % n if n else np.zeros(0, np.int64)
    hit = order[firsts]
    group_beam = beam[hit]
    beam_start = np.ones(n_groups, bool)
    beam_start[1:] = group_beam[1:] != group_beam[:-1]
    first_of_beam = np.flatnonzero(beam_start)
    rank = np.arange(n_groups) - np.repeat(
        first_of_beam, np.diff(np.append(first_of_beam, n_groups))
    )
    return Returns(hit, group_beam, rank, intensity)


#: What a mode keeps of a beam's returns.
RETURN_MODES = ("first", "last", "strongest", "dual", "all")


def select_returns(returns: Returns, mode: str, max_returns: int) -> np.ndarray:
    """bool per return: ``first`` the nearest, ``last`` the farthest, ``strongest`` the most
    intense (the nearest of equals), ``dual`` the strongest and the last (one return when they
    are the same), ``all`` the nearest ``max_returns``."""
    n = len(returns.beam)
    if mode == "all":
        return returns.rank < max_returns
    if mode == "first":
        return returns.rank == 0
    last = np.ones(n, bool)
    last[:-1] = returns.beam[1:] != returns.beam[:-1]
    if mode == "last":
        return last
    by_strength = np.lexsort((returns.rank, -returns.intensity, returns.beam))
    leads = np.ones(n, bool)
    leads[1:] = returns.beam[by_strength][1:] != returns.beam[by_strength][:-1]
    strongest = np.zeros(n, bool)
    strongest[by_strength[leads]] = True
    return strongest | last if mode == "dual" else strongest
