"""Benchmark figures: speed against ray count, per-frame time against ray and triangle count.

    python -m bench.plots --out docs/img [--scene PATH ...] [--repeat 3] [--max-rays N]
        [--threads 2] [--big] [--grid-sides 1,2,4]
    python -m bench.plots --out docs/img --replot docs/img/plots.json      # redraw, no measuring

Writes into --out:
  mrays-vs-rays-<scene>.png   trace-only Mrays/s against the number of primary rays (100² ... 2048²)
  frame-vs-rays-<scene>.png   per-frame time (new scene + trace) against the number of primary rays
  frame-vs-triangles.png      per-frame time at a fixed ray count against triangles (grids of
                              dragons, 100K to 1.6M, with --big to 16.9M)
  plots.json                  every plotted median, every single timing, and the machine

The timing is bench.run's: the same engine adapters (bench/engines.py), rays (bench/rays.py),
timers (bench/measure.py), engines alternating within each repetition, medians of --repeat.
The per-frame figures also show native Embree (bench/native_embree.py's C++ anchor, run after the
other engines at each point): its best frame of low, medium and refit, each its minimum over
max(2, --repeat) repetitions. Progress goes to stderr. See bench/README.md, "Figures".
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from bench import rays as R
from bench.engines import add_engine_arguments, available_engines
from bench.entry import description, use_kernel_cache
from bench.measure import build_and_trace, machine_info, median, mrays
from bench.native_embree import (
    ANCHOR,
    BUILD_DIR,
    AnchorUnavailable,
    anchor_frames,
    best_quality,
    build_anchor,
)
from bench.run import (
    KIND_SEED,
    WARMUP_RAYS,
    _clean,
    _error,
    _json_default,
    int_list,
    key_of,
    log,
    run_kind,
)
from bench.scene_io import load_mesh, load_view, mesh_bounds

SHARED_SCENES = Path(__file__).resolve().parent.parent.parent / "shared" / "scenes"
DEFAULT_SCENES = ("sibenik", "sponza", "conference")
# image widths: width² from ~10K to ~4M primary rays, each about twice the one before
WIDTHS = (100, 181, 256, 362, 512, 724, 1024, 1448, 2048)
GRID_SIDES = (1, 2, 4)  # k x k copies of the grid mesh: 100K, 400K, 1.6M dragon triangles
BIG_GRID_SIDES = (8, 13)  # --big: 6.4M and 16.9M (13 x 13 keeps the grid square, as the image)
NATIVE = "native-embree"  # the family and --engines name of bench.native_embree's anchor
NATIVE_LABEL = "Embree (native, best of low/medium/refit)"
GRID_GAP = 0.05  # space between copies, relative to the copy's extent
GRID_FOV_DEG = 20.0
JSON_NAME = "plots.json"


def parse_args(argv=None):
    usable = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    p = argparse.ArgumentParser(prog="python -m bench.plots", description=description(__doc__))
    p.add_argument("--out", required=True, help="directory for the PNGs and plots.json")
    p.add_argument(
        "--scene",
        nargs="+",
        default=None,
        metavar="PATH",
        help="scene files for the ray-count figures (default: "
        + ", ".join(f"{s}.npz" for s in DEFAULT_SCENES)
        + f" from {SHARED_SCENES})",
    )
    p.add_argument(
        "--repeat", type=int, default=3, help="timed runs per engine and point; medians are plotted"
    )
    p.add_argument(
        "--max-rays",
        type=int,
        default=WIDTHS[-1] ** 2,
        help=f"largest ray count: image widths {','.join(map(str, WIDTHS))} are kept while "
        f"width² <= N; also caps --frame-rays (default {WIDTHS[-1] ** 2})",
    )
    p.add_argument(
        "--threads",
        type=int,
        default=usable,
        help=f"threads for dacrt, Open3D and native Embree (default {usable}); embreex's run is "
        "always 1 thread",
    )
    p.add_argument(
        "--frame-rays",
        type=int,
        default=1_000_000,
        help="primary rays per frame in frame-vs-triangles (default 1000000)",
    )
    p.add_argument(
        "--big",
        action="store_true",
        help="also "
        + ", ".join(f"{k}x{k}" for k in BIG_GRID_SIDES)
        + " copies in frame-vs-triangles (6.4M and 16.9M dragon triangles)",
    )
    p.add_argument(
        "--grid-sides",
        type=int_list,
        default=None,
        metavar="K,K,...",
        help="the k of the k x k grids in frame-vs-triangles, instead of "
        + ",".join(map(str, GRID_SIDES))
        + " (and --big's "
        + ",".join(map(str, BIG_GRID_SIDES))
        + ")",
    )
    p.add_argument(
        "--grid-mesh",
        default=str(SHARED_SCENES / "dragon.npz"),
        help="the mesh copied into grids for frame-vs-triangles (default the dragon)",
    )
    p.add_argument(
        "--figures",
        default="rays,triangles",
        help="which measurements: 'rays' (the two per-scene figures), 'triangles', or both",
    )
    add_engine_arguments(p, ("dacrt", "embree", "open3d", NATIVE))
    p.add_argument(
        "--anchor-build-dir",
        type=Path,
        default=BUILD_DIR,
        help=f"where native Embree's anchor ({ANCHOR}) is compiled (default {BUILD_DIR})",
    )
    p.add_argument(
        "--slow",
        type=float,
        default=60.0,
        help=(
            "an engine whose run takes longer than this many seconds is not repeated at that point"
        ),
    )
    p.add_argument(
        "--replot",
        default=None,
        metavar="JSON",
        help="redraw the PNGs from a plots.json of an earlier run, without measuring",
    )
    args = p.parse_args(argv)
    args.figures = {f for f in args.figures.split(",") if f}
    if args.figures - {"rays", "triangles"}:
        p.error("--figures takes rays, triangles or rays,triangles")
    args.scene = args.scene or [str(SHARED_SCENES / f"{s}.npz") for s in DEFAULT_SCENES]
    args.widths = [w for w in WIDTHS if w * w <= args.max_rays]
    args.frame_rays = min(args.frame_rays, args.max_rays)
    if args.grid_sides is None:
        args.grid_sides = list(GRID_SIDES) + (list(BIG_GRID_SIDES) if args.big else [])
    args.no_stats = True  # run_kind: no untimed stats=True traces
    if args.repeat < 1 or args.threads < 1 or args.frame_rays < 1:
        p.error("--repeat, --threads and --frame-rays must be positive")
    if not args.grid_sides or min(args.grid_sides) < 1:
        p.error("--grid-sides takes positive sides")
    if "rays" in args.figures and not args.widths and not args.replot:
        p.error(f"--max-rays {args.max_rays} is below the smallest image ({WIDTHS[0]}² rays)")
    return args


# --- measuring: ray counts ------------------------------------------------------------------------


def measure_scene(path: Path, args, engines, errors, native=None) -> dict:
    """Trace-only and build + trace timings of every engine on primary rays at each width of
    ``args``, and native Embree's frames when ``native`` is (anchor binary, scratch folder).

    The rays of each width are the ones bench.run's ablation (--resolutions) uses for the same seed.
    """
    vertices, faces = load_mesh(path)
    bounds = mesh_bounds(vertices, faces)
    diag = R.scene_diagonal(bounds)
    view_key, view = load_view(path, bounds)
    log(f"{path.name}: {len(faces):,} triangles, view {view_key!r}")
    start = time.perf_counter()
    points = []
    for width in args.widths:
        rng = np.random.default_rng([args.seed, KIND_SEED["primary"], width])
        rays = R.primary_rays(view, width, width, rng)
        log(f"{path.stem} {width}²: {rays.n_rays:,} primary rays")
        info = run_kind(rays, engines, vertices, faces, args, diag, errors)
        label = f"{path.stem} {width}²"
        info["native"] = native_runs(native, vertices, faces, rays, args, errors, label)
        points.append({"width": width, **info})
    return {
        "path": str(path),
        "name": path.stem,
        "triangles": int(len(faces)),
        "vertices": int(len(vertices)),
        "bounds": bounds.tolist(),
        "diagonal": diag,
        "view_key": view_key,
        "view": view,
        "seconds": time.perf_counter() - start,
        "points": points,
    }


# --- measuring: triangle counts -------------------------------------------------------------------


def tile_mesh(
    vertices: np.ndarray, faces: np.ndarray, side: int, axes: tuple[int, int], gap: float = GRID_GAP
) -> tuple[np.ndarray, np.ndarray]:
    """(vertices float32, faces int32) of side x side translated copies of a mesh on a grid.

    The copies step along world ``axes`` by the mesh's extent on that axis times (1 + gap).
    The arrays are written copy by copy, so a 16M-triangle grid needs no float64 or int64 copy.
    """
    bounds = mesh_bounds(vertices, faces)
    step = (bounds[1] - bounds[0]) * (1.0 + gap)
    copies = side * side
    if copies * len(vertices) >= 2**31:
        raise ValueError(f"{copies} copies of {len(vertices):,} vertices overflow int32 indices")
    offsets = np.zeros((copies, 3))
    ii, jj = np.divmod(np.arange(copies), side)
    offsets[:, axes[0]] = ii * step[axes[0]]
    offsets[:, axes[1]] = jj * step[axes[1]]
    base_v = np.asarray(vertices, dtype=np.float64)
    base_f = np.asarray(faces, dtype=np.int32)
    grid_v = np.empty((copies, len(vertices), 3), dtype=np.float32)
    grid_f = np.empty((copies, len(faces), 3), dtype=np.int32)
    for c in range(copies):
        grid_v[c] = base_v + offsets[c]  # offset in float64, rounded once to float32
        grid_f[c] = base_f + np.int32(c * len(vertices))
    return grid_v.reshape(-1, 3), grid_f.reshape(-1, 3)


def grid_axes(view: dict) -> tuple[int, int]:
    """The two world axes most across the viewing direction: the plane the grid is laid in."""
    direction = np.asarray(view["eye"], float) - np.asarray(view["target"], float)
    order = np.argsort(np.abs(direction / np.linalg.norm(direction)))
    return tuple(sorted(int(a) for a in order[:2]))


def framing_view(bounds: np.ndarray, like: dict, fov_deg: float = GRID_FOV_DEG) -> dict:
    """A view from ``like``'s direction, as close as it can be while all of ``bounds`` is in a
    square image."""
    bounds = np.asarray(bounds, dtype=np.float64)
    target = bounds.mean(axis=0)
    back = np.asarray(like["eye"], float) - np.asarray(like["target"], float)
    back /= np.linalg.norm(back)
    forward, right, up = R.camera_frame(target + back, target, like["up"])
    tan_half = np.tan(np.radians(fov_deg) / 2.0)
    corners = (
        np.array(
            [
                [bounds[i, 0], bounds[j, 1], bounds[k, 2]]
                for i in (0, 1)
                for j in (0, 1)
                for k in (0, 1)
            ]
        )
        - target
    )
    # a corner c is in the image when |c.right|, |c.up| <= tan_half * (distance + c.forward)
    across = np.maximum(np.abs(corners @ right), np.abs(corners @ up))
    distance = 1.02 * float(np.max(across / tan_half - corners @ forward))
    eye = target + back * distance
    return {
        "eye": eye.tolist(),
        "target": target.tolist(),
        "up": list(map(float, like["up"])),
        "fov_deg": fov_deg,
        "note": "frames the whole grid, from the direction of the mesh's own view",
    }


def frame_runs(engines, vertices, faces, rays: R.RaySet, args, errors, label: str) -> dict:
    """Build + trace timings (bench.measure.build_and_trace) of every engine, alternating
    engines."""
    payloads = {key_of(e): e.convert(rays) for e in engines}
    runs = {
        key_of(e): {
            "family": e.family,
            "name": e.name,
            "threads": e.threads,
            "build_s": [],
            "trace_in_frame_s": [],
            "build_trace_s": [],
        }
        for e in engines
    }
    failed, slow = set(), set()
    for r in range(args.repeat):
        order = engines[r % len(engines) :] + engines[: r % len(engines)] if engines else []
        for engine in order:
            key = key_of(engine)
            if key in failed or key in slow:
                continue
            try:
                build_s, trace_s, result = build_and_trace(
                    engine, vertices, faces, payloads[key], rays
                )
            except Exception as exc:
                errors.append(_error(label, key, f"run {r}", exc))
                failed.add(key)
                continue
            run = runs[key]
            run["build_s"].append(build_s)
            run["trace_in_frame_s"].append(trace_s)
            run["build_trace_s"].append(build_s + trace_s)
            if r == 0 and "hit" not in run:
                run["hit"] = float(np.mean(result.hit))
            if build_s + trace_s > args.slow and r + 1 < args.repeat:
                slow.add(key)
                run["cut_short"] = True
                log(
                    f"  {key}: {build_s + trace_s:.1f} s > --slow {args.slow:g} s, "
                    f"not repeated for {label}"
                )
        log(
            f"  {label} run {r + 1}/{args.repeat}, frame s: "
            + ", ".join(
                f"{k} {v['build_trace_s'][-1]:.3g}"
                for k, v in runs.items()
                if len(v["build_trace_s"]) > r
            )
        )
    for run in runs.values():
        run["build_trace_mrays"] = mrays(rays.n_rays, median(run["build_trace_s"]))
    return runs


def measure_triangles(args, engines, errors, native=None) -> dict:
    """Per-frame time at args.frame_rays primary rays, on k x k grids of copies of
    args.grid_mesh, with native Embree's frames when ``native`` is (binary, scratch folder)."""
    path = Path(args.grid_mesh)
    vertices, faces = load_mesh(path)
    _, like = load_view(path, mesh_bounds(vertices, faces))
    axes = grid_axes(like)
    width, height = R.image_size(args.frame_rays)
    start = time.perf_counter()
    points = []
    for side in args.grid_sides:
        grid_v, grid_f = tile_mesh(vertices, faces, side, axes)
        view = framing_view(mesh_bounds(grid_v, grid_f), like)
        rng = np.random.default_rng([args.seed, KIND_SEED["primary"]])
        rays = R.primary_rays(view, width, height, rng, n_rays=args.frame_rays)
        label = f"{side}x{side} {path.stem}"
        log(f"{label}: {len(grid_f):,} triangles, {rays.n_rays:,} primary rays")
        live = engines
        if side == args.grid_sides[0]:  # one untimed small frame per engine, as in run_kind
            live = warm_up(engines, grid_v, grid_f, rays, errors, label)
        points.append(
            {
                "side": side,
                "copies": side * side,
                "triangles": int(len(grid_f)),
                "vertices": int(len(grid_v)),
                "n_rays": rays.n_rays,
                "view": view,
                "runs": frame_runs(live, grid_v, grid_f, rays, args, errors, label),
                "native": native_runs(native, grid_v, grid_f, rays, args, errors, label),
            }
        )
        engines = live
        del grid_v, grid_f, rays  # free this grid before the next, larger one is made
    return {
        "mesh": str(path),
        "name": path.stem,
        "mesh_triangles": int(len(faces)),
        "axes": list(axes),
        "gap": GRID_GAP,
        "image": [width, height],
        "seconds": time.perf_counter() - start,
        "points": points,
    }


