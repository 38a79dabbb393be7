"""World frames: lidars in a static street world with moving actors, per frame, beside
Embree's two-level scene (``../shared/anchors/embree_instances.cpp``).

    python -m bench.world                      # 3.3M static triangles, 40 cars, 1-16 lidars
    python -m bench.world --quick              # 0.5M triangles, 1 and 4 lidars, 3 frames
    python -m bench.world --triangles 8000000 --lidars 1,8 --frames 5 --out /tmp/world

The world (``build_world``, Z up, metres) is built from the shared scenes: a ground grid, rows of
box buildings along a straight street, Sibenik, the conference room and Sponza as buildings of the
rows (those that fit in 60% of the target), and copies of the dragon, the armadillo and the bunny
as statues on the sidewalks, added until the next would pass ``--triangles``. ``--actors`` cars
(the teapot, 4.5 m long) drive in four lanes; every frame moves each by its own seeded speed and
a small yaw (``actor_transforms``). The lidars are HDL-64E revolutions of 2048 steps (131,072 rays
each), made by ``dacrt.sensors.lidar`` (the engine's ray generation, which the server runs), on
the street's centre line 1.9 m up, each moving 1 m a frame. With N lidars a frame is one batch of
N x 131,072 rays.

Per frame, side by side, the engines' order turned every frame, frame 0 an untimed warm-up of
each, medians of ``--frames`` frames on ``--threads`` threads:

  embree        the anchor, one process per frame: it builds the world and the car once (medium;
                ``static ms``, not part of the frame), runs the previous frame untimed, then the
                frame: the K transforms + the top level's commit (``commit``) + the rays (``trace``)
  embree dynamic
                the same anchor with the rays taken in chunks of 256 from a shared counter
                (``bench/anchors/embree_instances_dynamic.cpp``): the anchor gives each thread a
                fixed share of the rays, which with one lidar are unequal work
  dacrt         ``dacrt.Scene`` of the world + K placed cars (``transforms=``, built every frame:
                ``scene``), then ``closest`` of every lidar's rays as one batch (``trace``)
  dacrt changes only when ``dacrt.Scene.with_changes`` exists: the previous frame's scene
                ``.with_changes(transforms={1 + i: matrix})`` (``scene``), then ``closest``
  service       a real server (``service.app``, uvicorn, ``DACRT_THREADS``): ``POST .../frame``
                of the K ``carNN.transform`` (``frame``), then one ``POST .../lidar`` per lidar
                (``sensors``; the first builds the engine's scene of the new version)
  service rig   only when the server has ``POST /v1/scenes/{scene}/sensors`` (the rigs of
                ../shared/API.md): the same frame, then every lidar in one ``/sensors`` request

The two service engines each have a scene of their own on the server (``SERVICE_SCENES``, both
uploaded at the start), so each frame moves the cars of the scene it is posted to: a second post
of the same transforms to one scene would change nothing, and its version would reuse the
engine scene of the first.

Every frame's answers are checked: dacrt's t against Embree's (the same hit or miss, and t within
1e-4 of the world's diagonal; the worst relative difference is printed), the two anchors' t
against each other (identical: the same calls on the same scene), and the service's against
dacrt's (identical: the same engine on the same rays). ``--out`` gets ``world.json`` (every
timing, the checks, the machine and the git commit), ``world.md`` (the tables) and
``world-frames.png``; ``--replot`` redraws the figure.
"""

from __future__ import annotations

import argparse
import functools
import gc
import io
import json
import math
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bench.entry import description, use_kernel_cache

REPO = Path(__file__).resolve().parent.parent
LIDAR_MODEL = "HDL-64E"
STEPS = 2048
LIDAR_HEIGHT = 1.9
LANES_Y = (-5.4, -1.9, 1.9, 5.4)  # y > 0 drives toward -x, y < 0 toward +x
CAR_LENGTH = 4.5
FRAME_DT = 0.1  # seconds a frame
LIDAR_STEP = 1.0  # metres each lidar moves a frame
SIDEWALK = (7.0, 14.0)  # |y| of the sidewalks; the road is |y| < 7, buildings beyond 14
LANDMARKS = ("sibenik", "conference", "sponza")  # buildings of the rows, in this order
STATUES = ("dragon", "armadillo", "bunny")
MAX_LIDARS = 16
#: The shared anchor's copy that takes the rays in dynamic chunks (its header says what differs).
DYNAMIC_ANCHOR = Path(__file__).resolve().parent / "anchors" / "embree_instances_dynamic.cpp"
#: The scene of each service engine on the server: each frame is a real change of its own scene.
SERVICE_SCENES = {"service": "world", "service rig": "world_rig"}


# --- the world ------------------------------------------------------------------------------------


def find_shared() -> Path | None:
    """The project's shared folder: ``../shared`` beside the repository, or one level further up
    (a worktree in a folder beside ``shared``)."""
    for candidate in (REPO.parent / "shared", REPO.parent.parent / "shared"):
        if (candidate / "scenes").is_dir():
            return candidate
    return None


