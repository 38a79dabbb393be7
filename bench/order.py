"""Storage order of a mesh's rows: the faces' order, Morton order, and shuffled faces,
side by side in one process.

    python -m bench.order                                   # Sibenik, Sponza; 131K and 1M rays
    python -m bench.order --scenes sibenik --rays 131072 --world 1e6 --repeats 7

For each scene, four ``dacrt.Scene`` of the same triangles, each built once:

  file             the faces as given, packed in that order (``order="file"``)
  morton           the faces as given, packed in Morton order (``order="morton"``)
  shuffled         the faces in a seeded random order, packed in that order
  shuffled+morton  the shuffled faces packed in Morton order

then ``closest`` of one batch of rays (a camera's primary rays for a shared scene, lidars for the
world of ``bench.world``: 131,072 rays each), the four scenes in turn, an untimed first round,
medians of ``--repeats`` rounds. Every round's answers are checked: t bit for bit in all four,
(mesh, prim) bit for bit between file and morton and between shuffled and shuffled+morton, and
the shuffled scenes' prims through the permutation against file order (they differ only where a
ray hits two faces at one t, an edge they share: counted as ``ties``). ``pack ms`` is the time to
build each Scene (medians of ``--repeats`` builds); its difference between morton and file is the
sort's cost.

``--baseline DIR`` adds a fifth scene, ``base``: the faces as given in an older copy of the
engine, imported from DIR as the package ``dacrt_base`` (its imports are all relative), timed in
the same rounds and checked bit for bit against ``file``; for the engine before Morton order:

    git archive c770b47 dacrt | tar -x -C /tmp/base && mv /tmp/base/dacrt /tmp/base/dacrt_base
    python -m bench.order --baseline /tmp/base
"""

from __future__ import annotations

import argparse
import gc
import importlib
import statistics
import sys
import time
from pathlib import Path

import numpy as np

import dacrt

from .entry import description, use_kernel_cache
from .rays import image_size, primary_rays
from .scene_io import load_mesh, load_view, mesh_bounds
from .world import build_world, find_shared, lidar_poses, lidar_rays

LIDAR_RAYS = 131072
MODES = ("file", "morton", "shuffled", "shuffled+morton")


def build(engine, vertices, faces, morton: bool) -> tuple[dacrt.Scene, float]:
    """(Scene, ms to build it) of the ``engine`` package, with each mesh packed in Morton order
    or in the faces' order (an engine without ``order=`` packs in the faces' order)."""
    order = {"order": "morton" if morton else "file"} if hasattr(engine, "packed") else {}
    gc.collect()
    start = time.perf_counter()
    scene = engine.Scene([(vertices, faces)], **order)
    return scene, 1e3 * (time.perf_counter() - start)


def camera_rays(vertices, faces, scene_path: Path, n_rays: int):
    """A camera's primary rays, ``n_rays`` of them (the scene's view from scenes/views.json)."""
    _, view = load_view(scene_path, mesh_bounds(vertices, faces))
    width, height = image_size(n_rays)
    rays = primary_rays(view, width, height, np.random.default_rng(0), n_rays=n_rays)
    return rays.origins, rays.directions


