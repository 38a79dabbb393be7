"""Sensors traced on a scene version by the engine's ``dacrt.sensors``: the rays, the hits and the
answers (pictures, depth images, point clouds) are the engine's, on the same engine scene (built
once per scene version) as ``/closest``; the service adds the meshes' stable indices, their
materials and the request's options.
"""

from __future__ import annotations

import time
from collections.abc import Mapping

import numpy as np

from dacrt.sensors import Camera, Lidar, Materials, Rig
from dacrt.sensors.batch import batch_stats, capture

from . import shading
from .options import Options
from .store import Snapshot
from .tracing import EngineScene, TraceResult, device_for, engine_scene, meshes_by_name

#: A sensor and its sensor-to-scene pose, as a request gives them.
Placed = tuple[Camera | Lidar, np.ndarray]


def materials(snapshot: Snapshot, engine: EngineScene) -> Materials:
    """The reflectivity and label of each mesh of the engine scene, in its mesh order."""
    by_index = {mesh.index: mesh for mesh in snapshot.meshes.values()}
    order = (
        engine.mesh_index[:-1]
        if engine.mesh_index is not None
        else np.arange(engine.scene.n_meshes)
    )
    meshes = [by_index[int(index)] for index in order]
    return Materials(
        reflectivity=np.array([m.reflectivity for m in meshes], np.float64),
        label=np.array([m.label for m in meshes], np.uint32),
    )


def _query(options: Options, device: str) -> dict:
    """What the request asks of the engine's ``Scene.closest`` / ``Scene.hits``, traced on
    ``device`` (``tracing.device_for``)."""
    return {
        "strategy": options.strategy,
        "threads": options.threads,
        "cull": options.cull,
        "mask": options.mask,
        "stats": options.stats,
        "device": device,
    }


def _stats(stats: dict | None, options: Options) -> dict | None:
    return None if stats is None else {**stats, "strategy": options.strategy, "where": "process"}


def _answer(arrays: Mapping[str, np.ndarray], engine: EngineScene, options: Options) -> dict:
    """The arrays the request's ``?fields=`` asks, in the sensor's answer order, with stable mesh
    indices (a lidar's ``time`` comes with a pattern's times only)."""
    picked = {name: array for name, array in arrays.items() if name in options.fields}
    if "mesh" in picked:
        picked["mesh"] = engine.map_mesh(picked["mesh"])
    return picked


def render(snapshot: Snapshot, camera: Camera, pose, style: str, options: Options) -> TraceResult:
    """The pixels of ``camera``'s view from ``pose`` in ``style`` (``shading``), as the answer's
    ``pixels``."""
    start = time.perf_counter()
    engine = engine_scene(snapshot)
    shot = camera.shot(pose)
    device, fallback = device_for(engine, options, "process")
    with meshes_by_name(snapshot, engine):
        (image,) = capture(engine.scene, [shot], None, **_query(options, device))
    t, headers = image["depth"], {}
    if style == "depth":
        pixels, span = shading.depth_pixels(t)
        if span is not None:
            headers["X-Depth-Range"] = f"{span[0]!r} {span[1]!r}"
    elif style == "normal":
        pixels = shading.normal_pixels(t, image["normal"])
    else:
        mesh = engine.map_mesh(image["mesh"])
        directions = shot.rays.directions.reshape(image["normal"].shape)
        pixels = shading.shaded_pixels(t, mesh, image["normal"], directions)
    seconds = time.perf_counter() - start
    stats = _stats(image.stats, options)
    return TraceResult(
        {"pixels": pixels}, snapshot.version, stats, seconds, t.size, headers=headers,
        fallback=fallback,
    )  # fmt: skip


def sense(
    snapshot: Snapshot, sensor: Camera | Lidar, pose, options: Options, pose_end=None
) -> TraceResult:
    """One camera's image or one lidar's points from ``pose`` (``Camera.capture``,
    ``Lidar.scan``; a lidar with ``period_s`` moving to ``pose_end``), with the meshes'
    materials."""
    start = time.perf_counter()
    engine = engine_scene(snapshot)
    device, fallback = device_for(engine, options, "process")
    query = _query(options, device)
    with meshes_by_name(snapshot, engine):
        if isinstance(sensor, Lidar):
            found = sensor.scan(engine.scene, pose, materials(snapshot, engine), pose_end, **query)
        else:
            found = sensor.capture(engine.scene, pose, **query)
    seconds = time.perf_counter() - start
    arrays = _answer(found, engine, options)
    stats = _stats(found.stats, options)
    return TraceResult(
        arrays, snapshot.version, stats, seconds, request_rays(sensor), fallback=fallback
    )


def sense_rig(
    snapshot: Snapshot,
    sensors: Mapping[str, Placed],
    options: Options,
    poses_end: Mapping[str, np.ndarray] | None = None,
) -> TraceResult:
    """Every sensor's answer, their rays traced as one batch (``Rig.capture``) on one version
    (``poses_end``: the lidars that move during their sweep); the answer's arrays are named
    ``NAME.KEY``, sensor by sensor."""
    start = time.perf_counter()
    engine = engine_scene(snapshot)
    rig = Rig({name: sensor for name, (sensor, _) in sensors.items()})
    poses = {name: pose for name, (_, pose) in sensors.items()}
    device, fallback = device_for(engine, options, "process")
    with meshes_by_name(snapshot, engine):
        found = rig.capture(
            engine.scene, poses, materials(snapshot, engine), poses_end, **_query(options, device)
        )
    seconds = time.perf_counter() - start
    arrays = {
        f"{name}.{key}": array
        for name in sensors
        for key, array in _answer(found[name], engine, options).items()
    }
    stats = _stats(batch_stats(found.values()), options)
    n_rays = sum(request_rays(sensor) for sensor, _ in sensors.values())
    return TraceResult(arrays, snapshot.version, stats, seconds, n_rays, fallback=fallback)


def request_rays(sensor: Camera | Lidar) -> int:
    """A sensor's rays as DACRT_MAX_RAYS_PER_REQUEST counts them (API.md): a camera's pixels, a
    lidar's beams x beam_samples, x max_returns with return_mode all (``Lidar.n_rays``)."""
    return sensor.n_traced_rays * hits_per_ray(sensor)


def hits_per_ray(sensor: Camera | Lidar) -> int:
    """The hits a sensor keeps of each ray: ``max_returns`` for a lidar seeing through surfaces
    (``return_mode`` all), else one."""
    if isinstance(sensor, Lidar) and sensor.return_mode == "all":
        return sensor.max_returns
    return 1