@functools.cache
def _z_up(scenes: Path, name: str) -> tuple[np.ndarray, np.ndarray]:
    """A shared scene in float64, turned Z up (all but the conference room are Y up), its
    footprint centred on the origin and standing on z = 0."""
    with np.load(scenes / f"{name}.npz") as z:
        vertices = z["vertices"].astype(np.float64)
        faces = np.ascontiguousarray(z["faces"], np.int32)
    if name != "conference":
        vertices = np.stack([vertices[:, 0], -vertices[:, 2], vertices[:, 1]], axis=1)
    used = vertices[np.unique(faces)]
    low, high = used.min(0), used.max(0)
    vertices = vertices - [(low[0] + high[0]) / 2, (low[1] + high[1]) / 2, low[2]]
    return vertices, faces


def grid_patch(corner, u, v, nu: int, nv: int) -> tuple[np.ndarray, np.ndarray]:
    """A parallelogram ``corner + a u + b v`` (a, b in [0, 1]) cut into nu x nv quads, two
    triangles each, wound so that the normal is u x v."""
    a = np.linspace(0.0, 1.0, nu + 1)
    b = np.linspace(0.0, 1.0, nv + 1)
    vertices = (
        np.asarray(corner, np.float64)
        + a[:, None, None] * np.asarray(u, np.float64)
        + b[None, :, None] * np.asarray(v, np.float64)
    ).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(nu), np.arange(nv), indexing="ij")
    p00 = (i * (nv + 1) + j).ravel()
    p10, p01 = p00 + nv + 1, p00 + 1
    p11 = p10 + 1
    faces = np.concatenate([np.stack([p00, p10, p11], 1), np.stack([p00, p11, p01], 1)])
    return vertices, faces.astype(np.int32)


def box_building(x0, x1, y0, y1, height, cell: float = 3.0) -> list[tuple[np.ndarray, np.ndarray]]:
    """Four walls and a roof (no floor), each cut into cells of about ``cell`` metres."""

    def n(length):
        return max(1, round(length / cell))

    w, d = x1 - x0, y1 - y0
    up = (0, 0, height)
    return [
        grid_patch((x0, y0, 0), (w, 0, 0), up, n(w), n(height)),
        grid_patch((x1, y1, 0), (-w, 0, 0), up, n(w), n(height)),
        grid_patch((x1, y0, 0), (0, d, 0), up, n(d), n(height)),
        grid_patch((x0, y1, 0), (0, -d, 0), up, n(d), n(height)),
        grid_patch((x0, y0, height), (w, 0, 0), (0, d, 0), n(w), n(d)),
    ]


def placed(vertices, faces, scale, yaw, offset) -> tuple[np.ndarray, np.ndarray]:
    c, s = math.cos(yaw), math.sin(yaw)
    rotation = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    return (vertices * scale) @ rotation.T + np.asarray(offset, np.float64), faces


@dataclass
class World:
    vertices: np.ndarray  #: (V, 3) float32
    faces: np.ndarray  #: (F, 3) int32
    length: float  #: of the street, along x, centred on 0
    parts: dict[str, int] = field(default_factory=dict)  #: triangles by part

    @property
    def diagonal(self) -> float:
        return float(np.linalg.norm(self.vertices.max(0) - self.vertices.min(0)))


def street_length(triangles: int) -> float:
    """100 m, plus 60 m a million triangles (130 m at 0.5M, 300 m at 3.3M, 580 m at 8M)."""
    return 100.0 + 60.0 * triangles / 1e6


