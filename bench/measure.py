"""Timing, agreement, memory and machine description: the measuring half of the runner."""

from __future__ import annotations

import gc
import os
import platform
import resource
import time
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context

import numpy as np

from bench.engines import TraceResult
from bench.rays import CLOSEST, RaySet

# --- time -----------------------------------------------------------------------------------------


def timed(fn, *args):
    """(seconds, result) of one call, with a collected heap and the collector off meanwhile."""
    gc.collect()
    gc.disable()
    try:
        start = time.perf_counter()
        out = fn(*args)
        return time.perf_counter() - start, out
    finally:
        gc.enable()


def build_and_trace(engine, vertices, faces, payload, rays: RaySet):
    """Per-frame cost: (build seconds, trace seconds, result) for a new scene plus the trace."""
    gc.collect()
    gc.disable()
    try:
        start = time.perf_counter()
        handle = engine.build(vertices, faces)
        engine.commit(handle)
        built = time.perf_counter()
        result = engine.trace(handle, payload, rays)
        done = time.perf_counter()
    finally:
        gc.enable()
    del handle
    return built - start, done - built, result


def median(values) -> float | None:
    values = [v for v in values if v is not None]
    return float(np.median(values)) if values else None


def mrays(n_rays: int, seconds: float | None) -> float | None:
    return None if not seconds else n_rays / seconds / 1e6


# --- agreement ----------------------------------------------------------------------------------


def agreement(result: TraceResult, reference: TraceResult, t_tol: float) -> dict:
    """Fractions of rays on which ``result`` agrees with ``reference`` (Embree).

    hit : same hit/miss (same occluded flag for occlusion queries)
    t :   of the rays both hit, |t - t_ref| <= t_tol   (closest only)
    prim: of the rays both hit, same triangle          (closest only)
    """
    hit, ref_hit = result.hit, reference.hit
    out = {
        "hit": float(np.mean(hit == ref_hit)) if len(hit) else 1.0,
        "n_hit_mismatch": int(np.count_nonzero(hit != ref_hit)),
    }
    if result.query == CLOSEST:
        both = hit & ref_hit
        n_both = int(np.count_nonzero(both))
        dt = np.abs(result.t[both].astype(np.float64) - reference.t[both].astype(np.float64))
        t_ok = dt <= t_tol
        same_prim = result.prim[both] == reference.prim[both]
        out["t"] = float(np.mean(t_ok)) if n_both else 1.0
        out["prim"] = float(np.mean(same_prim)) if n_both else 1.0
        out["n_both_hit"] = n_both
        out["n_t_mismatch"] = int(n_both - np.count_nonzero(t_ok))
        out["n_prim_mismatch"] = int(n_both - np.count_nonzero(same_prim))
        out["max_abs_dt"] = float(dt.max()) if n_both else 0.0
    return out


# --- memory ---------------------------------------------------------------------------------------


def peak_rss_bytes() -> int:
    """Peak resident set size of this process so far.

    Linux's VmHWM where there is one, else getrusage's ru_maxrss (KiB on Linux). They agree, except
    in a process started by fork + exec (our spawned children): ru_maxrss also keeps the forking
    parent's peak, which would charge the parent's 300 MB to a child.
    """
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


def current_rss_bytes() -> int:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


def reset_peak_rss() -> bool:
    """Start a new peak: Linux resets the RSS high-water mark (which getrusage reports) on "5"."""
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False


