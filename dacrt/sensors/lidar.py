"""Spinning lidars and scan patterns: the rays of one revolution (``Scan``) and ``Lidar``, the
sensor in process with the physics of its returns (``physics``) (docs/sensors.md, "Lidar").

Conventions:

- The sensor frame is x forward, y left, z up; ``pose`` (4, 4, row-major) maps it to the scene.
- A beam pattern is a list of elevations (degrees above the sensor's xy-plane); ring k is the
  k-th lowest of them (a stable sort, so equal elevations keep their order).
- One revolution has ``horizontal_steps`` columns; step s has azimuth ``2 pi s / steps``
  (radians, from +x toward +y, i.e. counter-clockwise seen from +z).
- Ray number ``ring * steps + step`` starts at ``pose[:3, 3]`` and runs along the unit vector
  ``(cos e cos a, cos e sin a, sin e)`` in the sensor frame, which is
  ``cos e * (cos a * R[:, 0] + sin a * R[:, 1]) + sin e * R[:, 2]`` in the scene
  (R = ``pose[:3, :3]``), computed in float64 and rounded to float32. ``t`` along it is the range;
  rays are traced for ``min_range <= t <= max_range``. A point is ``origin + t * direction`` in
  float32 arithmetic.

The named models' elevations are in ``models``; a pattern's rays in ``patterns``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from ..validation import InputError, check_row_count
from . import physics
from .batch import Rays, Shot, Traced, capture
from .cameras import check_pose
from .checks import FLOAT32_MAX, choice, flag, integer, number
from .models import MODELS
from .motion import poses_at
from .patterns import Pattern
from .pcd import write_pcd
from .physics import (
    RETURN_MODES,
    Dropout,
    Materials,
    Noise,
    beam_directions,
    contributions,
    cos_incidence,
    group_returns,
    select_returns,
    subray_directions,
)


@dataclass(frozen=True)
class Scan:
    """One revolution of a spinning lidar (module docstring)."""

    pose: np.ndarray  #: (4, 4) float64 sensor-to-scene, rigid
    elevations_deg: np.ndarray  #: (n_rings,) float64, lowest first (ring order)
    steps: int  #: rays per revolution and ring
    min_range: float
    max_range: float

    @property
    def n_rings(self) -> int:
        return len(self.elevations_deg)

    @property
    def n_rays(self) -> int:
        return self.n_rings * self.steps

    def angles(self) -> tuple[np.ndarray, np.ndarray]:
        """(elevation (n_rings,), azimuth (steps,)) float64 radians."""
        return np.radians(self.elevations_deg), 2 * np.pi * np.arange(self.steps) / self.steps

    def rays(self) -> tuple[np.ndarray, np.ndarray]:
        """(origins, directions), each (n_rays, 3) float32 C-contiguous; ray ``ring * steps +
        step``; directions are unit length before rounding to float32."""
        elevation, azimuth = self.angles()
        rotation = self.pose[:3, :3]
        # the horizontal part once per step, the vertical once per ring
        level = (
            np.cos(azimuth)[:, None] * rotation[:, 0] + np.sin(azimuth)[:, None] * rotation[:, 1]
        )
        directions = (
            np.cos(elevation)[:, None, None] * level
            + (np.sin(elevation)[:, None] * rotation[:, 2])[:, None, :]
        )
        directions = np.ascontiguousarray(directions.reshape(-1, 3), dtype=np.float32)
        origins = np.tile(self.pose[:3, 3].astype(np.float32), (len(directions), 1))
        return origins, directions


def make_scan(pose, vertical_angles_deg, steps: int, min_range: float, max_range: float) -> Scan:
    """A Scan with its rings sorted by elevation; CameraError (a ValueError) for a pose that is
    not rigid."""
    elevations = np.sort(np.asarray(vertical_angles_deg, dtype=np.float64), kind="stable")
    return Scan(check_pose(pose), elevations, steps, min_range, max_range)


def points(
    scan: Scan,
    origins: np.ndarray,
    directions: np.ndarray,
    ray: np.ndarray,
    t: np.ndarray,
    normal: np.ndarray,
) -> dict[str, np.ndarray]:
    """The per-point arrays derived from the hits of ``scan``'s rays, in float32 arithmetic: for
    hit k of ray ``ray[k]`` at ``t[k]`` with unit normal ``normal[k]``: ``xyz`` (origin + t *
    direction), ``range`` (t), ``ring`` uint16, ``azimuth`` and ``elevation`` float32 radians,
    ``cos_incidence`` |n . d| (d is unit up to float32 rounding; at most 1)."""
    elevation, azimuth = (a.astype(np.float32) for a in scan.angles())
    ring = ray // scan.steps
    step = ray - ring * scan.steps
    d = directions[ray]
    cos_incidence = np.abs(np.einsum("ij,ij->i", d, normal))
    return {
        "xyz": origins[0] + t[:, None] * d,  # every ray starts at the sensor
        "range": t,
        "ring": ring.astype(np.uint16),
        "azimuth": azimuth[step],
        "elevation": elevation[ring],
        "cos_incidence": np.minimum(cos_incidence, np.float32(1)),
    }


#: Most beams (rings) of explicit elevations, returns per beam, and sub-rays per beam.
MAX_BEAMS = 1024
MAX_RETURNS = 64
MAX_BEAM_SAMPLES = 64
#: The shortest sweep (seconds): speeds are displacements over it, in float32.
MIN_PERIOD_S = 1e-6
#: The arrays of a lidar's answer, in answer order; ``time`` only for a pattern with ``time_s`` or
#: a lidar with ``period_s``, ``velocity`` and ``radial_speed`` only with ``period_s``.
LIDAR_FIELDS = (
    "xyz",
    "range",
    "ring",
    "azimuth",
    "elevation",
    "mesh",
    "prim",
    "return",
    "cos_incidence",
    "ray",
    "intensity",
    "label",
    "time",
    "velocity",
    "radial_speed",
)
#: The value of a point that did not return (``non_hits="keep"``, organized answers' empty cells);
#: ring, azimuth, elevation, ray and time keep their beam's values.
FILL = {
    "xyz": np.float32(np.nan),
    "range": np.float32(np.inf),
    "mesh": -1,
    "prim": -1,
    "return": -1,
    "cos_incidence": 0,
    "intensity": 0,
    "label": 0,
    "velocity": np.float32(np.nan),
    "radial_speed": np.float32(np.nan),
}
NON_HITS = ("drop", "keep")
#: Where a lidar's points are given: the scene's frame, or the sensor's at the sweep's start.
FRAMES = ("scene", "sensor")


@dataclass(frozen=True, eq=False)
class Lidar:
    """A lidar: its beams (exactly one of ``model``, ``vertical_angles_deg`` and ``pattern``),
    range window and physics, each option named and checked as the HTTP body of ``/lidar`` names
    it (docs/sensors.md); ``scan(scene, pose)`` traces it.

    model : one of ``MODELS``' names; vertical_angles_deg : 1 to MAX_BEAMS elevations in degrees;
        pattern : a ``Pattern`` (its rays in its order; not ``organized``)
    horizontal_steps : columns of a revolution (a spinning lidar's)
    min_range, max_range : the range window (max_range None, inf or beyond float32: no limit;
        min_range at most float32's largest)
    return_mode : one of ``RETURN_MODES``, or None: ``all`` when max_returns > 1, else ``first``
        (as a ``/lidar`` body without it); max_returns : at most this many returns (mode ``all``)
    beam_divergence_deg, beam_samples, range_resolution, attenuation : ``physics``
    noise : a ``Noise`` or a dict of its keys; dropout : a ``Dropout`` or a dict of its keys
    non_hits : ``drop`` or ``keep`` (a beam that returns nothing is one point of FILL values)
    organized : arrays shaped (rings, steps) or (rings, steps, returns) instead of a list
    period_s : None (the sweep is an instant), or the sweep's duration in seconds: column s of
        a spinning lidar fires at tau = s / steps of it, a pattern's ray at time_s / period_s,
        from the sensor's pose at tau (``scan``'s ``pose_end``) into the scene at tau (meshes
        moving by ``transforms_end``); points then carry ``time`` (seconds from the sweep's
        start), ``velocity`` (the hit surface's, scene units a second) and ``radial_speed``
        (along the beam, relative to the sensor, positive receding)
    frame : ``scene`` (default) or ``sensor``: xyz (and velocity) in the sensor's frame at the
        sweep's start (``pose``), as a driver that does not undo the sensor's motion reports them
    """

    model: str | None = None
    vertical_angles_deg: object = None
    pattern: Pattern | None = None
    horizontal_steps: int = 1024
    min_range: float = 0.0
    max_range: float | None = math.inf
    max_returns: int = 1
    return_mode: str | None = None
    beam_divergence_deg: float = 0.0
    beam_samples: int = 1
    range_resolution: float = 0.1
    attenuation: float = 0.004
    noise: Noise | dict | None = None
    dropout: Dropout | dict | None = None
    non_hits: str = "drop"
    organized: bool = False
    period_s: float | None = None
    frame: str = "scene"

    def __post_init__(self) -> None:
        given = [self.model, self.vertical_angles_deg, self.pattern]
        if sum(value is not None for value in given) != 1:
            raise InputError(
                "give exactly one beam pattern: model (one of "
                f"{', '.join(MODELS)}), vertical_angles_deg (elevations in degrees) or pattern"
            )
        if self.model is not None:
            choice(self.model, "model", tuple(MODELS))
        if self.vertical_angles_deg is not None:
            object.__setattr__(self, "vertical_angles_deg", _elevations(self.vertical_angles_deg))
        if self.pattern is not None and not isinstance(self.pattern, Pattern):
            raise InputError(f"pattern must be a dacrt.sensors.Pattern, got {self.pattern!r}")
        integer(self.horizontal_steps, "horizontal_steps", at_least=1)
        number(self.min_range, "min_range", at_least=0, at_most=FLOAT32_MAX)
        if self.max_range is None:
            object.__setattr__(self, "max_range", math.inf)
        number(self.max_range, "max_range", above=self.min_range, infinite=True)
        if self.max_range > FLOAT32_MAX:  # the rays' windows are float32: beyond it is no limit
            object.__setattr__(self, "max_range", math.inf)
        integer(self.max_returns, "max_returns", at_least=1, at_most=MAX_RETURNS)
        if self.return_mode is None:  # max_returns alone asks for every return
            object.__setattr__(self, "return_mode", "all" if self.max_returns > 1 else "first")
        choice(self.return_mode, "return_mode", RETURN_MODES)
        number(self.beam_divergence_deg, "beam_divergence_deg", at_least=0, below=180)
        integer(self.beam_samples, "beam_samples", at_least=1, at_most=MAX_BEAM_SAMPLES)
        number(self.range_resolution, "range_resolution", at_least=0)
        number(self.attenuation, "attenuation", at_least=0)
        object.__setattr__(self, "noise", physics.options(self.noise, Noise, "noise"))
        object.__setattr__(self, "dropout", physics.options(self.dropout, Dropout, "dropout"))
        choice(self.non_hits, "non_hits", NON_HITS)
        flag(self.organized, "organized")
        choice(self.frame, "frame", FRAMES)
        if self.period_s is not None:
            number(self.period_s, "period_s", at_least=MIN_PERIOD_S)
            if self.pattern is not None and self.pattern.time_s is None:
                raise InputError("period_s needs a pattern with time_s (when each ray fires)")
            if self.pattern is not None and not self.pattern.time_s.max() <= self.period_s:
                late = int(np.argmax(self.pattern.time_s > self.period_s))
                raise InputError(
                    f"time_s[{late}] is {float(self.pattern.time_s[late])!r}, beyond period_s "
                    f"({self.period_s!r}): a ray fires within the sweep"
                )
        if self.organized and self.pattern is not None:
            raise InputError(
                "organized needs a spinning lidar (model or vertical_angles_deg): a pattern's "
                "rays have no rings x steps layout"
            )

    @property
    def elevations_deg(self) -> np.ndarray | None:
        """(n_rings,) float64 of a spinning lidar, as given (``Scan`` sorts them); None for a
        pattern."""
        if self.model is not None:
            return np.array(MODELS[self.model].vertical_angles_deg)
        return self.vertical_angles_deg

    @property
    def n_beams(self) -> int:
        if self.pattern is not None:
            return self.pattern.n_rays
        return len(self.elevations_deg) * self.horizontal_steps

    @property
    def n_traced_rays(self) -> int:
        """The rays one scan traces: beams x sub-rays."""
        return self.n_beams * self.beam_samples

    @property
    def n_rays(self) -> int:
        """The rays traced a scan: beams x sub-rays (x max_returns hits each in mode ``all``)."""
        return self.n_traced_rays * (self.max_returns if self.return_mode == "all" else 1)

    @property
    def fields(self) -> tuple[str, ...]:
        """The keys of this lidar's points, in LIDAR_FIELDS' order: ``time`` only with period_s
        or a pattern's times, ``velocity`` and ``radial_speed`` only with period_s."""
        timed = self.period_s is not None or (
            self.pattern is not None and self.pattern.time_s is not None
        )
        absent = set() if timed else {"time"}
        if self.period_s is None:
            absent |= {"velocity", "radial_speed"}
        return tuple(name for name in LIDAR_FIELDS if name not in absent)

    @property
    def slots(self) -> int:
        """The most points a beam gives: the last axis of an organized answer (1: no axis)."""
        return {"all": self.max_returns, "dual": 2}.get(self.return_mode, 1)

    def scan(
        self, scene, pose, materials: Materials | dict | None = None, pose_end=None, **query
    ) -> LidarPoints:
        """The points of one sweep from ``pose`` (4x4 sensor-to-scene, rigid) in ``scene`` (a
        ``dacrt.Scene``) whose meshes have ``materials``; ``pose_end`` (with ``period_s``) is
        the sensor's pose at the sweep's end (None: it stays at ``pose``); ``query`` goes to
        ``Scene.closest`` / ``Scene.hits`` (strategy, threads, cull, mask, stats)."""
        return capture(scene, [self.shot(pose, pose_end)], materials, **query)[0]

    def shot(self, pose, pose_end=None) -> Shot:
        """The lidar at ``pose`` (to ``pose_end``), ready to trace (for a batch of sensors)."""
        check_row_count(self.n_traced_rays, "a scan (beams x beam_samples)", "rays")
        pose = check_pose(pose)
        if pose_end is not None:
            if self.period_s is None:
                raise InputError("pose_end needs period_s (the sweep's duration)")
            pose_end = check_pose(pose_end, "pose_end")
        beams = self._beams(pose, pose_end)
        generator = None if self.noise is None else np.random.default_rng(self.noise.seed)
        azimuth, elevation, axes = beams.azimuth, beams.elevation, beams.directions
        if generator is not None and self.noise.angle_sigma_deg > 0:
            sigma = math.radians(self.noise.angle_sigma_deg)
            offsets = generator.normal(0.0, sigma, (len(azimuth), 2))
            azimuth, elevation = azimuth + offsets[:, 0], elevation + offsets[:, 1]
            axes = beam_directions(beams.pose, azimuth, elevation)
        directions = axes
        if self.beam_samples > 1:
            directions = subray_directions(
                beams.pose, azimuth, elevation, axes, self.beam_divergence_deg, self.beam_samples
            )
        if beams.origins is None:
            origins = np.tile(beams.origin, (len(directions), 1))
        else:
            origins = np.repeat(beams.origins, self.beam_samples, axis=0)
        max_hits = self.max_returns if self.return_mode == "all" else None
        tau = None if beams.tau is None else np.repeat(beams.tau, self.beam_samples)
        rays = Rays(origins, directions, self.min_range, self.max_range, max_hits, tau)
        return Shot(
            rays,
            lambda traced, materials: self._points(beams, directions, generator, traced, materials),
        )

    def _beams(self, pose: np.ndarray, pose_end: np.ndarray | None) -> Beams:
        if self.pattern is not None:
            azimuth = np.radians(self.pattern.azimuth_deg)
            elevation = np.radians(self.pattern.elevation_deg)
            n = len(azimuth)
            ring = np.zeros(n, np.uint16) if self.pattern.channel is None else self.pattern.channel
            time = None if self.pattern.time_s is None else self.pattern.time_s.astype(np.float32)
            tau = None
            if self.period_s is not None:
                tau = np.minimum(self.pattern.time_s / self.period_s, 1.0).astype(np.float32)
            layout = None
        else:
            scan = make_scan(pose, self.elevations_deg, self.horizontal_steps, 0.0, math.inf)
            elevation, azimuth = scan.angles()
            ring = np.repeat(np.arange(scan.n_rings), scan.steps)
            step = np.tile(np.arange(scan.steps), scan.n_rings)
            azimuth_out = azimuth.astype(np.float32)[step]
            elevation_out = elevation.astype(np.float32)[ring]
            azimuth, elevation, ring = azimuth[step], elevation[ring], ring.astype(np.uint16)
            time = tau = None
            if self.period_s is not None:
                # Column s fires at s / steps of the sweep.
                tau = (step / scan.steps).astype(np.float32)
                time = (step / scan.steps * self.period_s).astype(np.float32)
            layout = (scan.n_rings, scan.steps)
        moving = pose_end is not None and not np.array_equal(pose, pose_end)
        poses = poses_at(pose, pose_end, tau) if moving else pose
        origins = poses[:, :3, 3].astype(np.float32) if moving else None
        if layout is not None and not moving:
            directions = scan.rays()[1]
        else:
            directions = beam_directions(poses, azimuth, elevation)
        return Beams(
            pose=poses,
            origin=pose[:3, 3].astype(np.float32),
            directions=directions,
            azimuth=azimuth,
            elevation=elevation,
            ring=ring,
            azimuth_out=azimuth.astype(np.float32) if layout is None else azimuth_out,
            elevation_out=elevation.astype(np.float32) if layout is None else elevation_out,
            time=time,
            layout=layout,
            origins=origins,
            tau=tau,
            sensor_velocity=_sensor_velocity(pose, pose_end, self.period_s),
            pose_start=pose,
        )

    def _points(
        self, beams: Beams, directions, generator, traced: Traced, materials
    ) -> LidarPoints:
        reflectivity, labels = materials
        if traced.offsets is None:
            ray = np.flatnonzero(np.isfinite(traced.t))
            t, mesh, prim, normal = (
                np.take(a, ray, axis=0) for a in (traced.t, traced.mesh, traced.prim, traced.normal)
            )
        else:
            ray = np.repeat(np.arange(len(directions)), np.diff(traced.offsets))
            t, mesh, prim, normal = traced.t, traced.mesh, traced.prim, traced.normal
        if self.beam_samples == 1:
            beam, subray = ray, np.zeros_like(ray)
        else:
            beam, subray = np.divmod(ray, self.beam_samples)
        # np.take gathers rows several times faster than indexing with an array
        cosine = cos_incidence(np.take(directions, ray, axis=0), normal)
        contribution = contributions(reflectivity, mesh, cosine, t, self.attenuation)
        returns = group_returns(
            beam, subray, t, contribution, self.beam_samples, self.range_resolution
        )
        chosen = select_returns(returns, self.return_mode, self.max_returns)
        hit, beam, rank = returns.hit[chosen], returns.beam[chosen], returns.rank[chosen]
        intensity = returns.intensity[chosen].astype(np.float32)
        distance = t[hit]
        if self.noise is not None and self.noise.ranges:
            deviate = generator.standard_normal(len(hit))
            exact = distance.astype(np.float64)
            sigma = self.noise.range_sigma + self.noise.range_sigma_per_m * exact
            # a measured range is never negative, and one beyond float32 is no return
            noisy = np.maximum(exact + sigma * deviate, 0)
            measured = noisy <= FLOAT32_MAX
            hit, beam, rank, intensity = (a[measured] for a in (hit, beam, rank, intensity))
            distance = noisy[measured].astype(np.float32)
        if self.dropout is not None:
            uniform = np.random.default_rng(self.dropout.seed).random(len(hit))
            kept = (intensity >= self.dropout.min_intensity) & (uniform >= self.dropout.rate)
            hit, beam, rank, intensity, distance = (
                a[kept] for a in (hit, beam, rank, intensity, distance)
            )
        beam_axes = np.take(beams.directions, beam, axis=0)
        arrays = {
            # every ray starts at the sensor; a point lies along its beam's nominal direction
            "xyz": beams.origin + distance[:, None] * beam_axes,
            "range": distance,
            "ring": beams.ring[beam],
            "azimuth": beams.azimuth_out[beam],
            "elevation": beams.elevation_out[beam],
            "mesh": mesh[hit],
            "prim": prim[hit],
            "return": rank.astype(np.int16),
            "cos_incidence": cosine[hit],
            "ray": beam.astype(np.int32),
            "intensity": intensity,
            "label": labels[mesh[hit]],
        }
        if beams.origins is not None:  # a moving sensor: each beam from where it fired
            arrays["xyz"] = np.take(beams.origins, beam, axis=0) + distance[:, None] * beam_axes
        if beams.time is not None:
            arrays["time"] = beams.time[beam]
        if beams.tau is not None:
            arrays.update(self._speeds(beams, beam, traced, ray, hit))
        if self.frame == "sensor":
            arrays.update(_in_sensor_frame(arrays, beams.pose_start))
        if self.organized:
            arrays = self._organize(arrays, beam, beams)
        elif self.non_hits == "keep":
            arrays = _keep_non_hits(arrays, beam, beams)
        return LidarPoints(arrays, self.organized, traced.stats)

    def _speeds(self, beams: Beams, beam, traced: Traced, ray, hit) -> dict:
        """``velocity`` (M, 3) float32, the hit surface's in scene units a second, and
        ``radial_speed`` (M,) float32, (surface - sensor velocity) along the unit beam, positive
        receding."""
        motion = traced.motion[ray] if traced.offsets is None else traced.motion
        velocity = motion[hit] / self.period_s
        axis = beams.directions[beam].astype(np.float64)
        axis /= np.linalg.norm(axis, axis=1, keepdims=True)
        relative = velocity - beams.sensor_velocity
        radial = np.einsum("ij,ij->i", relative, axis)
        return {"velocity": velocity.astype(np.float32), "radial_speed": radial.astype(np.float32)}

    def _organize(self, arrays: dict, beam: np.ndarray, beams: Beams) -> dict:
        """Arrays of shape (n_beams, slots) filled with FILL, each point in its beam's row at its
        rank among the beam's points; then (rings, steps[, slots])."""
        slots = self.slots
        starts = np.searchsorted(beam, beam, side="left")
        slot = np.arange(len(beam)) - starts
        shape = beams.layout + ((slots,) if slots > 1 else ())
        organized = {}
        for name, values in _filled(beams, arrays).items():
            grid = np.repeat(values[:, None], slots, axis=1)
            grid[beam, slot] = arrays[name]
            organized[name] = grid.reshape(shape + values.shape[1:])
        return organized


@dataclass(frozen=True)
class Beams:
    """A lidar's beams at a pose: nominal directions and angles (float64 radians), and the
    per-beam values of its points."""

    pose: np.ndarray  #: (4, 4) float64
    origin: np.ndarray  #: (3,) float32
    directions: np.ndarray  #: (n, 3) float32, nominal
    azimuth: np.ndarray  #: (n,) float64 radians
    elevation: np.ndarray  #: (n,) float64 radians
    ring: np.ndarray  #: (n,) uint16
    azimuth_out: np.ndarray  #: (n,) float32: the points' azimuth
    elevation_out: np.ndarray  #: (n,) float32
    time: np.ndarray | None  #: (n,) float32 seconds, a pattern's or with period_s
    layout: tuple[int, int] | None  #: (rings, steps) of a spinning lidar
    origins: np.ndarray | None = None  #: (n, 3) float32 of a sensor moving in its sweep
    tau: np.ndarray | None = None  #: (n,) float32 in [0, 1], each beam's instant (period_s)
    sensor_velocity: np.ndarray | None = None  #: (3,) float64 scene units a second
    pose_start: np.ndarray | None = None  #: (4, 4) float64: the pose at the sweep's start


def _in_sensor_frame(arrays: dict, pose: np.ndarray) -> dict:
    """``xyz`` (and ``velocity``) moved from the scene into the frame of ``pose``, in float64
    then float32."""
    rotation, origin = pose[:3, :3], pose[:3, 3]
    moved = {"xyz": ((arrays["xyz"].astype(np.float64) - origin) @ rotation).astype(np.float32)}
    if "velocity" in arrays:
        moved["velocity"] = (arrays["velocity"].astype(np.float64) @ rotation).astype(np.float32)
    return moved


def _sensor_velocity(pose, pose_end, period_s) -> np.ndarray:
    """The sensor's velocity during the sweep (its translation is linear in time)."""
    if pose_end is None or period_s is None:
        return np.zeros(3)
    move = pose_end[:3, 3] - pose[:3, 3]
    velocity = move / period_s
    if not np.abs(velocity).max() <= FLOAT32_MAX:
        raise InputError(
            f"pose_end: a move of {np.abs(move).max():.3g} in period_s ({period_s!r}) is a speed "
            "beyond float32's range"
        )
    return velocity


def _filled(beams: Beams, arrays: dict) -> dict:
    """One point per beam with FILL values (and the beam's own ring, angles, ray and time), for
    every array of ``arrays``."""
    n_beams = len(beams.ring)
    per_beam = {
        "ring": beams.ring,
        "azimuth": beams.azimuth_out,
        "elevation": beams.elevation_out,
        "ray": np.arange(n_beams, dtype=np.int32),
        "time": beams.time,
    }
    filled = {}
    for name, values in arrays.items():
        if name in per_beam:
            filled[name] = per_beam[name]
        else:
            filled[name] = np.full((n_beams,) + values.shape[1:], FILL[name], values.dtype)
    return filled


def _keep_non_hits(arrays: dict, beam: np.ndarray, beams: Beams) -> dict:
    """``arrays`` with one FILL point for each beam that has none, in beam order."""
    n_beams = len(beams.ring)
    silent = np.ones(n_beams, bool)
    silent[beam] = False
    filled = _filled(beams, arrays)
    order = np.argsort(np.concatenate([beam, np.flatnonzero(silent)]), kind="stable")
    return {
        name: np.concatenate([values, filled[name][silent]])[order]
        for name, values in arrays.items()
    }


@dataclass(frozen=True)
class LidarPoints(Mapping):
    """A lidar's answer: ``points["xyz"]``, ``points["range"]`` ... by the names of LIDAR_FIELDS
    (docs/sensors.md): one row per point, beam by beam and nearest first; or, ``organized``,
    arrays of shape (rings, steps) or (rings, steps, returns), FILL where nothing returned."""

    arrays: dict[str, np.ndarray]
    organized: bool = False
    stats: dict | None = None  #: the trace's counters when asked with stats=True

    def __getitem__(self, key: str) -> np.ndarray:
        return self.arrays[key]

    def __iter__(self):
        return iter(self.arrays)

    def __len__(self) -> int:
        return len(self.arrays)

    @property
    def n_points(self) -> int:
        return self.arrays["range"].size

    def write_pcd(self, file, fields=None) -> None:
        """Write the points as a binary PCD v0.7 file (``pcd.write_pcd``)."""
        write_pcd(file, self, fields)


def _elevations(values) -> np.ndarray:
    """Explicit elevations as (n,) float64: 1 to MAX_BEAMS finite numbers in [-90, 90]."""
    array = np.asarray(values)
    if array.ndim != 1 or not 1 <= len(array) <= MAX_BEAMS or array.dtype.kind not in "fiu":
        raise InputError(
            f"vertical_angles_deg must be a list of 1 to {MAX_BEAMS} elevations in degrees, "
            f"got {values!r}"
        )
    array = array.astype(np.float64)
    bad = np.flatnonzero(~(np.abs(array) <= 90))
    if len(bad):
        raise InputError(
            f"vertical_angles_deg[{bad[0]}] must be in [-90, 90], got {array[bad[0]].item()!r}"
        )
    return array
