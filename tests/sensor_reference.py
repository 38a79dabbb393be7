"""Plain-NumPy re-derivations of the sensors' rules as docs/sensors.md states them, for the tests
of ``dacrt.sensors``: the rays of cameras, spinning lidars and patterns, a beam's sub-rays, ray-
plane hits, intensity, returns, noise and dropout. Nothing here imports dacrt or the service; the
loops are deliberately simple."""

from __future__ import annotations

import math

import numpy as np

#: The data sheets' vertical angles, written out here independently of dacrt.
PUBLISHED = {
    "VLP-16": [-15, -13, -11, -9, -7, -5, -3, -1, 1, 3, 5, 7, 9, 11, 13, 15],
    "HDL-32E": [round((4 * k - 92) / 3, 2) for k in range(32)],
    "HDL-64E": [2 - k / 3 for k in range(32)] + [-53 / 6 - k / 2 for k in range(32)],
    "OS1-64": [-22.5 + 45 * k / 63 for k in range(64)],
    "OS1-128": [-22.5 + 45 * k / 127 for k in range(128)],
}


def rigid_pose(yaw_deg: float, pitch_deg: float, position) -> np.ndarray:
    """A 4x4 rigid pose: a rotation about z by yaw, then about the rotated y by pitch."""
    yaw, pitch = math.radians(yaw_deg), math.radians(pitch_deg)
    rz = np.array(
        [[math.cos(yaw), -math.sin(yaw), 0], [math.sin(yaw), math.cos(yaw), 0], [0, 0, 1]]
    )
    ry = np.array(
        [[math.cos(pitch), 0, math.sin(pitch)], [0, 1, 0], [-math.sin(pitch), 0, math.cos(pitch)]]
    )
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = rz @ ry, position
    return pose


def lidar_rays(pose, elevations_deg, steps):
    """(origins, directions, ring, azimuth, elevation) of one revolution, ray ring * steps + step:
    rings sorted from the lowest elevation, azimuth a = 2 pi step / steps, direction
    cos e (cos a R[:, 0] + sin a R[:, 1]) + sin e R[:, 2] in float64, then float32."""
    pose = np.asarray(pose, np.float64)
    elevation = np.radians(np.sort(np.asarray(elevations_deg, np.float64), kind="stable"))
    azimuth = 2 * np.pi * np.arange(steps) / steps
    ring = np.repeat(np.arange(len(elevation)), steps)
    e, a = elevation[ring], np.tile(azimuth, len(elevation))
    return (*angle_rays(pose, a, e), ring, a, e)


def angle_rays(pose, azimuth, elevation):
    """(origins, directions) float32 of rays at the given float64 angles (radians)."""
    rotation = np.asarray(pose, np.float64)[:3, :3]
    level = np.cos(azimuth)[:, None] * rotation[:, 0] + np.sin(azimuth)[:, None] * rotation[:, 1]
    directions = np.cos(elevation)[:, None] * level + np.sin(elevation)[:, None] * rotation[:, 2]
    origins = np.tile(np.asarray(pose)[:3, 3], (len(directions), 1)).astype(np.float32)
    return origins, directions.astype(np.float32)


def pinhole_rays(fx, fy, cx, cy, pose, width, height):
    """(origins, directions) of an OpenCV pinhole: camera-frame direction ((j - cx) / fx,
    (i - cy) / fy, 1) of pixel (i, j), mapped as x R[:, 0] + (y R[:, 1] + R[:, 2])."""
    pose = np.asarray(pose, np.float64)
    rotation = pose[:3, :3]
    i, j = np.meshgrid(np.arange(height), np.arange(width), indexing="ij")
    x = ((j - cx) / fx).reshape(-1, 1)
    y = ((i - cy) / fy).reshape(-1, 1)
    directions = (x * rotation[:, 0] + (y * rotation[:, 1] + rotation[:, 2])).astype(np.float32)
    origins = np.tile(pose[:3, 3], (len(directions), 1)).astype(np.float32)
    return origins, directions


def look_at(eye, target, up, fov_deg, height):
    """(pose, focal) of a look-at camera: z along target - eye, x along z x up, y = z x x,
    f = (height / 2) / tan(fov / 2)."""
    eye, target, up = (np.asarray(v, np.float64) for v in (eye, target, up))
    forward = (target - eye) / np.linalg.norm(target - eye)
    right = np.cross(forward, up / np.linalg.norm(up))
    right /= np.linalg.norm(right)
    pose = np.eye(4)
    pose[:3, 0], pose[:3, 1], pose[:3, 2], pose[:3, 3] = (
        right,
        np.cross(forward, right),
        forward,
        eye,
    )
    return pose, (height / 2) / math.tan(math.radians(fov_deg) / 2)