def native_runs(native, vertices, faces, rays: R.RaySet, args, errors, label) -> dict | None:
    """Native Embree's frame of each quality and its best, in ms (the anchor's own timings: each
    its minimum over its repetitions, build and trace apart), or None when it is left out."""
    if native is None:
        return None
    binary, folder = native
    try:
        frames = anchor_frames(binary, folder, vertices, faces, rays, args.threads, args.repeat)
    except Exception as exc:
        errors.append(_error(label, NATIVE, "anchor", exc))
        return None
    qualities = {
        quality: {
            "build_ms": build_ms,
            "trace_ms": trace_ms,
            "frame_ms": round(build_ms + trace_ms, 3),  # the anchor prints 3 decimals
            "hit": float(np.mean(np.isfinite(t))),
        }
        for quality, (build_ms, trace_ms, t) in frames.items()
    }
    best = best_quality(frames)
    log(
        f"  {label} {NATIVE}@{args.threads} frame ms: "
        + ", ".join(f"{q} {v['frame_ms']:.3g}" for q, v in qualities.items())
    )
    return {
        "family": NATIVE,
        "name": NATIVE,
        "threads": args.threads,
        "reps": max(2, args.repeat),
        "best": best,
        "frame_ms": qualities[best]["frame_ms"],
        "build_ms": qualities[best]["build_ms"],
        "qualities": qualities,
    }


