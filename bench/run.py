"""Benchmark runner: dacrt strategies side by side with Embree and Open3D on one scene.

    python -m bench.run SCENE_PATH [--rays 1000000] [--kinds primary,shadow,ao,diffuse,random]
                        [--threads 1,2] [--repeat 5] [--out results.json]
    python -m bench.run SCENE_PATH --resolutions 512,1024,2048  # the paper's ray-sampling ablation

Markdown tables go to stdout, progress to stderr, every figure to the JSON file (--out).
See bench/README.md for what each column means.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
import traceback
from pathlib import Path

import numpy as np

from bench import rays as R
from bench.engines import add_engine_arguments, available_engines
from bench.entry import description, use_kernel_cache
from bench.measure import (
    agreement,
    build_and_trace,
    current_rss_bytes,
    machine_info,
    measure_memory,
    median,
    mrays,
    peak_rss_bytes,
    timed,
)
from bench.report import render
from bench.scene_io import load_mesh, load_view, mesh_bounds
from oracles.embree import Embree

KINDS = ("primary", "shadow", "ao", "diffuse", "random")
# fixed per-kind seed offsets, so adding a kind to --kinds changes no other kind's rays
KIND_SEED = {"primary": 0, "shadow": 1, "ao": 2, "diffuse": 3, "random": 4}
WARMUP_RAYS = 4096


def log(*parts):
    print("[bench]", *parts, file=sys.stderr, flush=True)


def int_list(text: str) -> list[int]:
    return [int(v) for v in text.split(",") if v.strip()]


def parse_args(argv=None):
    usable = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    p = argparse.ArgumentParser(prog="python -m bench.run", description=description(__doc__))
    p.add_argument("scene", help=".npz with vertices/faces, or a mesh file trimesh reads")
    p.add_argument("--rays", type=int, default=1_000_000, help="rays per kind (default 1000000)")
    p.add_argument("--kinds", default=",".join(KINDS), help="comma list of " + ",".join(KINDS))
    p.add_argument(
        "--bounces", default="1", help="diffuse bounces to report, e.g. 1,2,4,8 (default 1)"
    )
    p.add_argument(
        "--threads",
        default=",".join(str(t) for t in sorted({1, usable})),
        help=f"comma list of thread counts (default 1,{usable})",
    )
    p.add_argument(
        "--repeat", type=int, default=5, help="timed runs per engine; medians are reported"
    )
    p.add_argument("--out", default=None, help="JSON results file (default results-SCENE.json)")
    p.add_argument(
        "--resolutions",
        default=None,
        help="ablation mode: primary rays at these square resolutions, e.g. 512,1024,2048",
    )
    add_engine_arguments(p)
    p.add_argument(
        "--memory-kinds",
        default="primary,random",
        help="kinds whose peak memory is measured in fresh processes, or 'none'",
    )
    p.add_argument("--no-stats", action="store_true", help="skip the dacrt stats=True runs")
    p.add_argument(
        "--view", default=None, help="view name in scenes/views.json (default: scene file stem)"
    )
    p.add_argument(
        "--slow",
        type=float,
        default=60.0,
        help="an engine whose trace takes longer than this many seconds is not repeated "
        "for that kind (its figure is then from fewer runs; default 60)",
    )
    args = p.parse_args(argv)
    args.threads = int_list(args.threads)
    args.kinds = [k for k in args.kinds.split(",") if k]
    unknown = [k for k in args.kinds if k not in KINDS]
    if unknown:
        p.error(f"unknown kinds {unknown}; choose from {KINDS}")
    args.bounces = int_list(args.bounces)
    if args.resolutions:
        args.resolutions = int_list(args.resolutions)
    args.memory_kinds = [] if args.memory_kinds == "none" else args.memory_kinds.split(",")
    if args.rays < 1 or args.repeat < 1 or not args.threads or min(args.threads) < 1:
        p.error("--rays, --repeat and --threads must be positive")
    if args.bounces and min(args.bounces) < 1:
        p.error("--bounces start at 1")
    return args


# --- ray sets -------------------------------------------------------------------------------------


def reference_tracer(vertices, faces):
    """(name, trace) where trace(o, d) -> (t, normals) finds hits for building secondary rays.

    Embree when installed (the same reference the agreement columns use), else Open3D, else dacrt;
    so every engine is timed on the same rays.
    """
    try:
        scene = Embree([(vertices, faces)])

        def trace(o, d):
            hits = scene.closest(o, d)
            return hits.t, hits.normal

        return "embree", trace
    except ImportError:
        pass
    try:
        import open3d as o3d

        scene = o3d.t.geometry.RaycastingScene()
        scene.add_triangles(o3d.core.Tensor(vertices), o3d.core.Tensor(faces.astype(np.uint32)))

        def trace(o, d):
            out = scene.cast_rays(o3d.core.Tensor(np.ascontiguousarray(np.hstack([o, d]))))
            return out["t_hit"].numpy(), out["primitive_normals"].numpy()

        return "open3d", trace
    except ImportError:
        pass
    import dacrt

    scene = dacrt.Scene([(vertices, faces)])

    def trace(o, d):
        hits = scene.closest(o, d)
        return hits.t, hits.normal

    return "dacrt", trace


def make_ray_sets(args, view, bounds, trace, n_rays: int, kinds) -> list[R.RaySet]:
    """The ray sets of ``kinds``, each of ``n_rays`` rays, in the order of KINDS."""
    diag = R.scene_diagonal(bounds)
    eps = R.EPS_REL * diag
    rng = lambda kind: np.random.default_rng([args.seed, KIND_SEED[kind]])  # noqa: E731
    width, height = R.image_size(n_rays)
    primary = R.primary_rays(view, width, height, rng("primary"), n_rays=n_rays)
    sets = []
    if "primary" in kinds:
        sets.append(primary)
    if {"shadow", "ao", "diffuse"} & set(kinds):
        t, normals = trace(primary.origins, primary.directions)
        hits = R.hit_points(primary.origins, primary.directions, t, normals, eps)
        if "shadow" in kinds:
            if "light" not in view:
                raise SystemExit("the view has no 'light': cannot make shadow rays")
            sets.append(R.shadow_rays(hits, view["light"], n_rays, rng("shadow")))
        if "ao" in kinds:
            sets.append(R.ao_rays(hits, R.AO_REACH_REL * diag, n_rays, rng("ao")))
        if "diffuse" in kinds and args.bounces:
            bounce_sets = R.diffuse_bounces(
                primary, t, normals, trace, max(args.bounces), eps, rng("diffuse")
            )
            sets += [s for s in bounce_sets if int(s.kind.rsplit("b", 1)[1]) in args.bounces]
    if "random" in kinds:
        sets.append(R.random_rays(bounds, n_rays, rng("random")))
    return sets


# --- timing ---------------------------------------------------------------------------------------


def key_of(engine) -> str:
    return f"{engine.name}@{engine.threads}"


def run_kind(rays: R.RaySet, engines, vertices, faces, args, diag, errors) -> dict:
    """Trace-only and build + trace timings of every engine on one ray set, alternating engines."""
    n = rays.n_rays
    small = R.RaySet(
        rays.kind,
        rays.query,
        rays.origins[:WARMUP_RAYS].copy(),
        rays.directions[:WARMUP_RAYS].copy(),
        rays.tmax,
    )
    live, handles, payloads = [], {}, {}
    for engine in engines:
        key = key_of(engine)
        try:
            handle = engine.build(vertices, faces)
            engine.commit(handle)
            engine.trace(handle, engine.convert(small), small)  # warm-up, untimed
            handles[key], payloads[key] = handle, engine.convert(rays)
            live.append(engine)
        except Exception as exc:
            errors.append(_error(rays.kind, key, "warm-up", exc))
    runs = {
        key_of(e): {
            "family": e.family,
            "name": e.name,
            "threads": e.threads,
            "trace_s": [],
            "build_trace_s": [],
            "build_s": [],
            "trace_in_frame_s": [],
        }
        for e in live
    }
    results, slow = {}, set()
    for r in range(args.repeat):
        order = (
            live[r % len(live) :] + live[: r % len(live)] if live else []
        )  # rotate: no fixed position
        for engine in order:
            key = key_of(engine)
            if (key in results and results[key] is None) or key in slow:
                continue  # failed or too slow
            try:
                seconds, result = timed(engine.trace, handles[key], payloads[key], rays)
                build_s, trace_s, _ = build_and_trace(engine, vertices, faces, payloads[key], rays)
            except Exception as exc:
                errors.append(_error(rays.kind, key, f"run {r}", exc))
                results[key] = None
                continue
            run = runs[key]
            run["trace_s"].append(seconds)
            run["build_s"].append(build_s)
            run["trace_in_frame_s"].append(trace_s)
            run["build_trace_s"].append(build_s + trace_s)
            if r == 0:
                results[key] = result
            if seconds > args.slow and r + 1 < args.repeat:
                slow.add(key)
                run["cut_short"] = True
                log(
                    f"  {key}: {seconds:.1f} s > --slow {args.slow:g} s, "
                    f"not repeated for {rays.kind}"
                )
        log(
            f"  {rays.kind} run {r + 1}/{args.repeat}, trace s: "
            + ", ".join(
                f"{k} {v['trace_s'][-1]:.3g}" for k, v in runs.items() if len(v["trace_s"]) > r
            )
        )
    reference = results.get("embree@1")
    for key, run in runs.items():
        run["trace_mrays"] = mrays(n, median(run["trace_s"]))
        run["build_trace_mrays"] = mrays(n, median(run["build_trace_s"]))
        run["build_ms"] = None if not run["build_s"] else 1e3 * median(run["build_s"])
        if reference is not None and results.get(key) is not None and key != "embree@1":
            run["agreement"] = agreement(results[key], reference, 1e-4 * diag)
    info = {
        "n_rays": n,
        "query": rays.query,
        "tmax": None if np.isinf(rays.tmax) else float(rays.tmax),
        "reference_hit": None if reference is None else float(np.mean(reference.hit)),
        "runs": runs,
    }
    if not args.no_stats:
        info["stats"] = stats_runs(
            rays, [e for e in live if e.family == "dacrt"], handles, payloads, errors
        )
    return info


def stats_runs(rays, dacrt_engines, handles, payloads, errors) -> dict:
    """Counters of one untimed stats=True trace per strategy, at 1 thread (or the fewest
    threads)."""
    out = {}
    if not dacrt_engines:
        return out
    fewest = min(e.threads for e in dacrt_engines)
    for engine in [e for e in dacrt_engines if e.threads == fewest]:
        key = key_of(engine)
        try:
            st = engine.trace(handles[key], payloads[key], rays, stats=True).stats or {}
        except Exception as exc:
            errors.append(_error(rays.kind, key, "stats", exc))
            continue
        st = {k: int(v) for k, v in st.items()}
        n = max(1, rays.n_rays)
        out[engine.strategy] = {
            **st,
            "threads": fewest,
            "box_per_ray": st.get("ray_box_tests", 0) / n,
            "tri_per_ray": st.get("ray_triangle_tests", 0) / n,
        }
    return out


def _error(kind, key, stage, exc) -> dict:
    log(f"  ERROR {key} {kind} {stage}: {type(exc).__name__}: {exc}")
    return {
        "kind": kind,
        "engine": key,
        "stage": stage,
        "error": f"{type(exc).__name__}: {exc}",
        "traceback": traceback.format_exc(),
    }


def run_resolutions(args, view, engines, vertices, faces, diag, errors) -> tuple[list[dict], dict]:
    """Ray-sampling ablation: sampling vs sah (and Embree) on primary rays at each resolution."""
    pick = [
        e
        for e in engines
        if (e.family == "dacrt" and e.strategy in ("sampling", "sah")) or e.family == "embree"
    ]
    out, runs = [], {}
    for width in args.resolutions:
        rng = np.random.default_rng([args.seed, KIND_SEED["primary"], width])
        rays = R.primary_rays(view, width, width, rng)
        log(f"resolution {width}²: {rays.n_rays:,} rays")
        info = run_kind(rays, pick, vertices, faces, args, diag, errors)
        threads = sorted({e.threads for e in pick if e.family == "dacrt"}) or [1]
        embree = info["runs"].get("embree@1")
        for t in threads:
            row = {
                "width": width,
                "n_rays": rays.n_rays,
                "threads": t,
                "embree_s": embree and median(embree["trace_s"]),
            }
            for s in ("sampling", "sah"):
                run = info["runs"].get(f"{s}@{t}")
                row[f"{s}_s"] = run and median(run["trace_s"])
                st = info.get("stats", {}).get(s)
                row[f"{s}_box_per_ray"] = st and st["box_per_ray"]
                row[f"{s}_tri_per_ray"] = st and st["tri_per_ray"]
            row["ratio"] = (
                (row["sah_s"] / row["sampling_s"]) if row["sah_s"] and row["sampling_s"] else None
            )
            # Each repetition times both strategies one after the other: the median of their
            # ratios, run by run, is steadier than the ratio of medians when the machine's load
            # drifts.
            pair = [info["runs"].get(f"{s}@{t}") for s in ("sah", "sampling")]
            row["paired_ratio"] = (
                median([a / b for a, b in zip(pair[0]["trace_s"], pair[1]["trace_s"])])
                if all(pair) and pair[0]["trace_s"] and pair[1]["trace_s"]
                else None
            )
            out.append(row)
        runs[str(width)] = info
    return out, runs


# --- main ---------------------------------------------------------------------------------------


def main(argv=None) -> int:
    args = parse_args(argv)
    scene_path = Path(args.scene)
    vertices, faces = load_mesh(scene_path)
    bounds = mesh_bounds(vertices, faces)
    diag = R.scene_diagonal(bounds)
    view_key, view = load_view(scene_path, bounds, args.view)
    engines, dacrt, missing = available_engines(args.threads, args.strategies, args.engines)
    res = {
        "machine": machine_info(),
        "missing": missing,
        "errors": [],
        "args": {k: v for k, v in vars(args).items()},
        "scene": {
            "path": str(scene_path),
            "name": scene_path.stem,
            "triangles": int(len(faces)),
            "vertices": int(len(vertices)),
            "bounds": bounds.tolist(),
            "diagonal": diag,
            "view_key": view_key,
            "view": view,
        },
    }
    for family, reason in missing.items():
        log(f"{family} not available: {reason}")
    if dacrt is not None:
        use_kernel_cache()
        log("dacrt.warmup() ...")
        try:
            res["dacrt_warmup_s"] = float(dacrt.warmup())
        except Exception as exc:  # an engine that cannot warm up is left out
            missing["dacrt"] = f"warmup failed: {type(exc).__name__}: {exc}"
            res["errors"].append(_error("-", "dacrt", "warmup", exc))
            engines = [e for e in engines if e.family != "dacrt"]
    idle_rss = current_rss_bytes()  # engines imported and warmed up, scene loaded
    log(f"{scene_path.name}: {len(faces):,} triangles; engines: {[key_of(e) for e in engines]}")

    if args.resolutions:
        res["resolutions"], res["resolution_runs"] = run_resolutions(
            args, view, engines, vertices, faces, diag, res["errors"]
        )
        ray_sets = []
    else:
        ref_name, trace = reference_tracer(vertices, faces)
        start = time.perf_counter()
        ray_sets = make_ray_sets(args, view, bounds, trace, args.rays, args.kinds)
        res["ray_generation"] = {
            "tracer": ref_name,
            "seconds": time.perf_counter() - start,
            "eps": R.EPS_REL * diag,
            "ao_reach": R.AO_REACH_REL * diag,
        }
        res["kinds"] = {}
        for rays in ray_sets:
            log(f"{rays.kind}: {rays.n_rays:,} {rays.query} rays")
            res["kinds"][rays.kind] = run_kind(
                rays, engines, vertices, faces, args, diag, res["errors"]
            )

    res["peak_rss_bytes"], res["idle_rss_bytes"] = peak_rss_bytes(), idle_rss
    if args.memory_kinds and ray_sets:
        res["memory"] = memory_runs(args, engines, vertices, faces, ray_sets)

    out = Path(args.out or f"results-{scene_path.stem}.json")
    out.write_text(json.dumps(_clean(res), indent=1, default=_json_default, allow_nan=False))
    print(render(res))
    if res["errors"]:
        print(
            "## Errors\n\n"
            + "\n".join(
                f"- {e['engine']} {e['kind']} ({e['stage']}): {e['error']}" for e in res["errors"]
            )
        )
    log(f"results written to {out}")
    return 1 if res["errors"] else 0


def memory_runs(args, engines, vertices, faces, ray_sets) -> list[dict]:
    """Peak RSS of one build + trace per engine at the most threads, each in a fresh process."""
    top = max(args.threads)
    chosen = [e for e in engines if e.family == "embree" or e.threads == top]
    sets = [s for s in ray_sets if s.kind in args.memory_kinds]
    with tempfile.TemporaryDirectory(prefix="bench-mem-") as tmp:
        mesh_path = os.path.join(tmp, "mesh.npz")
        np.savez(mesh_path, vertices=vertices, faces=faces)
        rays_paths = {}
        for s in sets:
            rays_paths[s.kind] = os.path.join(tmp, f"{s.kind}.npz")
            np.savez(rays_paths[s.kind], origins=s.origins, directions=s.directions)
        specs = [
            {
                "family": e.family,
                "name": e.name,
                "strategy": getattr(e, "strategy", None),
                "threads": e.threads,
                "kind": s.kind,
                "query": s.query,
                "tmax": float(s.tmax),
                "n_rays": s.n_rays,
            }
            for s in sets
            for e in chosen
        ]
        log(f"memory: {len(specs)} fresh processes ...")
        return measure_memory(specs, mesh_path, rays_paths)


def _clean(value):
    """The results with non-finite floats as null, so the file is strict JSON."""
    if isinstance(value, dict):
        return {str(k): _clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_clean(v) for v in value]
    if isinstance(value, (float, np.floating)):
        return float(value) if np.isfinite(value) else None
    return value


def _json_default(value):
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"not JSON serialisable: {type(value)}")


if __name__ == "__main__":
    sys.exit(main())
