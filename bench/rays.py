"""Ray generators of the benchmark protocol (docs: ../../shared/BENCHMARKS.md, "Ray kinds").

Pure numpy, seeded, and independent of any engine: generators that start from hit points take
the hit distances and normals as arrays; the diffuse bounces take a ``trace`` callable so the
caller chooses the engine that finds the previous bounce's hits.

Conventions (the same for dacrt, Embree and Open3D):
- a ray is ``origin + t * direction`` with ``0 <= t <= tmax``; every generator returns
  float32, C-contiguous ``origins`` and ``directions`` of shape (n, 3) and a scalar ``tmax``.
  Embree's ``run`` has no ``tmin`` and Open3D's ``test_occlusions`` takes only scalar bounds,
  so ``tmin`` is always 0 and ``tmax`` is one scalar per ray set.
- secondary rays start at the hit point moved by ``eps`` along the normal flipped to face the
  incoming ray, so they do not hit the surface they start on.
- shadow rays start only from points that face the light; their directions are
  ``light - origin`` (not unit length), so the light sits at t = 1 for every ray and one
  scalar ``tmax`` just below 1 stops short of it.
- a kind built from hit points needs as many hit points as rays: when some of the previous
  rays missed, hit points are drawn again (with replacement) until there are ``n``, kept in the
  order of the rays they came from so that coherent sets stay coherent.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

#: closest-hit or any-hit query
CLOSEST = "closest"
OCCLUDED = "occluded"

#: offset of secondary origins along the normal, relative to the scene diagonal
EPS_REL = 1e-4
#: reach of ambient-occlusion rays, relative to the scene diagonal (BENCHMARKS.md)
AO_REACH_REL = 0.1
#: shadow rays stop this far short of the light, in units of the origin-to-light distance
SHADOW_SHORT = 1e-4

# a trace callable: (origins (n,3) f32, directions (n,3) f32) -> (t (n,) inf on a miss,
# normals (n,3))
TraceFn = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]


@dataclass
class RaySet:
    """One batch of rays of one kind.

    kind : str                    name of the kind, e.g. "primary", "diffuse-b2"
    query : str                   CLOSEST or OCCLUDED
    origins : (n, 3) float32
    directions : (n, 3) float32   not necessarily unit length
    tmax : float                  the same for every ray (inf for closest-hit kinds)
    """

    kind: str
    query: str
    origins: np.ndarray
    directions: np.ndarray
    tmax: float = float("inf")

    @property
    def n_rays(self) -> int:
        return len(self.origins)


def _f32(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float32)


def scene_diagonal(bounds: np.ndarray) -> float:
    """Length of the diagonal of (2, 3) ``bounds`` [[min], [max]]."""
    bounds = np.asarray(bounds, dtype=np.float64)
    return float(np.linalg.norm(bounds[1] - bounds[0]))


# --- sampling on spheres and hemispheres -------------------------------------------------------


def orthonormal_basis(normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit tangents (n, 3) completing unit ``normals`` (n, 3) to a right-handed frame.

    Branchless construction of Duff et al. 2017, "Building an orthonormal basis, revisited".
    """
    x, y, z = normals[:, 0], normals[:, 1], normals[:, 2]
    sign = np.where(z >= 0.0, 1.0, -1.0)
    a = -1.0 / (sign + z)
    b = x * y * a
    t1 = np.stack([1.0 + sign * x * x * a, sign * b, -sign * x], axis=1)
    t2 = np.stack([b, sign + y * y * a, -y], axis=1)
    return t1, t2


def _to_world(local: np.ndarray, normals: np.ndarray) -> np.ndarray:
    t1, t2 = orthonormal_basis(normals)
    return local[:, :1] * t1 + local[:, 1:2] * t2 + local[:, 2:3] * normals


def uniform_sphere(n: int, rng: np.random.Generator) -> np.ndarray:
    """(n, 3) float64 unit vectors uniform on the sphere."""
    z = 1.0 - 2.0 * rng.random(n)
    phi = 2.0 * np.pi * rng.random(n)
    r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def uniform_hemisphere(normals: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """(n, 3) unit vectors uniform on the hemispheres around unit ``normals`` (n, 3)."""
    n = len(normals)
    z = rng.random(n)
    phi = 2.0 * np.pi * rng.random(n)
    r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    local = np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)
    return _to_world(local, normals)


