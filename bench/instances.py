"""What transforms save a dynamic scene: 100 moving copies of one mesh, moved every frame.

    python -m bench.instances [--grid 71] [--copies 100] [--repeat 20] [--rays 1000]

One real uvicorn server on loopback holds two scenes of the same mesh (a bumpy ``--grid`` grid,
``2 * grid**2`` triangles: 10,082 with the default) placed ``--copies`` times:
  transforms  the mesh uploaded once and ``--copies`` instances of it; a frame is one
              ``POST .../frame`` .npz of ``carNNN.transform`` (4, 4) float64 matrices
  vertices    ``--copies`` meshes of their own; a frame is one ``POST .../frame`` .npz of
              ``carNNN.vertices`` (V, 3) float32, placed in numpy by the client beforehand
Every round moves every copy by new random rigid placements (the same in both scenes) and times,
side by side (the order swapped every round, after two untimed rounds), medians of ``--repeat``:
  frame           encoding the body, the request and the answer (the client's numpy placement of
                  the vertices, done before, is shown apart)
  frame + query   the frame, then ``closest`` of ``--rays`` rays: the first query of a version
                  builds its engine scene, which places the instances' vertices
and the bytes each frame sends. Both scenes' answers are checked against each other within the
rounding docs/engine.md states for instances, which are traced in their own space while the
placed copies are rounded to float32 ("How answers differ from placed copies"): where both hit
the same triangle, the hit lies within ACROSS_ULPS across the surface; elsewhere (hit or miss, or
another triangle) the ray passes within EDGE_ULPS of an edge of a triangle hit, or both hits lie on
one surface within ACROSS_ULPS. The run ends with how many rays differed.
"""

from __future__ import annotations

import argparse
import io
import statistics
import time

import httpx
import numpy as np

from bench.entry import description
from bench.http_overhead import cpu_model, start_server
from bench.persistence import grid

NPZ = {"Content-Type": "application/x-npz"}
NPY = {"Content-Type": "application/x-npy"}

#: docs/engine.md's bounds for an instance against its placed copy, in float32 ulps of the larger
#: of |origin| and |hit point|: a hit's position across the surface (|dt| |d| cos)...
ACROSS_ULPS = 8.0
#: ...and a ray's distance from an edge of the triangle hit, where hit or miss differs.
EDGE_ULPS = 16.0


def npz(**arrays: np.ndarray) -> bytes:
    out = io.BytesIO()
    np.savez(out, **arrays)
    return out.getvalue()


def placements(rng: np.random.Generator, n: int) -> np.ndarray:
    """(n, 4, 4) float64 rigid placements: a random rotation each, spread over a 40 x 40 area."""
    rotations, _ = np.linalg.qr(rng.normal(size=(n, 3, 3)))
    matrices = np.tile(np.eye(4), (n, 1, 1))
    matrices[:, :3, :3] = rotations
    matrices[:, :3, 3] = rng.uniform([-20, -20, -1], [20, 20, 1], (n, 3))
    return matrices


def place(vertices: np.ndarray, matrix: np.ndarray) -> np.ndarray:
    return (vertices.astype(np.float64) @ matrix[:3, :3].T + matrix[:3, 3]).astype(np.float32)


def ulps_at(origins: np.ndarray, directions: np.ndarray, t: np.ndarray) -> np.ndarray:
    """float32's spacing at max(|origin|, |origin + t d|) (max norms) of each ray, in float64."""
    point = origins + np.where(np.isfinite(t), t, 0.0)[:, None] * directions
    scale = np.maximum(np.abs(origins).max(axis=1), np.abs(point).max(axis=1))
    return np.spacing(scale.astype(np.float32)).astype(np.float64)