def _memory_child(spec: dict, mesh_path: str, rays_path: str, kernels_in: str | None) -> dict:
    """In a fresh process: peak RSS of one build + trace above the process with its inputs
    loaded; dacrt's kernels loaded from ``kernels_in`` (``bench.entry.use_kernel_cache``)."""
    from bench.engines import DacrtEngine, EmbreeEngine, Open3DEngine, import_dacrt
    from bench.entry import use_kernel_cache

    kernels = {}
    if spec["family"] == "dacrt":
        dacrt, reason = import_dacrt()
        if dacrt is None:
            raise RuntimeError(reason)
        kernels["kernel_cache"] = str(use_kernel_cache(kernels_in))
        dacrt.warmup()
        engine = DacrtEngine(dacrt, spec["strategy"], spec["threads"])
    elif spec["family"] == "embree":
        engine = EmbreeEngine()
    else:
        engine = Open3DEngine(spec["threads"])
    with np.load(mesh_path) as z:
        vertices, faces = z["vertices"], z["faces"]
    with np.load(rays_path) as z:
        rays = RaySet(spec["kind"], spec["query"], z["origins"], z["directions"], spec["tmax"])
    payload = engine.convert(rays)
    warm = engine.build(vertices, faces)  # one small warm-up trace, as in the timed runs
    engine.commit(warm)
    small = RaySet(
        rays.kind, rays.query, rays.origins[:256].copy(), rays.directions[:256].copy(), rays.tmax
    )
    engine.trace(warm, engine.convert(small), small)
    del warm, small
    gc.collect()
    was_reset = reset_peak_rss()
    idle, peak_before = current_rss_bytes(), peak_rss_bytes()
    handle = engine.build(vertices, faces)
    engine.commit(handle)
    peak_built = peak_rss_bytes()
    engine.trace(handle, payload, rays)
    peak_after = peak_rss_bytes()
    if spec["family"] == "dacrt":
        from dacrt import compiling

        kernels["kernels_compiled"] = compiling.compiled_kernels()  # 0 where the cache held them
    return {
        **kernels,
        "idle_rss": idle,
        "peak_before": peak_before,
        "peak_after": peak_after,
        "above_idle": peak_after - idle,
        "build_above_idle": peak_built - idle,
        "peak_was_reset": was_reset,
        # without a reset, a peak the trace did not raise makes above_idle only an upper bound
        "upper_bound_only": (not was_reset) and peak_after <= peak_before,
    }


def measure_memory(specs: list[dict], mesh_path: str, rays_paths: dict[str, str]) -> list[dict]:
    """Run ``_memory_child`` for each spec, each in a new spawned process (so peaks do not mix)
    that loads dacrt's kernels from this process's folder (``bench.entry.kernel_cache``)."""
    from bench.entry import kernel_cache

    folder = kernel_cache()
    kernels_in = None if folder is None else str(folder)
    results = []
    for spec in specs:
        with ProcessPoolExecutor(max_workers=1, mp_context=get_context("spawn")) as pool:
            try:
                rays_path = rays_paths[spec["kind"]]
                out = pool.submit(_memory_child, spec, mesh_path, rays_path, kernels_in).result()
            except Exception as exc:
                out = {"error": f"{type(exc).__name__}: {exc}"}
        results.append({**spec, **out})
    return results


# --- machine --------------------------------------------------------------------------------------


def machine_info() -> dict:
    """CPU model, logical and physical cores, usable cores, memory, library versions."""
    model, physical, sockets = platform.processor() or "unknown", set(), set()
    try:
        with open("/proc/cpuinfo") as f:
            block = {}
            for line in list(f) + ["\n"]:
                if not line.strip():
                    if block:
                        model = block.get("model name", model)
                        physical.add((block.get("physical id"), block.get("core id")))
                        sockets.add(block.get("physical id"))
                    block = {}
                    continue
                key, _, value = line.partition(":")
                block[key.strip()] = value.strip()
    except OSError:
        pass
    mem_total = None
    try:
        with open("/proc/meminfo") as f:
            total = next(row for row in f if row.startswith("MemTotal"))
            mem_total = int(total.split()[1]) * 1024
    except (OSError, StopIteration):
        pass
    versions = {}
    for module in ("numpy", "numba", "embreex", "open3d", "dacrt"):
        try:
            versions[module] = getattr(__import__(module), "__version__", "?")
        except Exception:
            versions[module] = None
    return {
        "cpu_model": model,
        "logical_cores": os.cpu_count(),
        "physical_cores": len(physical) if physical and None not in next(iter(physical)) else None,
        "sockets": len(sockets) if sockets and None not in sockets else None,
        "usable_cores": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None,
        "memory_bytes": mem_total,
        "python": platform.python_version(),
        "platform": platform.platform(),
        "versions": versions,
    }
