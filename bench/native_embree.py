"""Per frame against native Embree: dacrt's new scene + trace beside the C++ anchor of the shared
folder (``anchors/embree_native.cpp``: Embree 3, a fresh build at low or medium quality or a refit
of moved vertices, then ``rtcIntersect1`` / ``rtcOccluded1`` on every thread).

The anchor is compiled on first use (``g++``, Debian's ``libembree-dev`` and ``libtbb-dev``) into
``--build-dir``. For each scene and ray kind it is fed the same rays as dacrt, its answers are
checked against dacrt's (hit or not, and t), and a frame of each quality is its build + trace (the
minimum over its repetitions); Embree's best frame is the best of low, medium and refit, the
choice a C++ user would make. dacrt's frame is ``dacrt.Scene`` + the query, the median and the
minimum of ``--repeat`` frames on ``--threads`` threads, run between the anchor's runs; its
refit is the previous frame's scene ``with_changes(vertices=...)`` (a new copy of the
vertices every frame) + the query: the same faces keep their storage order, as a refit keeps
its hierarchy. The first frame of each (new Scene and refit) is untimed, and the kernels are
filed where ``dacrt.cache.use_cache_dir()`` puts them.
``--baseline DIR`` also times the ``dacrt`` package in DIR (an earlier copy of the engine),
alternating with this one, and adds its frames and this engine's speed-up over it.

``--rays`` takes several counts (each its own rows, same seed); after the table, one summary row
per count gives the geometric mean of Embree best / dacrt over the scenes and kinds.

    python -m bench.native_embree ../shared/scenes/sibenik.npz --rays 1000000 --threads 2
    python -m bench.native_embree ../shared/scenes/sibenik.npz --rays 65536,131072,1000000

``bench.plots`` draws the same anchor's best frame (``anchor_frames``) beside the other engines.
"""

from __future__ import annotations

import argparse
import importlib.util
import shutil
import subprocess
import sys
import tempfile
import time
from collections import namedtuple
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from bench import rays as R
from bench.entry import description, use_kernel_cache
from bench.run import KINDS, int_list, make_ray_sets, reference_tracer
from bench.scene_io import load_mesh, load_view, mesh_bounds

ANCHOR = Path(__file__).resolve().parents[2] / "shared" / "anchors" / "embree_native.cpp"
BUILD_DIR = Path.home() / ".cache" / "dacrt-bench"
QUALITIES = ("low", "medium", "refit")


class AnchorUnavailable(RuntimeError):
    """The anchor cannot be compiled here (no source, no g++, or no Embree 3 headers)."""


def build_anchor(source: Path = ANCHOR, build_dir: Path = BUILD_DIR) -> Path:
    """The anchor's executable (named as ``source``'s stem: ``embree_native``,
    ``embree_instances``), compiled from ``source`` unless it is there and newer."""
    binary = build_dir / source.stem
    if not source.exists():
        if binary.exists():
            return binary
        raise AnchorUnavailable(f"no anchor source at {source}")
    if binary.exists() and binary.stat().st_mtime >= source.stat().st_mtime:
        return binary
    build_dir.mkdir(parents=True, exist_ok=True)
    command = ["g++", "-O3", "-march=native", "-std=c++17", str(source), "-o", str(binary)]
    command += ["-lembree3", "-lpthread"]
    try:
        result = subprocess.run(command, capture_output=True, text=True)
    except FileNotFoundError as exc:
        raise AnchorUnavailable(f"no compiler: {exc}") from exc
    if result.returncode:
        raise AnchorUnavailable(
            f"building the anchor failed (apt-get install -y libembree-dev libtbb-dev):\n"
            f"{result.stderr.strip()}"
        )
    return binary


def write_inputs(folder: Path, vertices, faces, rays: R.RaySet) -> None:
    n = rays.n_rays
    table = np.empty((n, 8), np.float32)
    table[:, :3] = rays.origins
    table[:, 3:6] = rays.directions
    table[:, 6] = 0.0
    table[:, 7] = rays.tmax
    np.ascontiguousarray(vertices, np.float32).tofile(folder / "vertices.f32")
    np.ascontiguousarray(faces, np.int32).tofile(folder / "faces.i32")
    table.tofile(folder / "rays.f32")
    (folder / "query.txt").write_text(rays.query)


def run_anchor(binary: Path, folder: Path, quality: str, threads: int, reps: int):
    """(build ms, trace ms, the anchor's t) of one quality."""
    result = subprocess.run(
        [str(binary), str(folder), quality, str(threads), str(reps)],
        capture_output=True,
        text=True,
        check=True,
    )
    build_ms, trace_ms = (float(x) for x in result.stdout.split()[:2])
    return build_ms, trace_ms, np.fromfile(folder / "t.f32", np.float32)