def subray_directions(pose, azimuth, elevation, divergence_deg, samples):
    """(samples, 3) float64 unit sub-rays of one beam: sub-ray k leans from the axis d by
    (divergence / 2) sqrt(k / (samples - 1)) toward the angle k pi (3 - sqrt 5) around it, from u
    (z x d normalised: growing azimuth) toward v = d x u (growing elevation)."""
    d = np.array(
        [
            math.cos(elevation) * math.cos(azimuth),
            math.cos(elevation) * math.sin(azimuth),
            math.sin(elevation),
        ]
    )
    u = np.cross([0.0, 0.0, 1.0], d)
    u /= np.linalg.norm(u)
    v = np.cross(d, u)
    rays = []
    for k in range(samples):
        lean = math.radians(divergence_deg) / 2 * math.sqrt(k / max(samples - 1, 1))
        around = k * math.pi * (3 - math.sqrt(5))
        local = math.cos(lean) * d + math.sin(lean) * (math.cos(around) * u + math.sin(around) * v)
        rays.append(np.asarray(pose, np.float64)[:3, :3] @ local)
    return np.array(rays)


def hit_rectangle(origin, direction, corner, side_a, side_b):
    """t (float64, inf on a miss) of the ray on the parallelogram corner + s a + r b, s and r in
    [0, 1], and its unit normal a x b."""
    normal = np.cross(side_a, side_b)
    denominator = np.dot(direction, normal)
    if denominator == 0:
        return math.inf, normal / np.linalg.norm(normal)
    t = np.dot(np.asarray(corner) - origin, normal) / denominator
    point = origin + t * np.asarray(direction) - corner
    s = np.dot(point, side_a) / np.dot(side_a, side_a)
    r = np.dot(point, side_b) / np.dot(side_b, side_b)
    inside = t >= 0 and 0 <= s <= 1 and 0 <= r <= 1
    return (t if inside else math.inf), normal / np.linalg.norm(normal)


def intensity(reflectivity, cos_incidence, distance, attenuation):
    return reflectivity * cos_incidence * math.exp(-attenuation * distance)


def beam_returns(hits, samples, resolution):
    """The returns of one beam from its sub-ray hits [(t, subray, mesh, contribution)]: sorted by
    (t, subray), a new return wherever t exceeds the previous hit's by more than resolution (every
    hit its own return with one sub-ray); each return as (t, mesh, intensity) of its lowest
    sub-ray's hit, intensity the sum / samples."""
    hits = sorted(hits)
    groups = []
    for hit in hits:
        if samples > 1 and groups and hit[0] - groups[-1][-1][0] <= resolution:
            groups[-1].append(hit)
        else:
            groups.append([hit])
    returns = []
    for group in groups:
        reporter = min(group, key=lambda h: (h[1], h[0]))
        returns.append((reporter[0], reporter[2], sum(h[3] for h in group) / samples))
    return returns


def pick_returns(returns, mode, max_returns=1):
    """Indices of the returns (nearest first) that a mode keeps."""
    if not returns:
        return []
    strongest = max(range(len(returns)), key=lambda k: (returns[k][2], -k))
    last = len(returns) - 1
    return {
        "first": [0],
        "last": [last],
        "strongest": [strongest],
        "dual": sorted({strongest, last}),
        "all": list(range(min(max_returns, len(returns)))),
    }[mode]


def noisy_ranges(ranges, range_sigma, range_sigma_per_m, seed, n_beams=0, angle_sigma=0.0):
    """float32 max(r + (sigma + sigma_per_m r) z, 0), z = standard normals of
    default_rng(seed) drawn after (n_beams, 2) angle deviates when angle_sigma > 0; a range
    beyond float32's largest is no return (NaN here)."""
    generator = np.random.default_rng(seed)
    if angle_sigma > 0:
        generator.normal(0.0, math.radians(angle_sigma), (n_beams, 2))
    r = ranges.astype(np.float64)
    z = generator.standard_normal(len(r))
    noisy = np.maximum(r + (range_sigma + range_sigma_per_m * r) * z, 0)
    return np.where(noisy <= np.finfo(np.float32).max, noisy, np.nan).astype(np.float32)


def kept_by_dropout(intensity_values, rate, min_intensity, seed):
    u = np.random.default_rng(seed).random(len(intensity_values))
    return (intensity_values >= min_intensity) & (u >= rate)


def read_pcd(data: bytes):
    """(header dict, structured array) of a binary PCD v0.7 file, parsed by hand."""
    header, offset = {}, 0
    while True:
        end = data.index(b"\n", offset)
        line = data[offset:end].decode("ascii")
        offset = end + 1
        if line.startswith("#"):
            continue
        key, _, value = line.partition(" ")
        header[key] = value.split()
        if key == "DATA":
            break
    letters = {"F": "f", "I": "i", "U": "u"}
    dtype = np.dtype(
        [
            (name, f"<{letters[kind]}{size}")
            for name, kind, size in zip(header["FIELDS"], header["TYPE"], header["SIZE"])
        ]
    )
    n = int(header["POINTS"][0])
    return header, np.frombuffer(data, dtype, count=n, offset=offset)