def cosine_hemisphere(normals: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """(n, 3) unit vectors with density cos(theta)/pi around unit ``normals`` (n, 3)."""
    n = len(normals)
    u = rng.random(n)
    phi = 2.0 * np.pi * rng.random(n)
    r = np.sqrt(u)
    local = np.stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(np.maximum(0.0, 1.0 - u))], axis=1)
    return _to_world(local, normals)


# --- hit points ---------------------------------------------------------------------------------


@dataclass
class HitPoints:
    """Surface points that secondary rays start from.

    points : (m, 3) float64   already moved off the surface by eps along ``normals``
    normals : (m, 3) float64  unit, facing the ray that found the point
    """

    points: np.ndarray
    normals: np.ndarray

    def __len__(self) -> int:
        return len(self.points)


def hit_points(
    origins: np.ndarray, directions: np.ndarray, t: np.ndarray, normals: np.ndarray, eps: float
) -> HitPoints:
    """Offset hit points of the rays that hit (finite ``t``), in ray order.

    origins, directions : (n, 3) float   the rays that were traced
    t : (n,) float                       hit distance, inf (or >= 1e30, Embree's miss) on a miss
    normals : (n, 3) float               geometric normals of the hits, any length and side
    eps : float                          offset along the facing normal, in scene units
    """
    t = np.asarray(t, dtype=np.float64)
    hit = np.isfinite(t) & (t < 1e30)
    o = np.asarray(origins, dtype=np.float64)[hit]
    d = np.asarray(directions, dtype=np.float64)[hit]
    nrm = np.asarray(normals, dtype=np.float64)[hit]
    length = np.linalg.norm(nrm, axis=1)
    good = length > 0.0  # a zero normal would give no side; drop the point
    o, d, nrm, th, length = o[good], d[good], nrm[good], t[hit][good], length[good]
    nrm /= length[:, None]
    nrm *= np.where(np.einsum("ij,ij->i", nrm, d) > 0.0, -1.0, 1.0)[
        :, None
    ]  # face the incoming ray
    p = o + th[:, None] * d + eps * nrm
    return HitPoints(p, nrm)


def resample(hits: HitPoints, n: int, rng: np.random.Generator) -> HitPoints:
    """Exactly ``n`` hit points: all of ``hits`` plus random repeats, in the original order."""
    m = len(hits)
    if m == 0:
        raise ValueError("no ray hit the scene: cannot start secondary rays (check the view)")
    if m >= n:
        idx = np.arange(n)
    else:
        idx = np.sort(np.concatenate([np.arange(m), rng.integers(0, m, n - m)]), kind="stable")
    return HitPoints(hits.points[idx], hits.normals[idx])


# --- the ray kinds --------------------------------------------------------------------------------


