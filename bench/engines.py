"""One adapter per engine, all with the same four steps, so the runner can time them alike.

    engine.build(vertices, faces) -> handle   per-frame work: a new scene from (V,3) f32, (F,3) i32
    engine.commit(handle)                     finish lazy construction (Embree, Open3D build their
                                              BVH on first use); part of the build time
    engine.convert(rays) -> payload           the engine's input format (untimed)
    engine.trace(handle, payload, rays) -> TraceResult

An engine that is not importable is reported by ``available_engines`` with the reason, and left out.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bench.rays import CLOSEST, RaySet
from oracles.embree import Embree


@dataclass
class TraceResult:
    """What a trace returns, normalised across engines.

    query : str                 "closest" or "occluded"
    t : (n,) float32 | None     closest hit distance, inf on a miss (closest only)
    prim : (n,) int32 | None    triangle index, -1 on a miss (closest only)
    occluded : (n,) bool | None any hit in [0, tmax] (occluded only)
    stats : dict | None         dacrt counters when asked for
    """

    query: str
    t: np.ndarray | None = None
    prim: np.ndarray | None = None
    occluded: np.ndarray | None = None
    stats: dict | None = None

    @property
    def hit(self) -> np.ndarray:
        return self.occluded if self.query != CLOSEST else np.isfinite(self.t)


class DacrtEngine:
    """dacrt with one strategy and thread count; there is no acceleration structure to keep."""

    family = "dacrt"

    def __init__(self, dacrt_module, strategy: str, threads: int):
        self.dacrt = dacrt_module
        self.strategy = strategy
        self.threads = threads
        self.name = strategy

    def build(self, vertices, faces):
        return self.dacrt.Scene([(vertices, faces)])

    def commit(self, handle):
        pass

    def convert(self, rays: RaySet):
        return rays.origins, rays.directions

    def trace(self, handle, payload, rays: RaySet, stats: bool = False) -> TraceResult:
        origins, directions = payload
        tmax = None if np.isinf(rays.tmax) else rays.tmax
        if rays.query == CLOSEST:
            hits = handle.closest(
                origins,
                directions,
                tmin=None,
                tmax=tmax,
                strategy=self.strategy,
                threads=self.threads,
                stats=stats,
            )
            return TraceResult(CLOSEST, t=hits.t, prim=hits.prim, stats=hits.stats)
        occlusion = handle.occluded(
            origins,
            directions,
            tmin=None,
            tmax=tmax,
            strategy=self.strategy,
            threads=self.threads,
            stats=stats,
        )
        return TraceResult(rays.query, occluded=occlusion.occluded, stats=occlusion.stats)


class EmbreeEngine:
    """Embree through embreex (``oracles.embree``): ``run`` traces one ray at a time on one thread.

    The scene is built from (F, 3, 3) float32 triangles; gathering them from (V, F) is part of the
    build. Embree's BVH build (on commit) uses its own thread pool on every core; embreex gives
    no way to limit it.
    """

    family = "embree"
    name = "embree"
    threads = 1

    def __init__(self):
        import embreex  # noqa: F401  (raises here when embreex is missing)

    def build(self, vertices, faces):
        return Embree([(vertices, faces)])

    def commit(self, handle):
        handle.commit()

    def convert(self, rays: RaySet):
        return rays.origins, rays.directions, rays.tmax

    def trace(self, handle, payload, rays: RaySet, stats: bool = False) -> TraceResult:
        origins, directions, tmax = payload
        if rays.query == CLOSEST:
            t, prim = handle.closest_t(origins, directions, tmax)
            return TraceResult(CLOSEST, t=t, prim=prim)
        return TraceResult(rays.query, occluded=handle.occluded(origins, directions, tmax=tmax))


class Open3DEngine:
    """Open3D's RaycastingScene (Embree inside), with ``nthreads`` for both the build and the
    trace."""

    family = "open3d"

    def __init__(self, threads: int):
        import open3d

        self.o3d = open3d
        self.threads = threads
        self.name = "open3d"

    def build(self, vertices, faces):
        core = self.o3d.core
        scene = self.o3d.t.geometry.RaycastingScene(nthreads=self.threads)
        scene.add_triangles(
            core.Tensor(np.ascontiguousarray(vertices, dtype=np.float32)),
            core.Tensor(np.ascontiguousarray(faces, dtype=np.uint32)),
        )
        return scene

    def commit(self, handle):
        one_ray = self.o3d.core.Tensor(np.array([[0, 0, 0, 1, 0, 0]], dtype=np.float32))
        handle.cast_rays(one_ray, nthreads=self.threads)  # builds the BVH on first use

    def convert(self, rays: RaySet):
        return self.o3d.core.Tensor(
            np.ascontiguousarray(np.hstack([rays.origins, rays.directions]))
        )

    def trace(self, handle, payload, rays: RaySet, stats: bool = False) -> TraceResult:
        if rays.query == CLOSEST:
            out = handle.cast_rays(payload, nthreads=self.threads)
            t = out["t_hit"].numpy().astype(np.float32, copy=False)
            prim = out["primitive_ids"].numpy().view(np.int32)  # INVALID_ID = 2**32-1 -> -1
            if np.isfinite(rays.tmax):  # cast_rays has no tfar
                far = t > rays.tmax
                t, prim = np.where(far, np.float32(np.inf), t), np.where(far, -1, prim)
            return TraceResult(CLOSEST, t=t, prim=prim)
        occ = handle.test_occlusions(
            payload, tnear=0.0, tfar=float(rays.tmax), nthreads=self.threads
        )
        return TraceResult(rays.query, occluded=occ.numpy().astype(bool, copy=False))


def import_dacrt():
    """The dacrt module, or the reason it cannot be used."""
    try:
        import dacrt

        _ = dacrt.Scene, dacrt.STRATEGIES, dacrt.warmup
        return dacrt, None
    except Exception as exc:  # still being written, or broken: leave it out
        return None, f"{type(exc).__name__}: {exc}"


def comma_list(text: str) -> tuple[str, ...]:
    return tuple(item for item in text.split(",") if item)


def add_engine_arguments(parser, families: tuple[str, ...] = ("dacrt", "embree", "open3d")) -> None:
    """--engines, --strategies and --seed, as bench.run and bench.plots both take them; --engines
    chooses among ``families`` (all by default)."""
    parser.add_argument(
        "--engines",
        type=comma_list,
        default=",".join(families),
        help=f"comma list of {','.join(families)}",
    )
    parser.add_argument(
        "--strategies",
        type=comma_list,
        default=None,
        help="dacrt strategies (default: all of dacrt.STRATEGIES)",
    )
    parser.add_argument("--seed", type=int, default=1)


def available_engines(
    threads: list[int], strategies: list[str] | None = None, want=("dacrt", "embree", "open3d")
):
    """(engines, dacrt module or None, {family: reason unavailable}) for the requested families.

    Engines are ordered dacrt strategies (each thread count), Embree, Open3D (each thread count).
    """
    engines, missing, dacrt = [], {}, None
    if "dacrt" in want:
        dacrt, reason = import_dacrt()
        if dacrt is None:
            missing["dacrt"] = reason
        else:
            names = strategies or list(dacrt.STRATEGIES)
            unknown = [s for s in names if s not in dacrt.STRATEGIES]
            if unknown:
                raise SystemExit(
                    f"unknown dacrt strategies {unknown}; dacrt.STRATEGIES = {dacrt.STRATEGIES}"
                )
            engines += [DacrtEngine(dacrt, s, t) for t in threads for s in names]
    if "embree" in want:
        try:
            engines.append(EmbreeEngine())
        except Exception as exc:
            missing["embree"] = f"{type(exc).__name__}: {exc}"
    if "open3d" in want:
        try:
            engines += [Open3DEngine(t) for t in threads]
        except Exception as exc:
            missing["open3d"] = f"{type(exc).__name__}: {exc}"
    return engines, dacrt, missing