def warm_up(engines, vertices, faces, rays: R.RaySet, errors, label) -> list:
    """The engines that build and trace a few rays without an error (untimed)."""
    small = R.RaySet(
        rays.kind,
        rays.query,
        rays.origins[:WARMUP_RAYS].copy(),
        rays.directions[:WARMUP_RAYS].copy(),
        rays.tmax,
    )
    live = []
    for engine in engines:
        try:
            handle = engine.build(vertices, faces)
            engine.commit(handle)
            engine.trace(handle, engine.convert(small), small)
            live.append(engine)
        except Exception as exc:
            errors.append(_error(label, key_of(engine), "warm-up", exc))
    return live


# --- figures: the plotted data (what plots.json keeps under "figures") ----------------------------


def _label(run: dict, frame: bool) -> str:
    if run["family"] == "embree":
        return (
            "Embree (embreex; build on all cores, run on 1)"
            if frame
            else "Embree (embreex run, 1 thread)"
        )
    if run["family"] == "open3d":
        return f"Open3D ({run['threads']} threads)"
    return f"dacrt {run['name']} ({run['threads']} threads)"


def _series(points: list[dict], value, frame: bool) -> list[dict]:
    """One series per engine configuration, in first-seen order (dacrt strategies, Embree, Open3D).

    value(point, run) -> (median, low, high); a point where the engine has no run gets None.
    Per-frame series (``frame``) also keep the median build part, "build_ms", which is not drawn.
    """
    first = {}
    for point in points:
        for key, run in point["runs"].items():
            first.setdefault(key, run)
    out = []
    for key, run in first.items():
        ys = [value(p, p["runs"][key]) if key in p["runs"] else (None, None, None) for p in points]
        series = {
            "key": key,
            "family": run["family"],
            "name": run["name"],
            "threads": run["threads"],
            "label": _label(run, frame),
            "y": [y[0] for y in ys],
            "low": [y[1] for y in ys],
            "high": [y[2] for y in ys],
        }
        if frame:
            series["build_ms"] = [
                None
                if key not in p["runs"] or not p["runs"][key]["build_s"]
                else 1e3 * median(p["runs"][key]["build_s"])
                for p in points
            ]
        out.append(series)
    return out