def anchor_frames(binary: Path, folder: Path, vertices, faces, rays: R.RaySet, threads, reps):
    """{quality: (build ms, trace ms, t)} of every quality of QUALITIES on the same inputs."""
    write_inputs(folder, vertices, faces, rays)
    # refit's first repetition is a fresh build: only later ones refit
    reps = max(2, reps)
    return {q: run_anchor(binary, folder, q, threads, reps) for q in QUALITIES}


def best_quality(frames: dict) -> str:
    """The quality of the fastest frame (build + trace) of {quality: (build ms, trace ms, ...)}."""
    return min(frames, key=lambda q: frames[q][0] + frames[q][1])


def dacrt_frame(dacrt, vertices, faces, rays: R.RaySet, threads: int, previous=None):
    """(ms, t) of a frame: a new Scene, or with ``previous`` (a Scene of the same faces) its
    ``with_changes`` to ``vertices``, then the query."""
    start = time.perf_counter()
    if previous is None:
        scene = dacrt.Scene([(vertices, faces)])
    else:
        scene = previous.with_changes(vertices={0: vertices})
    if rays.query == R.CLOSEST:
        answer = scene.closest(rays.origins, rays.directions, tmax=rays.tmax, threads=threads)
        t = answer.t
    else:
        answer = scene.occluded(rays.origins, rays.directions, tmax=rays.tmax, threads=threads)
        t = np.where(answer.occluded, 0.0, np.inf).astype(np.float32)
    return (time.perf_counter() - start) * 1e3, t


def load_baseline(folder: Path):
    """The ``dacrt`` package in ``folder`` imported as ``dacrt_baseline``, beside this one."""
    spec = importlib.util.spec_from_file_location(
        "dacrt_baseline", folder / "__init__.py", submodule_search_locations=[str(folder)]
    )
    module = importlib.util.module_from_spec(spec)
    sys.modules["dacrt_baseline"] = module
    spec.loader.exec_module(module)
    return module


