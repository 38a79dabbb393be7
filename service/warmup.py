"""The service's warm-up: compile every kernel a request can reach before /health says ok.

``dacrt.warmup`` compiles the engine's queries for the arrays it makes itself; a request's arrays
come from a body (read-only views, strided columns, JSON lists), which are other Numba
signatures. So the warm-up then sends tiny bodies of every format through the functions the
routes call (``wire`` decoders, a private ``Store``, ``tracing``, the answer encoders). It logs
whether it loads the kernels from the cache or compiles them, every PROGRESS_SECONDS how many
have compiled and about how long is left, and each group's time.
"""

from __future__ import annotations

import io
import itertools
import json
import logging
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager

import numpy as np

import dacrt.cache
from dacrt import compiling

from . import tracing, wire
from .store import Store

log = logging.getLogger("service")

#: Seconds between progress lines while the kernels compile or load.
PROGRESS_SECONDS = 15.0
#: Kernels a warm-up compiles from an empty cache (``compiling.compiled_kernels()``, counted on
#: the point queries' commit): the "of about N" of the progress lines and their time left.
EXPECTED_COMPILES = 42
#: What a first start takes, measured from an empty cache (README, First start).
COLD_START = "about a minute on 2 idle cores, up to 15 on 2 cores busy with other work"

VERTICES = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], np.float32)
FACES = np.array([[0, 1, 2], [0, 2, 3]], np.int32)
RAYS = np.array(
    [[0.25, 0.5, 1, 0, 0, -1, 0, 10], [5, 5, 1, 0, 0, -1, 0, 10]], np.float32
)  #: a hit and a miss, with tmin and tmax


class Progress:
    """The warm-up's progress: the group under way and the kernels compiled since ``start``."""

    def __init__(self) -> None:
        self.start = time.perf_counter()
        self.first_count = compiling.compiled_kernels()
        self.group = ""

    @property
    def compiled(self) -> int:
        return compiling.compiled_kernels() - self.first_count

    def line(self) -> str:
        """One progress line: counts and time, never the same twice."""
        elapsed = time.perf_counter() - self.start
        compiled = self.compiled
        if not compiled:
            return f"warm-up: loading {self.group} from the cache ({elapsed:.0f} s)"
        kernel = compiling.latest_kernel()
        if compiled >= EXPECTED_COMPILES:
            return f"warm-up: compiling kernel {compiled} ({kernel}), {elapsed:.0f} s so far"
        # Kernels differ tenfold in compile time: a rate means something after a quarter of them.
        left = (
            f", ~{elapsed / compiled * (EXPECTED_COMPILES - compiled):.0f} s left"
            if compiled >= EXPECTED_COMPILES / 4
            else ""
        )
        return (
            f"warm-up: compiling kernel {compiled} of about {EXPECTED_COMPILES} ({kernel}), "
            f"{elapsed:.0f} s so far{left}"
        )

    @contextmanager
    def step(self, group: str) -> Iterator[None]:
        """Run one group of kernels, and log its time and compiles."""
        start, compiled, self.group = time.perf_counter(), self.compiled, group
        yield
        log.info(
            "warm-up: %s ready after %.1f s (%d kernels compiled)",
            group,
            time.perf_counter() - start,
            self.compiled - compiled,
        )

    @contextmanager
    def reporting(self) -> Iterator[None]:
        """A progress line every PROGRESS_SECONDS until the block ends."""
        done = threading.Event()

        def report() -> None:
            while not done.wait(PROGRESS_SECONDS):
                log.info("%s", self.line())

        threading.Thread(target=report, name="dacrt-warmup-progress", daemon=True).start()
        try:
            yield
        finally:
            done.set()


def announce() -> None:
    """Say whether the kernels load from the cache or compile, and where they go."""
    if dacrt.cache.cache_dir() is None:
        log.info("warm-up: kernels go where Numba puts them (dacrt.cache.use_cache_dir not called)")
        return
    folder = dacrt.cache.kernels_folder(dacrt.cache.cache_dir())
    if folder.is_dir() and any(folder.rglob("*.nbi")):
        log.info(
            "warm-up: loading the compiled kernels from %s (seconds; those of another CPU "
            "compile again)",
            folder,
        )
    else:
        log.info(
            "warm-up: compiling the engine's kernels for this CPU into %s, once: about %d "
            "kernels, %s",
            folder,
            EXPECTED_COMPILES,
            COLD_START,
        )


def warm_up(threads: int | None = None) -> float:
    """Compile (or load from Numba's cache: ``dacrt.cache``) every kernel; answers the seconds
    taken."""
    announce()
    progress = Progress()
    with compiling.warming_up(), progress.reporting():
        with progress.step("the engine's kernels (dacrt.warmup)"):
            tracing.warmup()
        with progress.step("mesh uploads, vertex updates and frames"):
            store = warm_up_meshes()
        with progress.step("queries on every ray format"):
            warm_up_queries(store, threads)
        with progress.step("point queries on every point format"):
            warm_up_points(store, threads)
    return time.perf_counter() - progress.start


def body(data: bytes) -> memoryview:
    """A read-only body, as a request's."""
    return memoryview(data).toreadonly()


def npy(array: np.ndarray) -> memoryview:
    out = io.BytesIO()
    np.save(out, array, allow_pickle=False)
    return body(out.getvalue())