def _native_series(points: list[dict]) -> list[dict]:
    """Native Embree's best frame as one series (no band: each value is already a minimum), or none
    when the anchor did not run."""
    runs = [p.get("native") for p in points]
    first = next((run for run in runs if run), None)
    if first is None:
        return []
    y = [None if run is None else run["frame_ms"] for run in runs]
    return [
        {
            "key": f"{NATIVE}@{first['threads']}",
            "family": NATIVE,
            "name": NATIVE,
            "threads": first["threads"],
            "label": NATIVE_LABEL,
            "y": y,
            "low": y,
            "high": y,
            "build_ms": [None if run is None else run["build_ms"] for run in runs],
            "best": [None if run is None else run["best"] for run in runs],
        }
    ]


def _trace_mrays(point, run):
    """Median Mrays/s of the trace-only runs, and the slowest and fastest run."""
    times = run["trace_s"]
    if not times:
        return None, None, None
    n = point["n_rays"]
    return mrays(n, median(times)), mrays(n, max(times)), mrays(n, min(times))


def _frame_ms(point, run):
    """Median ms of the build + trace runs, and the fastest and slowest run."""
    times = run["build_trace_s"]
    if not times:
        return None, None, None
    return 1e3 * median(times), 1e3 * min(times), 1e3 * max(times)