def build_world(scenes: Path, triangles: int = 3_300_000, seed: int = 0) -> World:
    """The static street world of about ``triangles`` triangles (module docstring): within one
    bunny (69K) below it, unless the fixed parts alone pass it."""
    rng = np.random.default_rng(seed)
    length = street_length(triangles)
    half = length / 2
    meshes: list[tuple[np.ndarray, np.ndarray]] = []
    parts: dict[str, int] = {}

    def add(name, mesh):
        meshes.append(mesh)
        parts[name] = parts.get(name, 0) + len(mesh[1])

    add(
        "ground",
        grid_patch(
            (-half - 20, -60, 0), (length + 40, 0, 0), (0, 120, 0), round((length + 40) / 2), 60
        ),
    )
    total = parts["ground"]
    # the rows of buildings: landmarks first (those that fit in 60% of the target), then boxes
    landmarks = []
    for name in LANDMARKS:
        vertices, faces = _z_up(scenes, name)
        if total + len(faces) <= 0.6 * triangles:
            landmarks.append(name)
            total += len(faces)
    for side in (-1.0, 1.0):
        x = -half
        todo = [n for k, n in enumerate(landmarks) if k % 2 == (side > 0)]
        lots = max(len(todo), int(length / 25))  # about the lots a row has
        slots = sorted(rng.choice(lots, size=len(todo), replace=False)) if todo else []
        lot = 0
        while x < half or todo:
            if todo and lot == slots[0]:
                name = todo.pop(0)
                slots = slots[1:]
                vertices, faces = _z_up(scenes, name)
                extent = np.ptp(vertices, axis=0)
                scale = 40.0 / max(extent[0], extent[1])  # 40 m along the street
                width, depth = extent[:2] * scale
                x1 = x + width
                add(
                    name,
                    placed(
                        vertices,
                        faces,
                        scale,
                        0.0,
                        (x + width / 2, side * (SIDEWALK[1] + 1 + depth / 2), 0),
                    ),
                )
            else:
                width = rng.uniform(10, 25)
                x1 = x + width if todo else min(x + width, half)
                y0, y1 = sorted(side * np.array([SIDEWALK[1], SIDEWALK[1] + rng.uniform(10, 20)]))
                for patch in box_building(x, x1, y0, y1, rng.uniform(8, 40)):
                    add("boxes", patch)
            x = x1 + rng.uniform(2, 5)
            lot += 1
    total = sum(parts.values())
    # statues on the sidewalks until the next one would pass the target
    statues = []
    while True:
        for name in STATUES[len(statues) % 3 :] + STATUES[: len(statues) % 3]:
            if total + len(_z_up(scenes, name)[1]) <= triangles:
                statues.append(name)
                total += len(_z_up(scenes, name)[1])
                break
        else:
            break
    per_side = max(1, math.ceil(len(statues) / 2))
    spacing = length / per_side
    for k, name in enumerate(statues):
        vertices, faces = _z_up(scenes, name)
        extent = np.ptp(vertices, axis=0)
        scale = min(rng.uniform(2.5, 5.0) / extent[2], 6.0 / max(extent[0], extent[1]))
        side = -1.0 if k % 2 else 1.0
        x = -half + spacing * (k // 2 + 0.5) + rng.uniform(-0.2, 0.2) * spacing
        add(
            name,
            placed(
                vertices, faces, scale, rng.uniform(0, 2 * np.pi), (x, side * sum(SIDEWALK) / 2, 0)
            ),
        )
    offsets = np.cumsum([0] + [len(v) for v, _ in meshes])
    vertices = np.concatenate([v for v, _ in meshes]).astype(np.float32)
    faces = np.concatenate([f + o for (_, f), o in zip(meshes, offsets)]).astype(np.int32)
    return World(vertices, faces, length, parts)


def car_mesh(scenes: Path) -> tuple[np.ndarray, np.ndarray]:
    """The teapot as a car: Z up, 4.5 m long along x, centred on the origin, on z = 0."""
    vertices, faces = _z_up(scenes, "teapot")
    scale = CAR_LENGTH / np.ptp(vertices[:, 0])
    return (vertices * scale).astype(np.float32), faces


def actor_transforms(k: int, frames: int, length: float, seed: int = 0) -> np.ndarray:
    """(frames, k, 4, 4) float64 rigid placements of the cars: car i in lane i % 4, at a seeded
    start and speed (8-15 m/s), moved ``FRAME_DT`` seconds a frame (around the street's ends),
    its yaw wobbling by up to 3 degrees."""
    rng = np.random.default_rng(seed + 1)
    lane = np.array(LANES_Y)[np.arange(k) % len(LANES_Y)]
    heading = np.where(lane > 0, np.pi, 0.0)
    start = rng.uniform(-length / 2, length / 2, k)
    speed = rng.uniform(8.0, 15.0, k)
    phase = rng.uniform(0, 2 * np.pi, k)
    out = np.tile(np.eye(4), (frames, k, 1, 1))
    for f in range(frames):
        travelled = speed * FRAME_DT * f * np.cos(heading)
        x = (start + travelled + length / 2) % length - length / 2
        yaw = heading + np.radians(3.0) * np.sin(phase + 0.3 * f)
        c, s = np.cos(yaw), np.sin(yaw)
        out[f, :, 0, 0], out[f, :, 0, 1], out[f, :, 1, 0], out[f, :, 1, 1] = c, -s, s, c
        out[f, :, 0, 3], out[f, :, 1, 3] = x, lane
    return out


def lidar_poses(n: int, frame: int, length: float) -> list[np.ndarray]:
    """The first ``n`` of 16 lidar poses (4x4 sensor-to-world) of a frame: near the centre line,
    ``LIDAR_HEIGHT`` up, spread along the street, each turned 22.5 degrees more than the one
    before, and moved ``LIDAR_STEP`` along x a frame."""
    poses = []
    for j in range(n):
        x = -0.4 * length + 0.8 * length * ((7 * j) % MAX_LIDARS) / (MAX_LIDARS - 1)
        yaw = np.radians(22.5 * j)
        pose = np.eye(4)
        pose[:2, :2] = [[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]]
        # off the ground grid's lines and the 45-degree diagonals through the buildings' corners:
        # a ray exactly along a shared edge is a hit for dacrt (watertight) and at times a miss
        # for Embree's (non-robust) test
        pose[:3, 3] = (x + LIDAR_STEP * frame + 0.37, 0.13, LIDAR_HEIGHT)
        poses.append(pose)
    return poses


def lidar_rays(poses: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """(origins, directions) float32 of the lidars one after another, each as the server makes
    a ``/lidar`` request's rays (``dacrt.sensors.lidar``)."""
    from dacrt.sensors import MODELS, make_scan

    elevations = MODELS[LIDAR_MODEL].vertical_angles_deg
    rays = [make_scan(pose, elevations, STEPS, 0.0, math.inf).rays() for pose in poses]
    return (np.concatenate([o for o, _ in rays]), np.concatenate([d for _, d in rays]))


# --- the engines ----------------------------------------------------------------------------------


def timed(call):
    """(result, ms) of call(), the collector run before and off during it."""
    gc.collect()
    gc.disable()
    try:
        start = time.perf_counter()
        result = call()
        return result, (time.perf_counter() - start) * 1e3
    finally:
        gc.enable()


class EmbreeAnchor:
    """The two-level anchor, one process a frame; the world and the car written once."""

    def __init__(self, binary: Path, world: World, car, threads: int):
        self.binary, self.threads = binary, threads
        self.folder = Path(tempfile.mkdtemp(prefix="world-embree-"))
        world.vertices.tofile(self.folder / "static_vertices.f32")
        world.faces.tofile(self.folder / "static_faces.i32")
        np.ascontiguousarray(car[0], np.float32).tofile(self.folder / "object_vertices.f32")
        np.ascontiguousarray(car[1], np.int32).tofile(self.folder / "object_faces.i32")
        (self.folder / "query.txt").write_text("closest")

    def frame(self, transforms: list[np.ndarray], rays: list[tuple[np.ndarray, np.ndarray]]):
        """{static, commit, trace: ms} and t of the last of the given frames (the ones before
        it run untimed, in the same process)."""
        k = transforms[0].shape[0]
        np.ascontiguousarray(np.stack(transforms)[:, :, :3, :], np.float32).tofile(
            self.folder / "transforms.f32"
        )
        table = []
        for origins, directions in rays:
            block = np.zeros((len(origins), 8), np.float32)
            block[:, :3], block[:, 3:6], block[:, 7] = origins, directions, np.inf
            table.append(block)
        np.concatenate(table).tofile(self.folder / "rays.f32")
        (self.folder / "frames.txt").write_text(f"{len(transforms)} {k}")
        out = subprocess.run(
            [str(self.binary), str(self.folder), str(self.threads)],
            capture_output=True,
            text=True,
            check=True,
        ).stdout.split("\n")
        static = float(out[0])
        commit, trace = (float(x) for x in out[len(transforms)].split())
        t = np.fromfile(self.folder / "t.f32", np.float32).reshape(len(transforms), -1)[-1]
        return {"static": static, "commit": commit, "trace": trace}, t

    def close(self):
        shutil.rmtree(self.folder, ignore_errors=True)


class InProcess:
    """dacrt in this process: a new Scene a frame, and (when the engine has it) the previous
    frame's scene ``with_changes``."""

    def __init__(self, dacrt, world: World, car, threads: int):
        self.dacrt, self.threads = dacrt, threads
        self.world, self.car = (world.vertices, world.faces), car
        self.previous = None  # the last scene with_changes made (or the first, fresh)
        self.has_changes = hasattr(dacrt.Scene, "with_changes")

    def fresh(self, matrices, origins, directions):
        k = len(matrices)
        scene, build = timed(
            lambda: self.dacrt.Scene(
                [self.world] + [self.car] * k, transforms=[None] + list(matrices)
            )
        )
        hits, trace = timed(lambda: scene.closest(origins, directions, threads=self.threads))
        if self.previous is None:
            self.previous = scene
        return {"scene": build, "trace": trace}, hits.t

    def changes(self, matrices, origins, directions):
        changes = {1 + i: m for i, m in enumerate(matrices)}
        scene, build = timed(lambda: self.previous.with_changes(transforms=changes))
        hits, trace = timed(lambda: scene.closest(origins, directions, threads=self.threads))
        self.previous = scene
        return {"scene": build, "trace": trace}, hits.t


class ThroughService:
    """A real server holding, in each service engine's scene (``SERVICE_SCENES``), the world,
    car00 and its K - 1 instances; given ``http`` (an httpx client of a running server), that
    server instead of a new one."""

    def __init__(self, world: World, car, k: int, threads: int, max_rays: int, http=None):
        import httpx

        from bench.http_overhead import start_server

        self.process = None
        if http is None:
            self.process, url = start_server(
                {
                    "DACRT_THREADS": str(threads),
                    "DACRT_MAX_RAYS_PER_REQUEST": str(max(max_rays, 1 << 24)),
                    "DACRT_LOAD_DEMO": "false",
                    "DACRT_LOG_LEVEL": "warning",
                }
            )
            http = httpx.Client(base_url=url, timeout=600)
        self.http = http
        self.k = k
        paths = self.http.get("/openapi.json").json()["paths"]
        self.has_rig = "/v1/scenes/{scene}/sensors" in paths
        self.rig_fields = True
        self.scenes = {e: s for e, s in SERVICE_SCENES.items() if self.has_rig or e == "service"}
        for scene in self.scenes.values():
            self.upload(scene, world, car)

    def upload(self, scene: str, world: World, car) -> None:
        """The world, car00 and its K - 1 instances into ``scene``."""
        self.put_npz(f"/v1/scenes/{scene}/meshes/world", vertices=world.vertices, faces=world.faces)
        self.put_npz(f"/v1/scenes/{scene}/meshes/car00", vertices=car[0], faces=car[1])
        for i in range(1, self.k):
            r = self.http.put(
                f"/v1/scenes/{scene}/meshes/car{i:02d}", json={"instance_of": "car00"}
            )
            r.raise_for_status()

    def put_npz(self, path, **arrays):
        body = io.BytesIO()
        np.savez(body, **arrays)
        r = self.http.put(
            path, content=body.getvalue(), headers={"Content-Type": "application/x-npz"}
        )
        r.raise_for_status()

    def post_frame(self, scene, matrices):
        body = io.BytesIO()
        np.savez(body, **{f"car{i:02d}.transform": m for i, m in enumerate(matrices)})
        r = self.http.post(
            f"/v1/scenes/{scene}/frame",
            content=body.getvalue(),
            headers={"Content-Type": "application/x-npz"},
        )
        r.raise_for_status()

    @staticmethod
    def lidar_body(pose):
        return {"pose": pose.tolist(), "model": LIDAR_MODEL, "horizontal_steps": STEPS}

    @staticmethod
    def t_of(archive, prefix=""):
        t = np.full(STEPS * 64, np.inf, np.float32)
        t[archive[prefix + "ray"]] = archive[prefix + "range"]
        return t

    def lidars(self, scene, poses):
        out = []
        for pose in poses:
            r = self.http.post(
                f"/v1/scenes/{scene}/lidar",
                json=self.lidar_body(pose),
                params={"fields": "ray,range"},
                headers={"Accept": "application/x-npz"},
            )
            r.raise_for_status()
            with np.load(io.BytesIO(r.content)) as archive:
                out.append(self.t_of(archive))
        return np.concatenate(out)

    def rig(self, scene, poses):
        body = {
            "sensors": {
                f"l{j:02d}": {"kind": "lidar", **self.lidar_body(p)} for j, p in enumerate(poses)
            }
        }
        params = {"fields": "ray,range"} if self.rig_fields else None
        r = self.http.post(
            f"/v1/scenes/{scene}/sensors",
            json=body,
            params=params,
            headers={"Accept": "application/x-npz"},
        )
        if r.status_code in (400, 422) and self.rig_fields:  # a rig without ?fields=
            self.rig_fields = False
            return self.rig(scene, poses)
        r.raise_for_status()
        with np.load(io.BytesIO(r.content)) as archive:
            return np.concatenate([self.t_of(archive, f"l{j:02d}.") for j in range(len(poses))])

    def frame(self, matrices, poses):
        scene = self.scenes["service"]
        _, frame = timed(lambda: self.post_frame(scene, matrices))
        t, sensors = timed(lambda: self.lidars(scene, poses))
        return {"frame": frame, "sensors": sensors}, t

    def rig_frame(self, matrices, poses):
        scene = self.scenes["service rig"]
        _, frame = timed(lambda: self.post_frame(scene, matrices))
        t, sensors = timed(lambda: self.rig(scene, poses))
        return {"frame": frame, "sensors": sensors}, t

    def close(self):
        """Stop the server this started (a client given to it stays open)."""
        if self.process is None:
            return
        self.http.close()
        self.process.terminate()
        self.process.wait(timeout=30)


# --- checks, tables, figure -----------------------------------------------------------------------


def agreement(ours: np.ndarray, embree: np.ndarray, diagonal: float) -> dict:
    """Hit/miss agreement, the share of rays agreeing (hit/miss and t within 1e-4 of the
    diagonal), and the worst relative t difference among the rays both hit."""
    same = np.isfinite(ours) == np.isfinite(embree)
    both = np.isfinite(ours) & np.isfinite(embree)
    close = same.copy()
    close[both] = np.abs(ours[both] - embree[both]) <= 1e-4 * diagonal
    relative = np.abs(ours[both] - embree[both]) / np.maximum(embree[both], 1e-30)
    return {
        "rays": int(len(ours)),
        "hit_miss_differ": int((~same).sum()),
        "agree": float(close.mean()),
        "max_rel_dt": float(relative.max()) if both.any() else 0.0,
        "hit_share": float(np.isfinite(embree).mean()),
    }


def median(values):
    return statistics.median(values) if values else math.nan


ENGINE_PARTS = {
    "embree": ("commit", "trace"),
    "embree dynamic": ("commit", "trace"),
    "dacrt": ("scene", "trace"),
    "dacrt changes": ("scene", "trace"),
    "service": ("frame", "sensors"),
    "service rig": ("frame", "sensors"),
}


#: The Embree engines: the anchor as given, and its copy that takes the rays in dynamic chunks.
ANCHORS = ("embree", "embree dynamic")


def summarise(counts: dict) -> dict:
    """Per lidar count and engine: median frame ms and the median of each part."""
    out = {}
    for n, record in counts.items():
        row = {}
        for engine, frames in record["frames"].items():
            parts = ENGINE_PARTS[engine]
            row[engine] = {
                "total": median([sum(f[p] for p in parts) for f in frames]),
                "best": min(sum(f[p] for p in parts) for f in frames),
                **{p: median([f[p] for f in frames]) for p in parts},
            }
            if engine in ANCHORS:
                row[engine]["static"] = median([f["static"] for f in frames])
        out[n] = row
    return out


def tables(result: dict) -> str:
    summary = summarise(result["counts"])
    engines = [e for e in ENGINE_PARTS if any(e in row for row in summary.values())]
    dynamic = "embree dynamic" in engines
    lines = [
        "| lidars | rays | "
        + " | ".join(_header(e, dynamic) for e in engines)
        + " | agree (dacrt vs Embree) |",
        "|---|---|" + "---|" * len(engines) + "---|",
    ]
    for n, row in summary.items():
        embree = row.get("embree", {}).get("total", math.nan)
        balanced = row.get("embree dynamic", {}).get("total", math.nan)
        cells = []
        for e in engines:
            r = row.get(e)
            if r is None:
                cells.append("—")
                continue
            a, b = ENGINE_PARTS[e]
            cell = f"{r['total']:.1f}, min {r['best']:.1f} ({a} {r[a]:.1f} + {b} {r[b]:.1f})"
            if e != "embree":
                cell += f": **{embree / r['total']:.2f}×**"
            if dynamic and e not in ANCHORS:
                cell += f", **{balanced / r['total']:.2f}×** dynamic"
            cells.append(cell)
        check = result["counts"][n]["checks"]
        agreed = "— (no Embree run)"
        if check:  # a run without embree has nothing to check against
            agree = min(c["agree"] for c in check)
            differ = max(c["hit_miss_differ"] for c in check)
            rel = max(c["max_rel_dt"] for c in check)
            agreed = f"{percent(agree)} (hit/miss differ ≤ {differ}, max |Δt|/t {rel:.1e})"
        lines.append(f"| {n} | {n * 64 * STEPS:,} | " + " | ".join(cells) + f" | {agreed} |")
    return "\n".join(lines)


def percent(share: float) -> str:
    """A share as a percentage to 4 decimals, never rounded up to 100."""
    text = f"{100 * share:.4f}"
    return ("99.9999" if share < 1 and text == "100.0000" else text) + "%"


def _header(engine, dynamic: bool = False):
    a, b = ENGINE_PARTS[engine]
    what = {
        "embree": "Embree two-level, ms",
        "embree dynamic": "Embree two-level, rays in dynamic chunks, ms",
        "dacrt": "dacrt new Scene, ms",
        "dacrt changes": "dacrt with_changes, ms",
        "service": "service (frame + one /lidar each), ms",
        "service rig": "service rig (frame + /sensors), ms",
    }[engine]
    ratios = ""
    if engine != "embree":
        ratios = ": Embree / it"
        if dynamic and engine not in ANCHORS:
            ratios += ", Embree dynamic / it"
        ratios += " (medians)"
    return f"{what}: median, min ({a} + {b}, medians){ratios}"


def ratios(summary: dict, anchor: str, engine: str) -> list[float]:
    """Per lidar count, ``anchor``'s median frame / ``engine``'s (NaN where either is missing)."""
    return [
        row[anchor]["total"] / row[engine]["total"] if engine in row and anchor in row else np.nan
        for row in summary.values()
    ]


def dotted(ax, x, y, label: str, style: dict) -> None:
    """A thin dotted line of an engine's ``style``: a part of its frame, or a second ratio."""
    ax.plot(
        x, y, label=label, linewidth=1, markersize=4, color=style["color"], linestyle=":",
        marker=style["marker"],
    )  # fmt: skip


def draw(result: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import FuncFormatter

    from bench.plots import DACRT_COLORS

    summary = summarise(result["counts"])
    counts = [int(n) for n in summary]
    styles = {
        "embree": {"color": "black", "linestyle": (0, (5, 2)), "marker": "s"},
        "embree dynamic": {"color": "dimgray", "linestyle": (0, (2, 2)), "marker": "s"},
        "dacrt": {"color": DACRT_COLORS[0], "linestyle": "-", "marker": "o"},
        "dacrt changes": {"color": DACRT_COLORS[1], "linestyle": "-", "marker": "D"},
        "service": {"color": DACRT_COLORS[2], "linestyle": "-.", "marker": "^"},
        "service rig": {"color": DACRT_COLORS[3], "linestyle": "-.", "marker": "v"},
    }
    fig, (left, right) = plt.subplots(1, 2, figsize=(13, 5.4), dpi=130)
    for engine, style in styles.items():
        if not any(engine in row for row in summary.values()):
            continue
        y = [row.get(engine, {}).get("total", np.nan) for row in summary.values()]
        left.plot(counts, y, label=engine, linewidth=2, markersize=6, **style)
        if engine in ("dacrt", "dacrt changes"):
            scene = [row.get(engine, {}).get("scene", np.nan) for row in summary.values()]
            dotted(left, counts, scene, f"{engine}: scene part", style)
        if engine != "embree":
            ratio = ratios(summary, "embree", engine)
            right.plot(counts, ratio, label=engine, linewidth=2, markersize=6, **style)
        if engine not in ANCHORS and any("embree dynamic" in row for row in summary.values()):
            ratio = ratios(summary, "embree dynamic", engine)
            dotted(right, counts, ratio, f"{engine}: against Embree dynamic", style)
    for ax in (left, right):
        ax.set_xscale("log", base=2)
        ax.set_xticks(counts, [str(n) for n in counts])
        ax.minorticks_off()
        ax.grid(True, alpha=0.35)
        ax.set_xlabel("lidars per frame")
    left.set_yscale("log")
    plain = FuncFormatter(lambda v, _: f"{v:g}")
    left.yaxis.set_major_formatter(plain)
    left.yaxis.set_minor_formatter(
        FuncFormatter(lambda v, _: f"{v:g}" if str(v)[0] in "25" else "")
    )
    left.set_ylabel("ms a frame (median)")
    left.set_title("Frame time", fontsize=12)
    right.axhline(1.0, color="gray", linewidth=1)
    right.set_ylabel("Embree frame / engine frame (above 1: faster than Embree)")
    right.set_title("Against Embree's two-level frame", fontsize=12)
    left.legend(fontsize=9, frameon=False)
    right.legend(fontsize=9, frameon=False)
    w = result["world"]
    fig.suptitle(
        f"World frames: {w['triangles'] / 1e6:.2f}M static triangles, {result['args']['actors']} "
        f"moving cars (teapot instances), {result['args']['threads']} threads; "
        f"{result['machine']['cpu']}, load {result['load'][0]:.1f}→{result['load'][1]:.1f}",
        fontsize=10,
    )
    fig.supxlabel(
        f"{LIDAR_MODEL} lidars, {64 * STEPS:,} rays each: one batch in process and for Embree, "
        "one /lidar request each through the service",
        fontsize=9,
    )
    fig.tight_layout()
    fig.savefig(path, bbox_inches="tight")
    plt.close(fig)


# --- main -----------------------------------------------------------------------------------------


def make_runners(anchors, in_process, service, transforms, rays_of, poses_of) -> dict:
    """{engine: run(frame) -> (times, t)} of one lidar count's frames; ``anchors`` is
    {engine: EmbreeAnchor}."""
    runners = {}
    for name, anchor in anchors.items():
        runners[name] = lambda f, anchor=anchor: anchor.frame(
            [transforms[max(f - 1, 0)], transforms[f]], [rays_of[max(f - 1, 0)], rays_of[f]]
        )
    if in_process:
        in_process.previous = None
        runners["dacrt"] = lambda f: in_process.fresh(transforms[f], *rays_of[f])
        if in_process.has_changes:
            runners["dacrt changes"] = lambda f: in_process.changes(transforms[f], *rays_of[f])
    if service:
        runners["service"] = lambda f: service.frame(transforms[f], poses_of[f])
        if service.has_rig:
            runners["service rig"] = lambda f: service.rig_frame(transforms[f], poses_of[f])
    return runners


def run_frames(runners: dict, n_frames: int, diagonal: float, in_process, label: str) -> dict:
    """The record of one lidar count: every engine's frames but the first (``frames``: {engine:
    [times]}), and the checks of every frame's answers."""
    record = {"frames": {}, "checks": [], "service_identical": True, "anchors_identical": True}
    names = list(runners)
    for f in range(n_frames):
        order = names[f % len(names) :] + names[: f % len(names)]
        answers = {}
        for name in order:
            if name == "dacrt changes" and in_process.previous is None:
                continue  # its first frame needs a scene to change: dacrt's comes first
            times, answers[name] = runners[name](f)
            if f:
                record["frames"].setdefault(name, []).append(times)
        if "embree" in answers and "dacrt" in answers:
            record["checks"].append(agreement(answers["dacrt"], answers["embree"], diagonal))
        if all(name in answers for name in ANCHORS):
            if not np.array_equal(answers["embree"], answers["embree dynamic"]):
                record["anchors_identical"] = False
                log(f"the two anchors' answers differ (frame {f}, {label})")
        for other in ("dacrt changes", "service", "service rig"):
            if other in answers and "dacrt" in answers:
                if not np.array_equal(answers[other], answers["dacrt"]):
                    record["service_identical"] = False
                    log(f"{other}'s answers differ from dacrt's (frame {f}, {label})")
    return record


def git_state(folder: Path = REPO) -> dict:
    """{commit, dirty} of the checkout the bench runs from: its HEAD and whether a tracked file
    differs from it (both None outside a git checkout)."""
    try:
        commit = subprocess.run(
            ["git", "-C", str(folder), "rev-parse", "HEAD"],
            capture_output=True,
            text=True,
            check=True,
        ).stdout.strip()
        changes = subprocess.run(
            ["git", "-C", str(folder), "status", "--porcelain", "--untracked-files=no"],
            capture_output=True,
            text=True,
            check=True,
        ).stdout
    except (OSError, subprocess.CalledProcessError):
        return {"commit": None, "dirty": None}
    return {"commit": commit, "dirty": bool(changes.strip())}


def int_list(text: str) -> list[int]:
    return [int(x) for x in text.split(",") if x]


def log(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=description(__doc__))
    parser.add_argument("--triangles", type=float, default=3.3e6, help="static triangles")
    parser.add_argument("--actors", type=int, default=40)
    parser.add_argument("--lidars", type=int_list, default=[1, 2, 4, 8, 16])
    parser.add_argument("--frames", type=int, default=5, help="timed frames per lidar count")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--engines",
        default="embree,embree-dynamic,dacrt,service",
        help="embree, embree-dynamic (the anchor, rays in dynamic chunks), dacrt, service",
    )
    parser.add_argument("--shared", type=Path, default=find_shared())
    parser.add_argument("--build-dir", type=Path, default=None, help="where the anchor goes")
    parser.add_argument("--out", type=Path, default=None, help="world.json, world.md, PNG")
    parser.add_argument("--quick", action="store_true", help="0.5M, 1 and 4 lidars, 3 frames")
    parser.add_argument("--replot", type=Path, default=None, help="redraw from a world.json")
    args = parser.parse_args(argv)
    if args.replot:
        result = json.loads(args.replot.read_text())
        result["counts"] = {int(n): record for n, record in result["counts"].items()}
        draw(result, args.replot.with_name("world-frames.png"))
        print(report(result))
        return 0
    if args.quick:
        args.triangles, args.lidars, args.frames = 5e5, [1, 4], 3
    if args.shared is None:
        parser.error("no shared folder found (../shared beside the repository): give --shared")
    if not 1 <= max(args.lidars) <= MAX_LIDARS or args.frames < 1:
        parser.error(f"--lidars between 1 and {MAX_LIDARS}, --frames at least 1")
    engines = set(args.engines.split(","))
    scenes = args.shared / "scenes"

    from bench.measure import machine_info
    from bench.native_embree import BUILD_DIR, AnchorUnavailable, build_anchor

    load_start = os.getloadavg()[0]
    started = time.perf_counter()
    code = git_state()  # before --out writes anything into the checkout
    world = build_world(scenes, int(args.triangles), args.seed)
    car = car_mesh(scenes)
    n_frames = args.frames + 1  # frame 0: the warm-up
    transforms = actor_transforms(args.actors, n_frames, world.length, args.seed)
    log(
        f"world: {len(world.faces):,} triangles {world.parts}, street {world.length:.0f} m, "
        f"car {len(car[1]):,} triangles x {args.actors}"
    )

    missing = {}
    anchors = {}
    service = in_process = None
    sources = {
        "embree": args.shared / "anchors" / "embree_instances.cpp",
        "embree dynamic": DYNAMIC_ANCHOR,
    }
    for name, source in sources.items():
        if name.replace(" ", "-") not in engines:
            continue
        try:
            binary = build_anchor(source, args.build_dir or BUILD_DIR)
            anchors[name] = EmbreeAnchor(binary, world, car, args.threads)
        except AnchorUnavailable as exc:
            missing[name] = str(exc)
            log(f"{name}: left out: {exc}")
    if "dacrt" in engines or "service" in engines:
        import dacrt

        use_kernel_cache()
        log("dacrt.warmup() ...")
        dacrt.warmup()
    if "dacrt" in engines:
        in_process = InProcess(dacrt, world, car, args.threads)
        if not in_process.has_changes:
            missing["dacrt changes"] = "dacrt.Scene has no with_changes"
    if "service" in engines:
        log("starting the server and uploading the world ...")
        service = ThroughService(world, car, args.actors, args.threads, MAX_LIDARS * 64 * STEPS)
        if not service.has_rig:
            missing["service rig"] = "the server has no POST /v1/scenes/{scene}/sensors"
    log(f"ready after {time.perf_counter() - started:.0f} s; missing: {missing or 'none'}")

    counts = {}
    try:
        for n in args.lidars:
            rays_of = [lidar_rays(lidar_poses(n, f, world.length)) for f in range(n_frames)]
            poses_of = [lidar_poses(n, f, world.length) for f in range(n_frames)]
            runners = make_runners(anchors, in_process, service, transforms, rays_of, poses_of)
            record = run_frames(runners, n_frames, world.diagonal, in_process, f"{n} lidars")
            counts[n] = record
            summary = summarise({n: record})[n]
            log(f"{n} lidars: " + ", ".join(f"{e} {r['total']:.1f} ms" for e, r in summary.items()))
    finally:
        for anchor in anchors.values():
            anchor.close()
        if service:
            service.close()

    machine = machine_info()
    result = {
        "args": {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()},
        "machine": {"cpu": machine["cpu_model"], **machine},
        "load": [load_start, os.getloadavg()[0]],
        "seconds": time.perf_counter() - started,
        "git": code,
        "world": {
            "triangles": int(len(world.faces)),
            "parts": world.parts,
            "street_m": world.length,
            "car_triangles": int(len(car[1])),
        },
        "missing": missing,
        "counts": counts,
    }
    text = report(result)
    print(text)
    if args.out:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "world.json").write_text(json.dumps(result, indent=1, default=float))
        (args.out / "world.md").write_text(text + "\n")
        draw(json.loads((args.out / "world.json").read_text()), args.out / "world-frames.png")
    return 0


def report(result: dict) -> str:
    w, a = result["world"], result["args"]
    summary = summarise(result["counts"])
    static = [row["embree"]["static"] for row in summary.values() if "embree" in row]
    parts = ", ".join(f"{k} {v:,}" for k, v in w["parts"].items())
    lines = [
        f"World: {w['triangles']:,} static triangles ({parts}), street {w['street_m']:.0f} m; "
        f"{a['actors']} cars (teapot, {w['car_triangles']:,} triangles) moved every frame; "
        f"{a['threads']} threads; medians of {a['frames']} frames after a warm-up.",
        f"Code: {describe_code(result.get('git'))}.",
        f"Machine: {result['machine']['cpu']}, {result['machine'].get('logical_cores', '?')} "
        f"cores; load average {result['load'][0]:.2f} at the start, {result['load'][1]:.2f} at "
        "the end; "
        f"{result['seconds']:.0f} s in all.",
        f"Embree's one-time build of the world and the car (not in its frames): "
        f"{median(static):.0f} ms (median)."
        if static
        else "Embree: left out.",
        f"Left out: {result['missing']}." if result["missing"] else "",
        "",
        tables(result),
        "",
        "Answers of the service (and of with_changes) identical to dacrt's in process: "
        + ", ".join(
            f"{n} lidars {'yes' if r['service_identical'] else 'NO'}"
            for n, r in result["counts"].items()
        ),
    ]
    if any("embree dynamic" in row and "embree" in row for row in summary.values()):
        lines.append(
            "Answers of Embree dynamic identical to Embree's: "
            + ", ".join(
                f"{n} lidars {'yes' if r.get('anchors_identical', True) else 'NO'}"
                for n, r in result["counts"].items()
            )
        )
    return "\n".join(line for line in lines if line is not None)


def describe_code(code: dict | None) -> str:
    """``commit abc1234`` (``, with uncommitted changes``) of a result's ``git``."""
    if not code or not code.get("commit"):
        return "commit unknown"
    dirty = ", with uncommitted changes" if code["dirty"] else ""
    return f"commit {code['commit'][:7]}{dirty}"


if __name__ == "__main__":
    raise SystemExit(main())