def edge_distance(corners: np.ndarray, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """Distance from each ray's line to the nearest edge of its triangle, (k, 3, 3) corners."""
    unit = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    nearest = np.full(len(origins), np.inf)
    for a, b in ((0, 1), (1, 2), (2, 0)):
        start, edge = corners[:, a], corners[:, b] - corners[:, a]
        # the closest points of the two lines, the edge's clamped to the segment
        ee, de = (edge * edge).sum(1), (unit * edge).sum(1)
        w = start - origins
        dw, ew = (unit * w).sum(1), (edge * w).sum(1)
        denom = ee - de * de
        s = np.clip(np.divide(de * dw - ew, denom, out=np.zeros_like(ee), where=denom > 0), 0, 1)
        r = start + s[:, None] * edge - origins
        across = r - (r * unit).sum(1)[:, None] * unit
        nearest = np.minimum(nearest, np.linalg.norm(across, axis=1))
    return nearest


def compare(got: dict, want: dict, origins, directions, placed) -> dict:
    """The instances' answers ``got`` against the placed copies' ``want`` (t, mesh, prim, normal
    of the same rays) within ACROSS_ULPS and EDGE_ULPS (the module's docstring); ``placed`` is
    [(vertices, faces)] of each mesh id as placed in scene space. Answers the counts of rays whose
    t, or whose hit or miss or triangle, differs, and the largest ulps of each; AssertionError
    naming the first ray beyond the bounds."""
    o, d = np.asarray(origins, np.float64), np.asarray(directions, np.float64)
    hit_got, hit_want = got["mesh"] >= 0, want["mesh"] >= 0
    both = hit_got & hit_want
    same = both & (got["mesh"] == want["mesh"]) & (got["prim"] == want["prim"])
    t_got, t_want = got["t"].astype(np.float64), want["t"].astype(np.float64)
    length = np.linalg.norm(d, axis=1)
    cos = np.abs((want["normal"].astype(np.float64) * d).sum(1)) / length
    across = np.full(len(o), np.inf)  # where both hit: |dt| |d| cos in ulps
    dt = np.abs(t_got[both] - t_want[both])
    across[both] = dt * length[both] * cos[both] / ulps_at(o[both], d[both], t_want[both])
    # where hit or miss or the triangle differs: the nearer edge of the two triangles hit
    other = np.flatnonzero((hit_got != hit_want) | (both & ~same))
    edge = np.full(len(other), np.inf)
    for answer in (got, want):
        hit = answer["mesh"][other] >= 0
        rays = other[hit]
        corners = np.array(
            [
                placed[m][0][placed[m][1][p]]
                for m, p in zip(answer["mesh"][rays], answer["prim"][rays])
            ],
            np.float64,
        ).reshape(-1, 3, 3)
        scale = ulps_at(o[rays], d[rays], answer["t"][rays].astype(np.float64))
        edge[hit] = np.minimum(edge[hit], edge_distance(corners, o[rays], d[rays]) / scale)
    one_surface = both[other] & (across[other] <= ACROSS_ULPS)
    wrong = np.concatenate(
        [
            np.flatnonzero(same & ~(across <= ACROSS_ULPS)),
            other[~one_surface & ~(edge <= EDGE_ULPS)],
        ]
    )
    if len(wrong):
        k = wrong[0]
        raise AssertionError(
            f"ray {k}: instances answer t={got['t'][k]} mesh {got['mesh'][k]} prim "
            f"{got['prim'][k]}, placed copies t={want['t'][k]} mesh {want['mesh'][k]} prim "
            f"{want['prim'][k]}: beyond docs/engine.md's rounding of instances ({ACROSS_ULPS:g} "
            f"ulps across the surface, {EDGE_ULPS:g} from an edge)"
        )
    return {
        "t": int(np.count_nonzero(same & (got["t"] != want["t"]))),
        "across_ulps": float(across[same].max(initial=0.0)),
        "other": len(other),
        "edge_ulps": float(edge[~one_surface].max(initial=0.0)),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=description(__doc__))
    parser.add_argument("--grid", type=int, default=71)
    parser.add_argument("--copies", type=int, default=100)
    parser.add_argument("--repeat", type=int, default=20)
    parser.add_argument("--rays", type=int, default=1000)
    args = parser.parse_args()
    rng = np.random.default_rng(7)
    vertices, faces = grid(args.grid)
    vertices[:, 2] = rng.uniform(0, 0.05, len(vertices))  # bumpy, so rotations matter
    names = [f"car{i:03}" for i in range(args.copies)]
    origins = np.zeros((args.rays, 3), np.float32) + np.float32([0, 0, 30])
    targets = rng.uniform([-20, -20, -1], [20, 20, 1], (args.rays, 3))
    directions = (targets - origins).astype(np.float32)
    rays = npz(origins=origins, directions=directions)
    process, url = start_server({"DACRT_LOAD_DEMO": "false"})
    seconds: dict[str, list[float]] = {
        f"{scene} {what}": [] for scene in ("transforms", "vertices") for what in ("frame", "+q")
    }
    sent: dict[str, int] = {}
    placing: list[float] = []
    worst: dict[str, float] = {}  # compare()'s figures, the largest of every round
    try:
        with httpx.Client(base_url=url, timeout=300) as http:
            first = placements(rng, args.copies)
            mesh = npz(vertices=vertices, faces=faces)
            for scene in ("transforms", "vertices"):  # "car" is mesh 0, copy i mesh i + 1
                http.put(f"/v1/scenes/{scene}/meshes/car", content=mesh, headers=NPZ)
            made = {f"{name}.instance_of": "car" for name in names}
            made |= {f"{name}.transform": m.tolist() for name, m in zip(names, first)}
            http.post("/v1/scenes/transforms/frame", json=made).raise_for_status()
            copies = {f"{name}.vertices": place(vertices, m) for name, m in zip(names, first)}
            copies |= {f"{name}.faces": faces for name in names}
            http.post("/v1/scenes/vertices/frame", content=npz(**copies), headers=NPZ)
            for round_ in range(args.repeat + 2):
                matrices = placements(rng, args.copies)
                start = time.perf_counter()
                moved = [place(vertices, m) for m in matrices]
                placing.append(time.perf_counter() - start)
                answers = {}
                order = ("transforms", "vertices") if round_ % 2 else ("vertices", "transforms")
                for scene in order:
                    start = time.perf_counter()
                    if scene == "transforms":
                        body = npz(**{f"{n}.transform": m for n, m in zip(names, matrices)})
                    else:
                        body = npz(**{f"{n}.vertices": v for n, v in zip(names, moved)})
                    http.post(f"/v1/scenes/{scene}/frame", content=body, headers=NPZ)
                    framed = time.perf_counter()
                    answer = http.post(f"/v1/scenes/{scene}/closest", content=rays, headers=NPZ)
                    done = time.perf_counter()
                    answer.raise_for_status()
                    answers[scene] = dict(np.load(io.BytesIO(answer.content)))
                    sent[scene] = len(body)
                    if round_ >= 2:
                        seconds[f"{scene} frame"].append(framed - start)
                        seconds[f"{scene} +q"].append(done - start)
                placed = [(vertices, faces), *((v, faces) for v in moved)]
                differ = compare(
                    answers["transforms"], answers["vertices"], origins, directions, placed
                )
                for key, value in differ.items():
                    worst[key] = max(worst.get(key, 0), value)
    finally:
        process.terminate()
        process.wait()
    print(
        f"{args.copies} copies of a {len(faces):,}-triangle mesh ({len(vertices):,} vertices) "
        f"moved by one POST .../frame, {args.repeat} rounds, medians; CPU: {cpu_model()}"
    )
    print(f"  {'':12s} {'frame':>10s} {'frame + query':>15s} {'bytes sent':>12s}")
    for scene in ("transforms", "vertices"):
        frame = 1000 * statistics.median(seconds[f"{scene} frame"])
        query = 1000 * statistics.median(seconds[f"{scene} +q"])
        print(f"  {scene:12s} {frame:8.2f} ms {query:12.2f} ms {sent[scene]:12,d}")
    print(
        f"  the client's numpy placement of the {args.copies} copies' vertices (vertices only): "
        f"{1000 * statistics.median(placing):.2f} ms; query: {args.rays} rays"
    )
    print(
        f"  answers, instances against placed copies, every round: t differs on at most "
        f"{worst['t']} rays (by up to {worst['across_ulps']:.1f} ulps across the surface), hit or "
        f"miss or the triangle on {worst['other']} (within {worst['edge_ulps']:.1f} ulps of an "
        f"edge, or on one surface): within docs/engine.md's rounding of instances"
    )


if __name__ == "__main__":
    main()