def _count(n: int) -> str:
    for size, unit in ((1e6, "M"), (1e3, "K")):
        if n >= size:
            return f"{n / size:.3g}{unit}"
    return str(n)


def _subtitle(machine: dict, args, native: bool = False) -> str:
    runs = "1 run" if args.repeat == 1 else f"{args.repeat} runs, band = fastest to slowest"
    engines = "dacrt, Open3D and native Embree" if native else "dacrt and Open3D"
    text = (
        f"{machine['cpu_model']}, {machine['logical_cores']} logical cores; {engines} at "
        f"{args.threads} thread{'s' * (args.threads > 1)}; median of {runs}"
    )
    if native:
        text += f"; native Embree: fastest of {max(2, args.repeat)} repetitions"
    return text


def scene_figures(scene: dict, machine: dict, args) -> dict:
    """{file stem: figure} for mrays-vs-rays-<scene> and frame-vs-rays-<scene>."""
    pts = scene["points"]
    native = _native_series(pts)
    title = f"{scene['name']} ({scene['triangles']:,} triangles), primary rays"
    common = {
        "x": [p["n_rays"] for p in pts],
        "x_ticks": [f"{p['width']}²\n{_count(p['n_rays'])}" for p in pts],
        "x_label": "primary rays per trace (image size, rays)",
        "x_log": True,
        "subtitle": _subtitle(machine, args),
    }
    return {
        f"mrays-vs-rays-{scene['name']}": {
            **common,
            "title": f"{title}: trace only (scene built beforehand)",
            "y_label": "Mrays/s",
            "y_log": False,
            "series": _series(pts, _trace_mrays, frame=False),
        },
        f"frame-vs-rays-{scene['name']}": {
            **common,
            "subtitle": _subtitle(machine, args, native=bool(native)),
            "title": f"{title}: per frame (new scene + trace)",
            "y_label": "time per frame (ms)",
            "y_log": True,
            "series": _series(pts, _frame_ms, frame=True) + native,
        },
    }


