"""Run under NUMBA_ENABLE_CUDASIM=1 (``test_cuda_sim``): dacrt.cuda's answers against the CPU
engine's on small scenes; prints ``ok`` and exits 0 when every answer is identical."""

import os
import sys
import warnings

import numpy as np

assert os.environ.get("NUMBA_ENABLE_CUDASIM") == "1", "run under Numba's CUDA simulator"

import dacrt  # noqa: E402
import dacrt.cache  # noqa: E402
from dacrt import cuda as dcuda  # noqa: E402
from dacrt.cuda import query as cuda_query  # noqa: E402
from dacrt.cuda import traversal  # noqa: E402
from dacrt.cuda.traversal import MAX_PAIRS as DEFAULT  # noqa: E402

# The CPU engine's kernels from the tests' cache (``conftest``), not compiled again.
dacrt.cache.use_cache_dir()


def soup(rng, n_tri):
    """Random triangles in the unit cube, two meshes; a few degenerate (a repeated corner)."""
    v = rng.random((3 * n_tri, 3)).astype(np.float32)
    v[3:30:9] = v[4:31:9]
    f = np.arange(3 * n_tri).reshape(-1, 3)
    half = 3 * (n_tri // 2)
    return [(v[:half], f[: n_tri // 2]), (v[half:], f[n_tri // 2 :] - half)]


def grid(k):
    """A k x k grid of quads in z = 0 split into triangles, plus a coplanar duplicate mesh."""
    xs, ys = np.meshgrid(np.arange(k + 1), np.arange(k + 1), indexing="ij")
    v = np.stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)], axis=1).astype(np.float32)
    faces = []
    for i in range(k):
        for j in range(k):
            a, b, c, d = i * (k + 1) + j, (i + 1) * (k + 1) + j, i * (k + 1) + j + 1, 0
            d = (i + 1) * (k + 1) + j + 1
            faces += [(a, b, d), (a, d, c)]
    f = np.array(faces)
    return [(v, f), (v.copy(), f[::-1].copy())]


def grid_rays(k, rng):
    """Rays down onto the grid through its vertices, edge middles and random points."""
    pts = [(i, j) for i in range(k + 1) for j in range(k + 1)]
    pts += [(i + 0.5, j) for i in range(k) for j in range(k + 1)]
    pts += [(i + 0.5, j + 0.5) for i in range(k) for j in range(k)]
    xy = np.array(pts, np.float32)
    xy = np.concatenate([xy, (rng.random((40, 2)) * k).astype(np.float32)])
    o = np.concatenate([xy, np.full((len(xy), 1), 2.0, np.float32)], axis=1)
    d = np.tile(np.array([[0, 0, -1]], np.float32), (len(o), 1))
    d[::3, :2] = 0.1 * (rng.random((len(d[::3]), 2)) - 0.5)
    return o, d


def random_rays(rng, n):
    o = (rng.random((n, 3)) * 1.4 - 0.2).astype(np.float32)
    d = (rng.random((n, 3)) - 0.5).astype(np.float32)
    return o, d


def same(name, a, b):
    """Exit 1 naming the first difference, bit for bit (NaN-free arrays)."""
    a, b = np.asarray(a), np.asarray(b)
    if a.shape != b.shape or a.tobytes() != b.tobytes():
        diff = np.flatnonzero((a != b).reshape(len(a), -1).any(axis=1))
        print(
            f"FAIL {name}: {len(diff)} rows differ, first {diff[:5]} {a[diff[:3]]} vs {b[diff[:3]]}"
        )
        sys.exit(1)


def compare(label, scene, o, d, max_pairs, **kw):
    cpu = scene.closest(o, d, **kw)
    gpu = dcuda.closest(scene, o, d, max_pairs=max_pairs, **kw)
    for field in ("t", "mesh", "prim", "u", "v", "normal"):
        same(f"{label} closest {field}", getattr(gpu, field), getattr(cpu, field))
    occ_cpu = scene.occluded(o, d, **kw).occluded
    occ_gpu = dcuda.occluded(scene, o, d, max_pairs=max_pairs, **kw).occluded
    if max_pairs == DEFAULT:
        # Scene's device="cuda" is dacrt.cuda with its default frontier size.
        by_scene = scene.closest(o, d, device="cuda", **kw)
        same(f"{label} Scene(device=cuda) t", by_scene.t, cpu.t)
        same(f"{label} Scene(device=cuda) prim", by_scene.prim, cpu.prim)
        same(
            f"{label} Scene(device=cuda) occluded",
            scene.occluded(o, d, device="cuda", **kw).occluded,
            occ_cpu,
        )
    same(f"{label} occluded", occ_gpu, occ_cpu)
    print(label, "hits", int((cpu.mesh >= 0).sum()), "of", len(o), flush=True)


def compare_crossings(label, scene, o, d, max_hits, by_scene=False, **kw):
    """count and hits (max_hits) against the CPU's; by_scene: through Scene(device="cuda")."""
    cpu = scene.count(o, d, **kw).count
    if by_scene:
        gpu = scene.count(o, d, device="cuda", **kw).count
    else:
        gpu = dcuda.count(scene, o, d, **kw).count
    same(f"{label} count", gpu, cpu)
    cpu_hits = scene.hits(o, d, max_hits=max_hits, **kw)
    if by_scene:
        gpu_hits = scene.hits(o, d, max_hits=max_hits, device="cuda", **kw)
    else:
        gpu_hits = dcuda.hits(scene, o, d, max_hits=max_hits, **kw)
    for field in ("offsets", "t", "mesh", "prim", "u", "v", "normal", "truncated"):
        a, b = getattr(gpu_hits, field), getattr(cpu_hits, field)
        assert a.dtype == b.dtype, (label, field, a.dtype, b.dtype)
        same(f"{label} hits {field}", a, b)
    print(
        label, "crossings", int(cpu.sum()), "kept", len(cpu_hits.t), "truncated",
        int(cpu_hits.truncated.sum()), flush=True,
    )  # fmt: skip
    return cpu


def affine(linear, offset):
    m = np.eye(4)
    m[:3, :3] = linear
    m[:3, 3] = offset
    return m


def rotation(rng):
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    return q * np.sign(np.linalg.det(q))


def check_placed_meshes(rng):
    """Placed meshes (instances traced in their mesh's space, merged on the host): closest,
    occluded, count and hits as the CPU's, bit for bit."""
    base, car = soup(rng, 60)
    placements = [
        None,
        affine(rotation(rng) * 0.5, (0.3, 0.2, 0.1)),
        affine(np.diag([-0.7, 0.6, 0.8]), (0.9, 0.4, 0.5)),  # mirrored: culling swaps
        affine(rotation(rng) @ np.diag([1.2, 0.4, 0.9]), (0.1, 0.8, 0.6)),
        affine(np.eye(3), (0.5, 0.5, 0.5)),
    ]
    meshes = [base] + [car] * 4  # one packing of the car, four placements
    masks = np.array([1, 2, 4, 2, 8], np.uint32)
    scene = dacrt.Scene(meshes, transforms=placements, masks=masks)
    o, d = random_rays(rng, 120)
    compare("placed", scene, o, d, DEFAULT)
    compare("placed batched", scene, o, d, 16)
    ray_masks = rng.integers(0, 16, len(o)).astype(np.uint32)
    for cull in ("back", "front"):
        compare(f"placed cull {cull}, masks", scene, o, d, DEFAULT, cull=cull, mask=ray_masks)
    # One mask for every ray: the base level traces the rows it sees, instances it does not see
    # take no rays.
    compare("placed, one mask", scene, o, d, DEFAULT, mask=6)
    tmin = (rng.random(len(o)) * 0.2).astype(np.float32)
    tmax = (0.2 + rng.random(len(o))).astype(np.float32)
    compare("placed tmin tmax", scene, o, d, DEFAULT, tmin=tmin, tmax=tmax)
    # Only placed meshes (no base rows), one of them moving (time=None: its start placement).
    only = dacrt.Scene([car, car], transforms=placements[1:3], transforms_end=[placements[4], None])
    compare("placed only, moving at 0", only, o, d, DEFAULT)
    # Rays at their own instants: the moving instance placed at each ray's time (on the host),
    # a placement mirrored at some instants and not others where culling swaps faces.
    times = rng.random(len(o)).astype(np.float32)
    flipping = dacrt.Scene(
        [base, car, car],
        transforms=[None, placements[1], placements[3]],
        transforms_end=[None, placements[2], placements[4]],
    )
    for cull in ("none", "back"):
        compare(f"moving, rays' times, cull {cull}", flipping, o, d, DEFAULT, time=times, cull=cull)
        compare_crossings(
            f"moving, rays' times, cull {cull}", flipping, o, d, 4, time=times, cull=cull
        )
    # A later version that moves the instances answers as a new Scene.
    moved = scene.with_changes(transforms={1: placements[3], 3: placements[1]})
    # The new version shares the earlier one's levels: nothing is uploaded again.
    uploads = []
    upload = cuda_query.upload_rows
    cuda_query.upload_rows = lambda verts, ids: uploads.append(len(ids)) or upload(verts, ids)
    compare("placed with_changes", moved, o, d, DEFAULT)
    cuda_query.upload_rows = upload
    assert uploads == [], uploads
    same(
        "with_changes on the GPU against a new Scene",
        moved.closest(o, d, device="cuda").t,
        dacrt.Scene(meshes, transforms=[None, placements[3], placements[2], placements[1],
                                        placements[4]], masks=masks).closest(o, d).t,
    )  # fmt: skip
    # The car modelled 1e4 units from its own origin and placed back: packed relative to its
    # box's centre, which the host's rays into mesh space (static and at the rays' times) take.
    shift = np.array([1e4, -6e3, 3e3])
    far_car = ((car[0] + shift).astype(np.float32), car[1])
    back = affine(np.eye(3), -shift)
    far = dacrt.Scene(
        [base, far_car, far_car],
        transforms=[None, placements[1] @ back, placements[2] @ back],
        transforms_end=[None, placements[3] @ back, None],
    )
    compare("modelled far", far, o, d, DEFAULT)
    compare("modelled far, rays' times", far, o, d, DEFAULT, time=times, cull="back")
    compare_crossings("modelled far, rays' times", far, o, d, 4, time=times)
    check_sensors(scene, rng)
    compare_crossings("placed", scene, o, d, 3, by_scene=True)
    compare_crossings("placed cull back, masks", scene, o, d, 16, cull="back", mask=ray_masks)
    compare_crossings("placed cull front, one mask", scene, o, d, 2, cull="front", mask=6)
    compare_crossings("placed tmin tmax", scene, o, d, 4, tmin=tmin, tmax=tmax)
    compare_crossings("placed only, moving at 0", only, o, d, 5)
    # A ray that leaves float32's range in a mesh's space is named with that mesh, as on the CPU.
    halved = dacrt.Scene(
        [base, car], transforms=[affine(np.eye(3), (5, 5, 0)), affine(np.eye(3) * 0.5, (0, 0, 0))]
    )
    far_o = np.array([[0.1, 0.1, 3e38], [0.1, 0.1, 5.0]], np.float32)
    far_d = np.array([[0, 0, -1], [0, 0, -1]], np.float32)
    for call in (halved.closest, halved.occluded):
        for device in ("cpu", "cuda"):
            try:
                call(far_o, far_d, device=device)
            except dacrt.MeshSpaceError as error:
                assert error.mesh == 1 and "space of mesh 1" in str(error), error
            else:
                raise AssertionError(f"{device}: a ray beyond float32 in a mesh space was traced")


def check_sensors(scene, rng):
    """A lidar (moving during its sweep: its rays carry times, which a scene where nothing moves
    ignores), a camera and a rig of both traced on the GPU: the CPU's answers, bit for bit."""
    from dacrt.sensors import Camera, Lidar, Rig, look_at_pose

    pose = np.eye(4)
    pose[:3, 3] = (0.45, 0.5, 0.55)
    pose_end = pose.copy()
    pose_end[:3, 3] += (0.05, 0.0, 0.0)
    lidar = Lidar(vertical_angles_deg=[-30, -10, 0, 10, 30], horizontal_steps=12, period_s=0.1)
    camera = Camera.from_fov(6, 5, fov_deg=60)
    eye = look_at_pose(eye=[1.6, 1.4, 1.5], target=[0.5, 0.5, 0.5], up=[0, 0, 1])
    cpu = lidar.scan(scene, pose, pose_end=pose_end)
    gpu = lidar.scan(scene, pose, pose_end=pose_end, device="cuda")
    assert list(gpu) == list(cpu) and cpu.n_points > 0, (list(gpu), cpu.n_points)
    for key in cpu:
        same(f"lidar {key}", gpu[key], cpu[key])
    cpu_image = camera.capture(scene, eye)
    gpu_image = camera.capture(scene, eye, device="cuda")
    for key in ("depth", "range", "mesh", "prim", "normal"):
        same(f"camera {key}", gpu_image[key], cpu_image[key])
    rig = Rig({"roof": lidar, "front": camera})
    poses = {"roof": pose, "front": eye}
    by_rig = rig.capture(scene, poses, poses_end={"roof": pose_end}, device="cuda")
    for key in cpu:
        same(f"rig lidar {key}", by_rig["roof"][key], cpu[key])
    same("rig camera depth", by_rig["front"]["depth"], cpu_image["depth"])
    print("sensors", cpu.n_points, "points,", int((cpu_image["mesh"] >= 0).sum()), "pixels hit")
    # A lidar sweeping a scene whose instances move: each ray at its instant.
    moving = scene.with_changes(transforms_end={1: affine(np.eye(3) * 0.5, (0.6, 0.5, 0.4))})
    cpu = lidar.scan(moving, pose, pose_end=pose_end)
    gpu = lidar.scan(moving, pose, pose_end=pose_end, device="cuda")
    for key in cpu:
        same(f"lidar in a moving scene {key}", gpu[key], cpu[key])
    # Times in a scene where nothing moves are checked and ignored, as on the CPU.
    o, d = random_rays(rng, 40)
    times = rng.random(len(o)).astype(np.float32)
    static = dacrt.Scene(soup(rng, 40))
    compare("time where nothing moves", static, o, d, DEFAULT, time=times)
    compare_crossings("time where nothing moves", static, o, d, 4, time=times)
    for bad in (1.5, np.float32(np.nan)):
        try:
            dcuda.count(static, o, d, time=bad)
        except ValueError as error:
            assert "time" in str(error), error
        else:
            raise AssertionError(f"time={bad} was accepted")


def main():
    # 0 * inf in the slab test is NaN by design (``geometry.intersect_box``); the simulator's
    # threads would warn of it.
    warnings.simplefilter("ignore", RuntimeWarning)
    rng = np.random.default_rng(7)
    scene = dacrt.Scene(soup(rng, 120), masks=np.array([1, 2], np.uint32))
    o, d = random_rays(rng, 80)
    compare("soup", scene, o, d, DEFAULT)
    # A frontier of at most n rays' slots is cut into runs of nodes.
    cut = traversal.cut
    runs = []
    traversal.cut = lambda frontier, limit: runs.append(cut(frontier, limit)) or runs[-1]
    compare("soup batched", scene, o, d, 16)
    traversal.cut = cut
    assert max(len(r) for r in runs) > 1, "no frontier was cut"
    # Hits behind the origin: negative t in the (t, triangle) keys.
    compare("soup negative tmin", scene, o, d, DEFAULT, tmin=-0.5)
    masks = rng.integers(0, 4, len(o)).astype(np.uint32)
    compare("soup cull back, masks", scene, o, d, DEFAULT, cull="back", mask=masks)
    tmin = (rng.random(len(o)) * 0.3).astype(np.float32)
    tmax = (0.3 + rng.random(len(o))).astype(np.float32)
    compare("soup cull front, tmin tmax", scene, o, d, DEFAULT, cull="front", tmin=tmin, tmax=tmax)
    crossed = compare_crossings("soup", scene, o, d, 3, by_scene=True)
    assert crossed.max() > 3, "no list was truncated"
    compare_crossings("soup cull back, masks", scene, o, d, 16, cull="back", mask=masks)
    compare_crossings(
        "soup cull front, tmin tmax", scene, o, d, 2, cull="front", tmin=tmin, tmax=tmax
    )
    k = 4
    g = dacrt.Scene(grid(k))
    go, gd = grid_rays(k, rng)
    compare("grid", g, go, gd, DEFAULT)
    compare("grid tmax at hit", g, go, gd, DEFAULT, tmax=2.0)
    # Through vertices and edges each mesh is crossed once; the duplicate ties in t (mesh order).
    crossed = compare_crossings("grid", g, go, gd, 1)
    assert (crossed[: (k + 1) ** 2] == 2).any() and (crossed == 1).sum() == 0, crossed
    compare_crossings("grid tmax at hit", g, go, gd, 4, tmax=2.0)
    # float64 bounds float32 cannot hold round inward on the host, for both: no hit at t = 2.
    inner_o = np.float32([[0.3, 0.6, 2.0], [1.7, 2.2, 2.0]])
    inner_d = np.float32([[0, 0, -1], [0, 0, -1]])
    assert (dcuda.closest(g, inner_o, inner_d, tmax=2.0).t == 2).all()
    for bounds in (
        {"tmax": 1.99999999},
        {"tmin": 2.00000001},
        {"tmin": 2.00000001, "tmax": 2.00000002},
    ):
        compare(f"grid float64 {bounds}", g, go, gd, DEFAULT, **bounds)
        compare_crossings(f"grid float64 {bounds}", g, go, gd, 4, **bounds)
        assert (dcuda.closest(g, inner_o, inner_d, **bounds).mesh == -1).all(), bounds
        assert (dcuda.count(g, inner_o, inner_d, **bounds).count == 0).all(), bounds
    # A mesh of mask 0 is hidden from rays with the default mask, as from every ray.
    hidden = dacrt.Scene(soup(rng, 120), masks=np.array([0, 1], np.uint32))
    compare("mesh mask 0, default ray mask", hidden, o, d, DEFAULT)
    seen = compare_crossings("mesh mask 0, default ray mask", hidden, o, d, 16, by_scene=True)
    assert seen.sum() < compare_crossings("both meshes", scene, o, d, 16, mask=3).sum()

    # tmax at a hit's own t keeps the hit where a box's entry rounds one step above that t.
    def bits(*words):
        return np.array([float.fromhex(w) for w in words], np.float32)

    tri = bits(
        "0x1.2d0048p+0", "0x1.c623p+0", "0x1.7704fap+1", "0x1.79cd14p+0", "0x1.c623p+0",
        "0x1.7704fap+1", "0x1.2d0048p+0", "0x1.0977e6p+1", "0x1.7704fap+1",
    ).reshape(3, 3)  # fmt: skip
    ro = bits("0x1.2a1c4ep+0", "0x1.198d7ap+1", "0x1.d33334p+2").reshape(1, 3)
    rd = bits("0x1.83eba4p-8", "-0x1.16b53ep-3", "-0x1.c8dc76p+0").reshape(1, 3)
    copies = [tri + np.float32([10 * (k > 0) + 2 * k, 0, 0]) for k in range(9)]
    nine = dacrt.Scene([(np.concatenate(copies), np.arange(27).reshape(-1, 3))])
    at_hit = nine.closest(ro, rd).t
    assert np.isfinite(at_hit).all()
    compare("tmax at a rounded box entry", nine, ro, rd, DEFAULT, tmax=at_hit)
    compare_crossings("tmax at a rounded box entry", nine, ro, rd, 2, tmax=at_hit)
    assert dcuda.closest(nine, ro, rd, tmax=at_hit).mesh[0] == 0
    # A hit beyond float32's range (t would round to inf) is a miss, as on the CPU.
    square = np.array([[-1, -1, 0], [2, -1, 0], [2, 2, 0], [-1, 2, 0]], np.float32)
    flat = dacrt.Scene([(square, np.array([[0, 1, 2], [0, 2, 3]], np.int32))])
    far_z = [(-1.0, 1e-45), (-1.0, 2e-39), (-1e30, 1e-9), (-1.0, 1e-37), (-1e30, 1e-8)]
    fo = np.array([[0.25, 0.25, z] for z, _ in far_z], np.float32)
    fd = np.array([[0, 0, dz] for _, dz in far_z], np.float32)
    for tmax in (None, np.full(len(fo), np.inf, np.float32)):
        compare("beyond float32", flat, fo, fd, DEFAULT, tmax=tmax)
        compare_crossings("beyond float32", flat, fo, fd, 2, tmax=tmax)
        hit = dcuda.closest(flat, fo, fd, tmax=tmax).mesh >= 0
        assert hit.tolist() == [False, False, False, True, True], hit
    # A component whose 1/d overflows (d_x = 1e-40) beside the box plane x = 0, in a level the
    # GPU tests without a box and the CPU with one: both keep the hit at t = 1.
    corner = np.float32([[0, 0, 0], [1, 0, 0], [0, 1, 0]])
    one = dacrt.Scene([(corner, np.int32([[0, 1, 2]]))])
    to, td = np.float32([[-1.4e-45, 0.3, 1]]), np.float32([[1e-40, 0, -1]])
    compare("1/d overflows", one, to, td, DEFAULT)
    compare_crossings("1/d overflows", one, to, td, 2)
    assert dcuda.closest(one, to, td).t.tolist() == [1.0]
    check_placed_meshes(rng)
    # No rays, and a scene without triangles.
    none = np.zeros((0, 3), np.float32)
    assert len(dcuda.count(scene, none, none)) == 0
    empty_hits = dcuda.hits(scene, none, none, max_hits=2)
    assert len(empty_hits) == 0 and list(empty_hits.offsets) == [0]
    empty = dacrt.Scene([(np.zeros((0, 3), np.float32), np.zeros((0, 3), int))])
    compare_crossings("no triangles", empty, o[:3], d[:3], 2)
    # Lists beyond the device bound are traced in chunks of rays that fit: 3 rays a chunk.
    bound = cuda_query.MAX_LIST_BYTES
    cuda_query.MAX_LIST_BYTES = 8 * 3 * (3 + 1)
    compare_crossings("lists in chunks", scene, o, d, 3)
    cuda_query.MAX_LIST_BYTES = bound
    # No rays, and a bad ray: the CPU engine's answer and error.
    assert len(dcuda.closest(scene, np.zeros((0, 3)), np.zeros((0, 3)))) == 0
    d[3] = 0.0
    try:
        dcuda.occluded(scene, o, d)
    except ValueError as error:
        assert "directions[3] is zero" in str(error), error
    else:
        raise AssertionError("a zero direction was accepted")
    print("ok")


if __name__ == "__main__":
    main()