def npz(**arrays: np.ndarray) -> memoryview:
    out = io.BytesIO()
    np.savez(out, **arrays)
    return body(out.getvalue())


def as_json(**values: object) -> memoryview:
    listed = {k: v.tolist() if isinstance(v, np.ndarray) else v for k, v in values.items()}
    return body(json.dumps(listed).encode())


def mesh_files() -> dict[str, bytes]:
    """The quad as every mesh file format the service reads."""
    import trimesh  # slow to import, as in ``wire.meshfile``

    quad = trimesh.Trimesh(VERTICES, FACES, process=False)
    files = {fmt: quad.export(file_type=fmt) for fmt in ("ply", "stl", "glb")}
    files["obj"] = b"v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n"
    files["off"] = b"OFF\n4 1 0\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n4 0 1 2 3\n"
    return {fmt: data if isinstance(data, bytes) else data.encode() for fmt, data in files.items()}


def warm_up_meshes() -> Store:
    """Every mesh body format into a private store, a vertex update of each format and a frame."""
    store = Store(2**20, 2**30)
    bodies = {
        "npz": npz(vertices=VERTICES, faces=FACES),
        "json": as_json(vertices=VERTICES, faces=FACES),
    }
    bodies.update({fmt: body(data) for fmt, data in mesh_files().items()})
    for fmt, data in bodies.items():
        store.put_mesh("warm-up", fmt, wire.decode_mesh(data, fmt))
    moved = VERTICES + np.float32(0.5)
    vertex_bodies = {"npy": npy(moved), "npz": npz(vertices=moved), "json": as_json(vertices=moved)}
    for fmt, data in vertex_bodies.items():
        store.update_vertices("warm-up", "npz", wire.decode_vertices(data, fmt))
    frames = {
        "npz": npz(**{"npz.vertices": VERTICES, "new.vertices": VERTICES, "new.faces": FACES}),
        "json": as_json(
            **{"json.vertices": VERTICES, "new.vertices": VERTICES, "new.faces": FACES}
        ),
    }
    for fmt, data in frames.items():
        store.apply_frame("warm-up", wire.decode_frame(data, fmt))
    return store


def warm_up_queries(store: Store, threads: int | None) -> None:
    """closest and occluded with every strategy, culling mode and with and without statistics on
    rays of every format, and the one-shot trace."""
    origins, directions, tmin, tmax = RAYS[:, 0:3], RAYS[:, 3:6], RAYS[:, 6], RAYS[:, 7]
    ray_bodies = {
        "npy": [npy(RAYS[:, :6]), npy(RAYS)],
        "npz": [npz(origins=origins, directions=directions, tmin=tmin, tmax=tmax)],
        "json": [
            as_json(origins=origins, directions=directions),
            as_json(origins=origins, directions=directions, tmin=0.0, tmax=tmax),
        ],
    }
    snapshot = store.snapshot("warm-up")
    for fmt, bodies in ray_bodies.items():
        for data in bodies:
            rays = wire.decode_rays(data, fmt)
            for query, strategy, cull, stats in itertools.product(
                tracing.Query, tracing.strategies(), tracing.CULL_MODES, (False, True)
            ):
                options = tracing.make_options(
                    query, strategy=strategy, stats=stats, threads=threads, cull=cull
                )
                encode(tracing.trace(snapshot, rays, options).arrays, options.answer_formats)
    trace_bodies = {
        "npz": npz(vertices=VERTICES, faces=FACES, origins=origins, directions=directions),
        "json": as_json(vertices=VERTICES, faces=FACES, origins=origins, directions=directions),
    }
    for fmt, data in trace_bodies.items():
        mesh, rays = wire.decode_trace(data, fmt)
        for query in tracing.Query:
            options = tracing.make_options(query, threads=threads)
            encode(tracing.trace_once(mesh, rays, options).arrays, options.answer_formats)


def warm_up_points(store: Store, threads: int | None) -> None:
    """/nearest with and without the sign, on points of every format (an .npy body's points
    are a read-only view, which the kernels are compiled for apart)."""
    points = RAYS[:, 0:3]
    point_bodies = {"npy": npy(points), "npz": npz(points=points), "json": as_json(points=points)}
    snapshot = store.snapshot("warm-up")
    for fmt, data in point_bodies.items():
        for sign in (False, True):
            options = tracing.point_options(None, sign, 1, None, False, threads)
            encode(tracing.nearest(snapshot, wire.decode_points(data, fmt), options).arrays)


def encode(
    arrays: dict[str, np.ndarray],
    formats: tuple[str, ...] = wire.ANSWER_FORMATS,
    consume: Callable[[object], object] = bytes,
) -> None:
    """Each answer format of ``formats``, sent nowhere."""
    for fmt in formats:
        parts, _, _ = wire.encode_answer(arrays, fmt)
        for part in parts:
            consume(part)


def main() -> None:
    """``python -m service.warmup``: compile (or load) every kernel a request reaches into
    DACRT_CACHE_DIR, then exit; a container build runs it so that the server starts in seconds."""
    from .logs import configure_logging

    configure_logging("info")
    dacrt.cache.use_cache_dir()
    seconds = warm_up()
    log.info("warm-up: every kernel ready after %.1f s", seconds)


if __name__ == "__main__":
    main()