def triangle_figure(tri: dict, machine: dict, args) -> dict:
    pts = tri["points"]
    native = _native_series(pts)
    n_rays = pts[0]["n_rays"] if pts else args.frame_rays
    return {
        "frame-vs-triangles": {
            "x": [p["triangles"] for p in pts],
            "x_ticks": [f"{_count(p['triangles'])}\n{p['side']}×{p['side']}" for p in pts],
            "x_label": f"triangles (grid of copies of {tri['name']})",
            "x_log": True,
            "title": (
                f"Per frame (new scene + trace), {n_rays:,} primary rays, grids of {tri['name']}s"
            ),
            "subtitle": _subtitle(machine, args, native=bool(native)),
            "y_label": "time per frame (ms)",
            "y_log": True,
            "series": _series(pts, _frame_ms, frame=True) + native,
        }
    }


# --- figures: drawing -----------------------------------------------------------------------------

DACRT_COLORS = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#17becf")
DACRT_MARKERS = ("o", "D", "v", "P", "*", "h")
OTHER_STYLE = {
    "embree": {"color": "black", "linestyle": (0, (5, 2)), "marker": "s", "linewidth": 1.6},
    "open3d": {"color": "#8c564b", "linestyle": "-.", "marker": "^", "linewidth": 1.6},
    NATIVE: {"color": "black", "linestyle": "-", "marker": "X", "linewidth": 2.2},
}