def agreement(ours: np.ndarray, theirs: np.ndarray, diagonal: float) -> float:
    """Fraction of rays with the same hit or miss and, for hits, t within 1e-4 of the diagonal."""
    same_hit = np.isfinite(ours) == np.isfinite(theirs)
    both = np.isfinite(ours) & np.isfinite(theirs)
    close = np.ones_like(same_hit)
    close[both] = np.abs(ours[both] - theirs[both]) <= 1e-4 * diagonal
    return float(np.mean(same_hit & close))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=description(__doc__))
    parser.add_argument("scenes", nargs="+")
    parser.add_argument(
        "--rays", type=int_list, default=[1_000_000], help="comma list of ray counts per kind"
    )
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--kinds", default=",".join(KINDS))
    parser.add_argument("--anchor", type=Path, default=ANCHOR)
    parser.add_argument("--build-dir", type=Path, default=BUILD_DIR)
    parser.add_argument(
        "--baseline", type=Path, default=None, help="a dacrt package folder to time alongside"
    )
    args = parser.parse_args(argv)
    kinds = args.kinds.split(",")
    if not args.rays or min(args.rays) < 1:
        parser.error("--rays takes positive counts")

    import dacrt

    baseline = load_baseline(args.baseline) if args.baseline else None
    use_kernel_cache()  # this copy's kernels; a --baseline copy keeps Numba's own rule
    try:
        binary = build_anchor(args.anchor, args.build_dir)
    except AnchorUnavailable as exc:
        raise SystemExit(str(exc)) from exc
    extra = " baseline ms | baseline / dacrt |" if baseline else ""
    print(
        "| scene | kind | rays | dacrt ms (median, min) | Embree low | medium | refit "
        "(build + trace ms) | Embree best / dacrt | dacrt refit ms (median, min) | Embree best "
        f"/ dacrt refit | agree |{extra}"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|" + ("---|---|" if baseline else ""))
    rows_of = {n: [] for n in args.rays}  # compare()'s answer for each row, by ray count
    for path in args.scenes:
        vertices, faces = load_mesh(path)
        bounds = mesh_bounds(vertices, faces)
        _, view = load_view(path, bounds)
        _, trace = reference_tracer(vertices, faces)
        options = SimpleNamespace(seed=0, bounces=[1])
        diagonal = R.scene_diagonal(bounds)
        folder = Path(tempfile.mkdtemp(prefix="native-embree-"))
        try:
            for n_rays in args.rays:
                for rays in make_ray_sets(options, view, bounds, trace, n_rays, kinds):
                    row = compare(
                        dacrt, binary, folder, vertices, faces, rays, diagonal, args, baseline
                    )
                    rows_of[n_rays].append(row)
                    cells = " | ".join(f"{b:.1f} + {t:.1f}" for b, t in row.frames.values())
                    extra = ""
                    if row.base_ms:
                        speedup = np.median(row.base_ms) / np.median(row.ours_ms)
                        extra = f" {np.median(row.base_ms):.1f} | {speedup:.2f} |"
                    print(
                        f"| {Path(path).stem} | {rays.kind} | {rays.n_rays} "
                        f"| {np.median(row.ours_ms):.1f}, {min(row.ours_ms):.1f} | {cells} "
                        f"| {row.ratio:.2f} | {np.median(row.refit_ms):.1f}, "
                        f"{min(row.refit_ms):.1f} | {row.refit_ratio:.2f} | {row.agree:.5f} "
                        f"|{extra}",
                        flush=True,
                    )
        finally:
            shutil.rmtree(folder, ignore_errors=True)
    print()
    print(
        "| rays | rows | Embree best / dacrt, geometric mean (lowest–highest) | Embree best / "
        "dacrt refit | agree |"
    )
    print("|---|---|---|---|---|")
    for n_rays, rows in rows_of.items():
        spans = []
        for values in ([row.ratio for row in rows], [row.refit_ratio for row in rows]):
            values = np.array(values)
            mean = np.exp(np.mean(np.log(values)))
            spans.append(f"{mean:.2f} ({values.min():.2f}–{values.max():.2f})")
        print(
            f"| {n_rays} | {len(rows)} | {spans[0]} | {spans[1]} "
            f"| {min(row.agree for row in rows):.5f} |"
        )
    return 0


Row = namedtuple("Row", "ratio refit_ratio agree ours_ms refit_ms frames base_ms")
Row.__doc__ = """One ray set: Embree's best frame over dacrt's median new-Scene frame and its median
refit frame, the worst agreement of dacrt's answers with Embree's, dacrt's frames (ms), Embree's
{quality: (build ms, trace ms)} and the baseline's new-Scene frames (ms) or None."""


def compare(dacrt, binary, folder, vertices, faces, rays: R.RaySet, diagonal, args, baseline):
    """The ``Row`` of one ray set; dacrt's frames (new Scene and refit, and the baseline's new
    Scene, alternating, whose answers must equal dacrt's) run between the anchor's runs."""
    write_inputs(folder, vertices, faces, rays)
    ours_ms, refit_ms, base_ms, frames, agree = [], [], [], {}, []
    engines = [(dacrt, ours_ms)] + ([(baseline, base_ms)] if baseline else [])
    answers = [dacrt_frame(engine, vertices, faces, rays, args.threads)[1] for engine, _ in engines]
    if baseline and not np.array_equal(answers[0], answers[1]):
        raise SystemExit(f"the baseline's answers differ from dacrt's ({rays.kind})")
    previous = dacrt.Scene([(vertices, faces)])

    def refit():
        fresh = np.array(vertices)  # a new array every frame, as a simulation hands over
        ms, t = dacrt_frame(dacrt, fresh, faces, rays, args.threads, previous)
        if not np.array_equal(t, answers[0]):
            raise SystemExit(f"dacrt's refit answers differ from its new Scene's ({rays.kind})")
        refit_ms.append(ms)

    # the first refit compiles with_changes' kernels where the cache lacks them: untimed
    dacrt_frame(dacrt, np.array(vertices), faces, rays, args.threads, previous)
    reps = max(2, args.repeat)  # refit's first repetition is a fresh build: only later ones refit
    for quality in QUALITIES:
        for engine, times in engines:
            ms, ours = dacrt_frame(engine, vertices, faces, rays, args.threads)
            times.append(ms)
        refit()
        build_ms, trace_ms, theirs = run_anchor(binary, folder, quality, args.threads, reps)
        frames[quality] = (build_ms, trace_ms)
        agree.append(agreement(ours, theirs, diagonal))
    for _ in range(max(0, args.repeat - len(QUALITIES))):
        for engine, times in engines:
            times.append(dacrt_frame(engine, vertices, faces, rays, args.threads)[0])
        refit()
    best = sum(frames[best_quality(frames)])
    return Row(
        best / np.median(ours_ms),
        best / np.median(refit_ms),
        min(agree),
        ours_ms,
        refit_ms,
        frames,
        base_ms or None,
    )


if __name__ == "__main__":
    raise SystemExit(main())