def camera_frame(eye, target, up) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unit (forward, right, up) vectors of a pinhole camera at ``eye`` looking at ``target``."""
    eye, target, up = (np.asarray(v, dtype=np.float64) for v in (eye, target, up))
    forward = target - eye
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, up)
    norm = np.linalg.norm(right)
    if norm == 0.0:
        raise ValueError("camera 'up' is parallel to the viewing direction")
    right /= norm
    return forward, right, np.cross(right, forward)


def image_size(n_rays: int) -> tuple[int, int]:
    """A near-square (width, height) with width * height >= ``n_rays``."""
    width = int(np.ceil(np.sqrt(n_rays)))
    return width, int(np.ceil(n_rays / width))


def primary_rays(
    view: dict,
    width: int,
    height: int,
    rng: np.random.Generator,
    jitter: bool = True,
    n_rays: int | None = None,
) -> RaySet:
    """Pinhole camera rays, one per pixel, row by row from the top left; unit directions.

    view : dict with "eye", "target", "up" (3 floats each) and "fov_deg" (vertical field of view)
    width, height : int   image size in pixels
    jitter : bool         a uniform random position inside each pixel, else the pixel centre
    n_rays : int | None   keep only the first n_rays (for counts that are not width * height)
    """
    forward, right, up = camera_frame(view["eye"], view["target"], view["up"])
    tan_half = np.tan(np.radians(float(view["fov_deg"])) / 2.0)
    aspect = width / height
    n = width * height
    pix = np.arange(n)
    col, row = pix % width, pix // width
    du, dv = (rng.random(n), rng.random(n)) if jitter else (np.full(n, 0.5), np.full(n, 0.5))
    x = (2.0 * (col + du) / width - 1.0) * tan_half * aspect
    y = (1.0 - 2.0 * (row + dv) / height) * tan_half
    d = forward[None, :] + x[:, None] * right[None, :] + y[:, None] * up[None, :]
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    o = np.broadcast_to(np.asarray(view["eye"], dtype=np.float64), d.shape)
    if n_rays is not None:
        o, d = o[:n_rays], d[:n_rays]
    return RaySet("primary", CLOSEST, _f32(o), _f32(d))


def shadow_rays(hits: HitPoints, light, n: int, rng: np.random.Generator) -> RaySet:
    """Occlusion rays from ``n`` hit points to the point ``light``; the light is at t = 1.

    Only points whose surface faces the light start a ray, as in a renderer (N.L <= 0 gets no light
    and would give rays that stop at once on their own surface); all points if none faces it.
    """
    light = np.asarray(light, dtype=np.float64)
    facing = np.einsum("ij,ij->i", hits.normals, light[None, :] - hits.points) > 0.0
    if facing.any():
        hits = HitPoints(hits.points[facing], hits.normals[facing])
    hits = resample(hits, n, rng)
    d = light[None, :] - hits.points
    return RaySet("shadow", OCCLUDED, _f32(hits.points), _f32(d), tmax=1.0 - SHADOW_SHORT)


def ao_rays(hits: HitPoints, reach: float, n: int, rng: np.random.Generator) -> RaySet:
    """Occlusion rays, uniform on the hemisphere of each of ``n`` hit points, up to ``reach``."""
    hits = resample(hits, n, rng)
    d = uniform_hemisphere(hits.normals, rng)
    return RaySet("ao", OCCLUDED, _f32(hits.points), _f32(d), tmax=float(reach))


def diffuse_rays(
    hits: HitPoints, n: int, rng: np.random.Generator, kind: str = "diffuse"
) -> RaySet:
    """Closest-hit rays, cosine-weighted around the normal of each of ``n`` hit points."""
    hits = resample(hits, n, rng)
    d = cosine_hemisphere(hits.normals, rng)
    return RaySet(kind, CLOSEST, _f32(hits.points), _f32(d))


def diffuse_bounces(
    primary: RaySet,
    primary_t: np.ndarray,
    primary_normals: np.ndarray,
    trace: TraceFn,
    n_bounces: int,
    eps: float,
    rng: np.random.Generator,
) -> list[RaySet]:
    """Diffuse rays of bounces 1..n_bounces, each of ``primary.n_rays`` rays.

    Bounce 1 starts from the primary hits; bounce k > 1 from the hits of bounce k - 1,
    which ``trace`` finds (it is not called for the last bounce).
    """
    n = primary.n_rays
    sets = []
    hits = hit_points(primary.origins, primary.directions, primary_t, primary_normals, eps)
    for bounce in range(1, n_bounces + 1):
        rays = diffuse_rays(hits, n, rng, kind=f"diffuse-b{bounce}")
        sets.append(rays)
        if bounce < n_bounces:
            t, normals = trace(rays.origins, rays.directions)
            hits = hit_points(rays.origins, rays.directions, t, normals, eps)
    return sets


def random_rays(bounds: np.ndarray, n: int, rng: np.random.Generator) -> RaySet:
    """Closest-hit rays, origins uniform in the (2, 3) ``bounds`` box, directions uniform on the
    sphere."""
    bounds = np.asarray(bounds, dtype=np.float64)
    o = bounds[0] + rng.random((n, 3)) * (bounds[1] - bounds[0])
    return RaySet("random", CLOSEST, _f32(o), _f32(uniform_sphere(n, rng)))