def _styles(series: list[dict]) -> list[dict]:
    """Matplotlib line styles: one colour per dacrt strategy (the first drawn thicker), fixed for
    the others."""
    styles, n_dacrt = [], 0
    for s in series:
        if s["family"] == "dacrt":
            i = n_dacrt % len(DACRT_COLORS)
            styles.append(
                {
                    "color": DACRT_COLORS[i],
                    "linestyle": "-",
                    "marker": DACRT_MARKERS[i],
                    "linewidth": 2.6 if n_dacrt == 0 else 1.6,
                }
            )
            n_dacrt += 1
        else:
            default = {"color": "gray", "linestyle": ":", "marker": "x", "linewidth": 1.6}
            styles.append(dict(OTHER_STYLE.get(s["family"], default)))
    return styles


def draw(figure: dict, path: Path) -> None:
    """One PNG from a figure dict of scene_figures / triangle_figure."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import (
        FixedLocator,
        FuncFormatter,
        LogLocator,
        NullFormatter,
        NullLocator,
    )

    x = np.asarray(figure["x"], dtype=float)
    nan = lambda values: np.array([np.nan if v is None else v for v in values], dtype=float)  # noqa: E731
    fig, ax = plt.subplots(figsize=(10, 5.8), dpi=130)
    for s, style in zip(figure["series"], _styles(figure["series"])):
        ax.plot(x, nan(s["y"]), label=s["label"], markersize=6, **style)
        ax.fill_between(
            x, nan(s["low"]), nan(s["high"]), color=style["color"], alpha=0.12, linewidth=0
        )
    if figure["x_log"]:
        ax.set_xscale("log")
        if len(x):
            ax.set_xlim(x.min() / 1.35, x.max() * 1.35)
    ax.xaxis.set_major_locator(FixedLocator(x))
    ax.xaxis.set_minor_locator(NullLocator())
    ax.set_xticks(x, figure["x_ticks"])
    plain = FuncFormatter(lambda v, _: f"{v:g}")
    if figure["y_log"]:
        ax.set_yscale("log")
        low, high = ax.get_ylim()
        decades = np.log10(high / low)
        # label enough minor ticks that a range of less than a decade still reads
        subs = (2, 3, 4, 5, 6, 7, 8, 9) if decades < 0.7 else (2, 3, 5) if decades < 1.5 else (2, 5)
        ax.yaxis.set_major_locator(LogLocator(base=10))
        ax.yaxis.set_minor_locator(LogLocator(base=10, subs=subs))
        ax.yaxis.set_major_formatter(plain)
        ax.yaxis.set_minor_formatter(plain if decades < 3.5 else NullFormatter())
    else:
        ax.set_ylim(bottom=0)
    ax.grid(True, which="major", alpha=0.35)
    ax.grid(True, which="minor", axis="y", alpha=0.15)
    ax.set_xlabel(figure["x_label"], fontsize=11)
    ax.set_ylabel(figure["y_label"], fontsize=11)
    ax.tick_params(labelsize=10)
    ax.set_title(figure["title"], fontsize=13, pad=20)
    ax.text(
        0.5,
        1.012,
        figure["subtitle"],
        transform=ax.transAxes,
        ha="center",
        va="bottom",
        fontsize=8.5,
        color="#444444",
    )
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=10, frameon=False)
    fig.savefig(path, bbox_inches="tight")
    plt.close(fig)


# --- main -----------------------------------------------------------------------------------------


def save(res: dict, out: Path) -> None:
    path = out / JSON_NAME
    path.write_text(json.dumps(_clean(res), indent=1, default=_json_default, allow_nan=False))


def draw_all(figures: dict, out: Path) -> None:
    for name, figure in figures.items():
        draw(figure, out / f"{name}.png")
        log(f"wrote {out / name}.png")


def main(argv=None) -> int:
    args = parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if args.replot:
        draw_all(json.loads(Path(args.replot).read_text())["figures"], out)
        return 0
    started = time.perf_counter()
    engines, dacrt, missing = available_engines([args.threads], args.strategies, args.engines)
    native = None
    if NATIVE in args.engines:
        try:
            binary = build_anchor(ANCHOR, args.anchor_build_dir)
            native = (binary, Path(tempfile.mkdtemp(prefix="plots-native-embree-")))
        except AnchorUnavailable as exc:
            missing[NATIVE] = str(exc)
    for family, reason in missing.items():
        log(f"{family} not available: {reason}")
    try:
        return measure_and_draw(args, out, engines, dacrt, missing, native, started)
    finally:
        if native is not None:
            shutil.rmtree(native[1], ignore_errors=True)


def measure_and_draw(args, out: Path, engines, dacrt, missing, native, started) -> int:
    res = {
        "machine": machine_info(),
        "loadavg_start": list(os.getloadavg()),
        "missing": missing,
        "errors": [],
        "args": {
            "scene": args.scene,
            "repeat": args.repeat,
            "max_rays": args.max_rays,
            "threads": args.threads,
            "frame_rays": args.frame_rays,
            "big": args.big,
            "grid_mesh": args.grid_mesh,
            "figures": sorted(args.figures),
            "engines": list(args.engines),
            "strategies": args.strategies,
            "seed": args.seed,
            "slow": args.slow,
            "widths": args.widths,
            "grid_sides": args.grid_sides,
        },
        "scenes": [],
        "figures": {},
    }
    if dacrt is not None:
        use_kernel_cache()
        log("dacrt.warmup() ...")
        try:
            res["dacrt_warmup_s"] = float(dacrt.warmup())
        except Exception as exc:
            missing["dacrt"] = f"warmup failed: {type(exc).__name__}: {exc}"
            res["errors"].append(_error("-", "dacrt", "warmup", exc))
            engines = [e for e in engines if e.family != "dacrt"]
    keys = [key_of(e) for e in engines] + ([f"{NATIVE}@{args.threads}"] if native else [])
    log(f"engines: {keys}")

    if "rays" in args.figures:
        for scene_path in args.scene:
            scene = measure_scene(Path(scene_path), args, engines, res["errors"], native)
            res["scenes"].append(scene)
            figures = scene_figures(scene, res["machine"], args)
            res["figures"].update(figures)
            save(res, out)  # a figure at a time, so a failure later keeps what was done
            draw_all(figures, out)
            log(f"{scene['name']}: {scene['seconds']:.0f} s")
    if "triangles" in args.figures:
        res["triangles"] = measure_triangles(args, engines, res["errors"], native)
        figures = triangle_figure(res["triangles"], res["machine"], args)
        res["figures"].update(figures)
        draw_all(figures, out)
        log(f"triangles: {res['triangles']['seconds']:.0f} s")
    res["loadavg_end"] = list(os.getloadavg())
    res["seconds"] = time.perf_counter() - started
    save(res, out)
    log(f"{out / JSON_NAME} written; {res['seconds']:.0f} s in all")
    for e in res["errors"]:
        print(f"error: {e['engine']} {e['kind']} ({e['stage']}): {e['error']}")
    return 1 if res["errors"] else 0


if __name__ == "__main__":
    sys.exit(main())