def world_rays(length: float, n_rays: int):
    """Lidars on the world's street, ``n_rays // 131072`` of them (at least one)."""
    return lidar_rays(lidar_poses(max(1, n_rays // LIDAR_RAYS), 0, length))


def compare(name, vertices, faces, ray_sets, repeats, threads, seed, modes, base) -> list[dict]:
    """The rows of one scene's table: per ray count, each mode's median ms (and its spread);
    ``base`` is the package of mode ``base`` (or None)."""
    perm = np.random.default_rng(seed).permutation(len(faces))
    shuffled = np.ascontiguousarray(faces[perm])
    scenes, packs = {}, {mode: [] for mode in modes}
    for _ in range(repeats):
        for mode in modes:
            given = shuffled if mode.startswith("shuffled") else faces
            engine = base if mode == "base" else dacrt
            scenes[mode], ms = build(engine, vertices, given, mode.endswith("morton"))
            packs[mode].append(ms)
    pack_ms = {mode: statistics.median(packs[mode]) for mode in modes}
    rows = []
    for n_rays, (origins, directions) in ray_sets.items():
        times = {mode: [] for mode in modes}
        ties = 0
        for round_ in range(repeats + 1):
            answers = {}
            for mode in modes:
                gc.collect()
                start = time.perf_counter()
                answers[mode] = scenes[mode].closest(origins, directions, threads=threads)
                if round_:  # the first round is untimed
                    times[mode].append(1e3 * (time.perf_counter() - start))
            ties = check(answers, perm) if set(MODES) <= set(modes) else 0
            if "base" in modes and "file" in modes:
                same(answers["base"], answers["file"], ("base", "file"))
        rows.append(
            {
                "scene": name,
                "triangles": len(faces),
                "rays": n_rays,
                "ms": {mode: statistics.median(times[mode]) for mode in modes},
                "range": {mode: (min(times[mode]), max(times[mode])) for mode in modes},
                "pack_ms": pack_ms,
                "ties": ties,
                "hits": int(np.isfinite(answers["file"].t).sum()),
            }
        )
        print(row_line(rows[-1]), flush=True)
        spread = ", ".join(f"{m} {lo:.0f}-{hi:.0f}" for m, (lo, hi) in rows[-1]["range"].items())
        print(f"  (ms from-to: {spread})", flush=True)
    return rows


def check(answers, perm) -> int:
    """Assert the modes' answers agree (module docstring); returns the rays whose shuffled prim
    maps to another face of file order (ties at a shared edge)."""
    file = answers["file"]
    for mode in MODES[1:]:
        assert np.array_equal(answers[mode].t.view(np.uint32), file.t.view(np.uint32)), mode
        assert np.array_equal(answers[mode].mesh, file.mesh), mode
    for a, b in (("file", "morton"), ("shuffled", "shuffled+morton")):
        same(answers[a], answers[b], (a, b))
    prim = answers["shuffled"].prim
    mapped = np.where(prim >= 0, perm[np.maximum(prim, 0)], prim)
    return int((mapped != file.prim).sum())


def same(a, b, what) -> None:
    """Assert two closest answers are identical, bit for bit."""
    for field in ("t", "mesh", "prim", "u", "v", "normal"):
        x, y = getattr(a, field), getattr(b, field)
        assert np.array_equal(x.view(np.uint32), y.view(np.uint32)), (what, field)


def row_line(row) -> str:
    ms = {mode: row["ms"].get(mode, float("nan")) for mode in ("base",) + MODES}
    return (
        f"| {row['scene']} | {row['triangles']:,} | {row['rays']:,} | {ms['base']:.0f} | "
        + " | ".join(f"{ms[mode]:.0f}" for mode in MODES)
        + f" | {ms['file'] / ms['base']:.2f} | {ms['morton'] / ms['base']:.2f}"
        + f" | {ms['morton'] / ms['file']:.2f} | {ms['shuffled+morton'] / ms['file']:.2f} |"
        + f" {row['ties']} |"
    )


def table(rows) -> str:
    lines = [
        "| scene | triangles | rays | base ms | file ms | morton ms | shuffled ms "
        "| shuffled+morton ms | file / base | morton / base | morton / file "
        "| shuffled+morton / file | ties |",
        "|---|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|--:|",
    ]
    lines += [row_line(row) for row in rows]
    packs = ("base",) + MODES
    lines += ["", "| scene | triangles | pack ms: " + " | ".join(packs) + " | sort ms per 1M |"]
    lines += ["|---|--:|" + "--:|" * (len(packs) + 1)]
    seen = set()
    for row in rows:
        if row["scene"] in seen:
            continue
        seen.add(row["scene"])
        pack = {mode: row["pack_ms"].get(mode, float("nan")) for mode in packs}
        per_million = (pack["morton"] - pack["file"]) * 1e6 / row["triangles"]
        lines.append(
            f"| {row['scene']} | {row['triangles']:,} | "
            + " | ".join(f"{pack[mode]:.0f}" for mode in packs)
            + f" | {per_million:.0f} |"
        )
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=description(__doc__))
    parser.add_argument("--scenes", default="sibenik,sponza", help="shared scenes (or none)")
    parser.add_argument("--rays", default="131072,1048576", help="batch sizes")
    parser.add_argument("--world", type=float, default=0, help="bench.world's triangles (0: no)")
    parser.add_argument("--repeats", type=int, default=5, help="timed rounds (medians)")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--seed", type=int, default=0, help="of the shuffle")
    parser.add_argument("--shared", type=Path, default=find_shared())
    parser.add_argument("--modes", default=",".join(MODES), help="of " + ", ".join(MODES))
    parser.add_argument("--baseline", type=Path, default=None, help="folder of dacrt_base")
    args = parser.parse_args(argv)
    modes = args.modes.split(",")
    use_kernel_cache()
    base = None
    if args.baseline:
        sys.path.insert(0, str(args.baseline))
        base = importlib.import_module("dacrt_base")
        base.warmup()
        modes = ["base", *modes]
    counts = [int(n) for n in args.rays.split(",")]
    dacrt.warmup()
    rows = []
    print(table([]).split("\n\n")[0], flush=True)
    for name in [n for n in args.scenes.split(",") if n and n != "none"]:
        path = args.shared / "scenes" / f"{name}.npz"
        vertices, faces = load_mesh(path)
        ray_sets = {n: camera_rays(vertices, faces, path, n) for n in counts}
        rows += compare(
            name, vertices, faces, ray_sets, args.repeats, args.threads, args.seed, modes, base
        )
    if args.world:
        start = time.perf_counter()
        world = build_world(args.shared / "scenes", int(args.world))
        seconds = time.perf_counter() - start
        print(f"world of {len(world.faces):,} triangles built in {seconds:.0f} s", flush=True)
        ray_sets = {n: world_rays(world.length, n) for n in counts}
        rows += compare(
            "world", world.vertices, world.faces, ray_sets, args.repeats, args.threads, args.seed,
            modes, base,
        )  # fmt: skip
    print()
    print(table(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
