"""Python client of the service: NumPy arrays in, NumPy arrays out, over httpx.

    from service.client import Client
    with Client("http://127.0.0.1:8000") as client:
        client.put_mesh("demo", "box", vertices, faces)        # (V,3) float, (F,3) int
        hits = client.closest("demo", origins, directions)    # (N,3) each, or one (N,6|8) array
        hits.t, hits.mesh, hits.version                        # arrays, and the scene version
        every = client.hits("demo", origins, directions, max_hits=8)
        every.t[every.offsets[i]:every.offsets[i + 1]]         # the hits of ray i, nearest first
        client.count("demo", origins, directions, mask=0b10).count  # crossings, masked rays
        client.frame("demo", {"box": {"transform_end": matrix}})  # moves over the frame
        client.closest("demo", origins, directions, time=times)  # each ray at its time in [0, 1]
        client.put_instance("demo", "box2", "box", matrix)      # shares box's arrays
        client.set_mask("demo", "box2", 0b10), client.mesh("demo", "box2")  # mesh info
        points = client.lidar("demo", pose=pose, model="VLP-16", return_mode="dual")
        points.xyz, points.intensity, points.label                # the body's keys as arguments
        both = client.sensors("demo", {"roof": {"kind": "lidar", ...}, "front": {...}})
        both["roof"].xyz, both["front"].depth                     # one batch, one version

Binary by default (.npy rays in, or .npz with per-ray masks or times; .npz answers out); arrays
are converted to the wire dtypes (float32, int32) here, so any float or int arrays may be
passed, but nothing is rounded or wrapped on the way: faces must be whole numbers within int32,
a pattern's channels within its range, a ray's time within [0, 1], and a JSON body's numbers
finite (ValueError naming the argument). Names are sent as one path segment each, checked as the
server checks them. Errors raise ``APIError`` with the HTTP status and the server's message
(also for a redirect, or an answer that cannot be read); a connection that fails or times out
raises httpx's ``TransportError``. ``read_answer`` gives an answer's arrays, in any format, with
the keys, dtypes and values of its .npz answer.
Requests go through httpx on urllib3's connection pool (``transport.PooledTransport``), which
reads big answers at half httpx's own cost.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import httpx
import numpy as np

from dacrt.sensors.patterns import MAX_CHANNEL

from . import wire
from .errors import ServiceError
from .store import NAME
from .timing import parse_server_timing
from .transport import PooledTransport

#: dtype of every answer key, for answers read from JSON.
ANSWER_DTYPES = {
    "t": np.float32,
    "mesh": np.int32,
    "prim": np.int32,
    "u": np.float32,
    "v": np.float32,
    "normal": np.float32,
    "occluded": np.bool_,
    "offsets": np.int64,
    "truncated": np.bool_,
    "count": np.int32,
    "distance": np.float32,
    "point": np.float32,
    "inside": np.bool_,
    "signed_distance": np.float32,
    "xyz": np.float32,
    "range": np.float32,
    "ring": np.uint16,
    "azimuth": np.float32,
    "elevation": np.float32,
    "return": np.int16,
    "cos_incidence": np.float32,
    "ray": np.int32,
    "intensity": np.float32,
    "label": np.uint32,
    "time": np.float32,
    "velocity": np.float32,
    "radial_speed": np.float32,
    "depth": np.float32,
}
#: Answer keys whose JSON null is NaN (a lidar's fill where nothing returned); every other null is
#: inf, and ``signed_distance``'s takes its sign from ``inside``.
NAN_KEYS = ("xyz", "velocity", "radial_speed")
#: Answer keys of three columns, shaped (0, 3) when empty as in the binary answers.
ROW_KEYS = ("normal", "point", "xyz", "velocity")
_SUFFIX_FORMATS = {
    ".obj": "obj",
    ".ply": "ply",
    ".stl": "stl",
    ".glb": "glb",
    ".off": "off",
    ".npz": "npz",
    ".json": "json",
}


class APIError(Exception):
    """An error answer: ``status`` (e.g. 422) and the server's ``detail`` message."""

    def __init__(self, status: int, detail: str, response: httpx.Response | None = None) -> None:
        super().__init__(f"{status}: {detail}")
        self.status, self.detail, self.response = status, detail, response


class Answer(Mapping):
    """The arrays of a query answer (``answer["t"]`` or ``answer.t``) with its headers' facts."""

    def __init__(
        self,
        arrays: dict[str, np.ndarray],
        version: int,
        timing: dict[str, float],
        stats: dict[str, Any] | None,
    ) -> None:
        self.arrays = arrays
        self.version = version  #: X-Scene-Version: the scene version the answer was computed on
        self.timing = timing  #: Server-Timing in ms: receive, decode, trace, encode
        self.stats = stats  #: X-Trace-Stats (with stats=True), else None

    def __getitem__(self, key: str) -> np.ndarray:
        return self.arrays[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self.arrays)

    def __len__(self) -> int:
        return len(self.arrays)

    def __getattr__(self, key: str) -> np.ndarray:
        try:
            return self.__dict__["arrays"][key]
        except KeyError:
            raise AttributeError(key) from None

    def __repr__(self) -> str:
        shapes = ", ".join(f"{k}={v.dtype}{v.shape}" for k, v in self.arrays.items())
        return f"Answer(version={self.version}, {shapes})"


def rays_array(
    origins: Any, directions: Any = None, tmin: Any = None, tmax: Any = None
) -> np.ndarray:
    """One (N, 6) or (N, 8) float32 ray array from origins + directions (+ tmin, tmax), or as
    given. ValueError naming the argument for a shape the engine would refuse (one ray is
    (1, 3), not (3,)): nothing is broadcast."""
    if directions is None:
        rays = _numbers(origins, "origins")
        if rays.ndim != 2 or rays.shape[1] not in (6, 8):
            raise ValueError(
                f"without directions, origins must be (N, 6) or (N, 8) rays, got {rays.shape}"
            )
        if tmin is None and tmax is None:
            return np.ascontiguousarray(rays, dtype="<f4")
        origins, directions = rays[:, 0:3], rays[:, 3:6]
        if rays.shape[1] == 8:
            tmin = rays[:, 6] if tmin is None else tmin
            tmax = rays[:, 7] if tmax is None else tmax
    origins, directions = _ray_rows(origins, directions)
    has_t = tmin is not None or tmax is not None
    rays = np.empty((len(origins), 8 if has_t else 6), dtype="<f4")
    rays[:, 0:3], rays[:, 3:6] = origins, directions
    if has_t:
        rays[:, 6] = 0.0 if tmin is None else _ray_bound(tmin, len(rays), "tmin")
        rays[:, 7] = np.inf if tmax is None else _ray_bound(tmax, len(rays), "tmax")
    return rays


def _numbers(value: Any, name: str) -> np.ndarray:
    """``value`` as a numeric array; ValueError naming ``name`` for strings, booleans, objects."""
    array = np.asarray(value)
    if array.dtype.kind not in "fiu":
        raise ValueError(f"{name} must be numbers, got dtype {array.dtype}")
    return array


def _ray_rows(origins: Any, directions: Any) -> tuple[np.ndarray, np.ndarray]:
    """origins and directions as (n, 3) arrays of one length, as the engine checks them."""
    rows = []
    for value, name in ((origins, "origins"), (directions, "directions")):
        array = _numbers(value, name)
        if array.ndim != 2 or array.shape[1] != 3:
            raise ValueError(f"{name} must have shape (n, 3), got {array.shape}")
        rows.append(array)
    if len(rows[0]) != len(rows[1]):
        raise ValueError(f"origins has {len(rows[0])} rows but directions has {len(rows[1])}")
    return rows[0], rows[1]


def _ray_bound(value: Any, n_rays: int, name: str) -> np.ndarray:
    """tmin or tmax: a scalar (every ray) or (n_rays,); ValueError naming ``name`` otherwise."""
    array = _numbers(value, name)
    if array.ndim != 0 and array.shape != (n_rays,):
        raise ValueError(
            f"{name} must be a scalar or have shape ({n_rays},), one per ray, got {array.shape}"
        )
    return array


def _ray_time(value: Any, n_rays: int) -> np.ndarray:
    """Each ray's time as little-endian float32 (n_rays,) from a scalar (every ray) or (n_rays,)
    values, each finite and in [0, 1] as given (before rounding to float32), as the engine checks
    them; ValueError naming ``time`` or its first bad entry ``time[i]`` otherwise."""
    given = _ray_bound(value, n_rays, "time").astype(np.float64)
    given = np.broadcast_to(given, (n_rays,))
    bad = np.flatnonzero(~((given >= 0) & (given <= 1)))  # NaN fails both
    if len(bad):
        raise ValueError(
            f"time[{bad[0]}] is {given[bad[0]]}: each time must be finite and in [0, 1] "
            f"({len(bad)} rays)"
        )
    return np.ascontiguousarray(given, dtype="<f4")


class Client:
    """A connection to one service; use as a context manager or call ``close()``."""

    def __init__(
        self,
        base_url: str = "http://127.0.0.1:8000",
        token: str | None = None,
        timeout: float = 600.0,
        http: httpx.Client | None = None,
    ) -> None:
        headers = {"Authorization": f"Bearer {token}"} if token else {}
        # urllib3 reads big answers more cheaply than httpx's own transport (transport.py)
        self.http = http or httpx.Client(
            base_url=base_url, timeout=timeout, transport=PooledTransport()
        )
        self.http.headers.update(headers)

    def close(self) -> None:
        self.http.close()

    def __enter__(self) -> Client:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ---- plumbing

    def request(self, method: str, path: str, **kwargs: Any) -> httpx.Response:
        """Send a request; raise APIError for any error status."""
        response = self.http.request(method, path, **kwargs)
        if response.status_code >= 300:  # a redirect is no answer: the path was not the API's
            raise _api_error(response)
        return response

    def fetch(self, method: str, path: str, **kwargs: Any) -> tuple[httpx.Response, memoryview]:
        """Send a request and read its body into one buffer (``wire.BodyBuffer``, cheaper than
        ``response.content`` for big answers); raise APIError for any error status."""
        with self.http.stream(method, path, **kwargs) as response:
            if response.status_code >= 300:
                response.read()
                raise _api_error(response)
            declared = response.headers.get("content-length", "")
            encoded = response.headers.get("content-encoding", "identity") != "identity"
            body = wire.BodyBuffer(int(declared) if declared.isdigit() and not encoded else None)
            for chunk in response.iter_bytes():
                body.add(chunk)
        return response, body.finish()

    @staticmethod
    def _binary_body(
        arrays: Mapping[str, np.ndarray], fmt: str, kwargs: dict[str, Any]
    ) -> dict[str, Any]:
        """Request arguments sending arrays as one .npy (a single array) or .npz body: headers
        around the arrays' memory."""
        parts = wire.npy_parts(arrays) if fmt == "npy" else wire.npz_parts(arrays)
        headers = {
            "Content-Type": wire.MEDIA_TYPES[fmt],
            "Content-Length": str(sum(len(part) for part in parts)),
            **kwargs.pop("headers", {}),
        }
        return {"content": _slices(parts), "headers": headers, **kwargs}

    def _binary(
        self,
        method: str,
        path: str,
        arrays: Mapping[str, np.ndarray],
        fmt: str = "npz",
        **kwargs: Any,
    ) -> httpx.Response:
        return self.request(method, path, **self._binary_body(arrays, fmt, kwargs))

    def _query(
        self, path: str, arrays: Mapping[str, np.ndarray], fmt: str, **kwargs: Any
    ) -> Answer:
        response, body = self.fetch("POST", path, **self._binary_body(arrays, fmt, kwargs))
        return _answer(response, body)

    # ---- operations

    def health(self) -> dict[str, Any]:
        """``{"status": "ok" | "starting" | "error", ...}`` (no exception for 503; an answer
        that is not the service's JSON is ``{"status": "error", "detail": its text}``)."""
        response = self.http.get("/health")
        try:
            body = response.json()
        except ValueError:
            body = None
        if not isinstance(body, dict) or "status" not in body:
            return {"status": "error", "http_status": response.status_code, "detail": response.text}
        return body

    def capabilities(self) -> dict[str, Any]:
        return self.request("GET", "/v1/capabilities").json()

    def metrics(self) -> str:
        """``GET /metrics``: the Prometheus text (requests, rays traced, trace seconds, scene
        memory)."""
        return self.request("GET", "/metrics").text

    # ---- scenes and meshes

    def scenes(self) -> list[dict[str, Any]]:
        return self.request("GET", "/v1/scenes").json()["scenes"]

    def scene(self, scene: str) -> dict[str, Any]:
        return self.request("GET", f"/v1/scenes/{_seg(scene)}").json()

    def put_mesh(
        self,
        scene: str,
        mesh: str,
        vertices: Any = None,
        faces: Any = None,
        *,
        file: str | Path | bytes | None = None,
        format: str | None = None,
        mask: int | None = None,
    ) -> dict[str, Any]:
        """Add or replace a mesh from arrays, or from a file (path or bytes; ``format`` is
        obj/ply/stl/glb/off, or npz/json for a mesh body saved as a file, taken from the path's
        suffix if not given). ``mask`` is the mesh's 32-bit visibility mask (default all ones).
        Answers mesh info."""
        path = f"/v1/scenes/{_seg(scene)}/meshes/{_seg(mesh, 'mesh')}"
        params = {} if mask is None else {"mask": str(_mask_value(mask, "mask"))}
        if file is None:
            if vertices is None:
                raise ValueError("give vertices and faces, or file= (a mesh file)")
            return self._binary(
                "PUT",
                path,
                {"vertices": np.asarray(vertices, dtype="<f4"), "faces": _faces(faces)},
                params=params,
            ).json()
        if isinstance(file, (str, Path)):
            suffix = Path(file).suffix.lower()
            format = format or _SUFFIX_FORMATS.get(suffix)
            if format is None:
                raise ValueError(
                    f"give format= ({', '.join(wire.MESH_FORMATS)}): the suffix {suffix!r} "
                    "names none"
                )
            file = Path(file).read_bytes()
        if format is None:
            raise ValueError(
                f"give format= ({', '.join(wire.MESH_FORMATS)}) for a mesh file given as bytes"
            )
        format = _choice(str(format).lower(), "format", wire.MESH_FORMATS)
        return self.request(
            "PUT",
            path,
            content=file,
            params={"format": format, **params},
            headers={"Content-Type": wire.MEDIA_TYPES[format]},
        ).json()

    def update_vertices(self, scene: str, mesh: str, vertices: Any) -> dict[str, Any]:
        """New positions for a mesh's vertices (same count); answers mesh info."""
        return self._binary(
            "PUT",
            f"/v1/scenes/{_seg(scene)}/meshes/{_seg(mesh, 'mesh')}/vertices",
            {"vertices": np.asarray(vertices, dtype="<f4")},
            "npy",
        ).json()

    def set_transform(self, scene: str, mesh: str, matrix: Any) -> dict[str, Any]:
        """Place a mesh with a 4x4 row-major affine ``matrix`` (an instance: the mesh is not
        sent again). Answers mesh info."""
        matrix = np.asarray(matrix, dtype=np.float64)
        return self.request(
            "PUT",
            f"/v1/scenes/{_seg(scene)}/meshes/{_seg(mesh, 'mesh')}/transform",
            json=_json_ready({"matrix": matrix}),
        ).json()

    def frame(self, scene: str, meshes: Mapping[str, Any]) -> dict[str, Any]:
        """Change several meshes in one version: ``{name: vertices}`` moves a mesh,
        ``{name: (vertices, faces)}`` adds or replaces one, and ``{name: {part: value}}`` sets
        any of its parts (``wire.FRAME_PARTS``): ``vertices`` (V, 3), ``faces`` (F, 3),
        ``transform`` 4x4, ``mask``, ``reflectivity``, ``label``, ``instance_of`` (a mesh
        name), and its placement at the frame's end, ``transform_end`` 4x4 or ``vertices_end``
        (V, 3) (docs/API.md, "Frames"). Sent as ``.npz`` keys ``NAME.PART``, or as JSON when a
        mesh has ``instance_of`` (text, which an ``.npz`` cannot hold). Answers scene info."""
        arrays: dict[str, Any] = {}
        for name, value in meshes.items():
            where = f"meshes[{name!r}]"
            if isinstance(value, Mapping):
                parts = dict(value)
            elif isinstance(value, tuple):
                if len(value) != 2:
                    raise ValueError(f"{where} is a tuple of {len(value)}: give (vertices, faces)")
                parts = {"vertices": value[0], "faces": value[1]}
            else:
                parts = {"vertices": value}
            for part, item in parts.items():
                if part not in wire.FRAME_PARTS:
                    known = ", ".join(wire.FRAME_PARTS)
                    raise ValueError(f"{where} has {part!r}, not a part of a frame: {known}")
                arrays[f"{name}.{part}"] = _frame_part(part, item, f"{where} {part}")
        path = f"/v1/scenes/{_seg(scene)}/frame"
        if any(isinstance(value, str) for value in arrays.values()):  # instance_of is text
            return self.request("POST", path, json=_json_ready(arrays)).json()
        return self._binary("POST", path, arrays).json()

    def mesh(self, scene: str, mesh: str) -> dict[str, Any]:
        """One mesh's info."""
        return self.request("GET", f"/v1/scenes/{_seg(scene)}/meshes/{_seg(mesh, 'mesh')}").json()

    def put_instance(
        self,
        scene: str,
        mesh: str,
        source: str,
        transform: Any = None,
        *,
        mask: int | None = None,
    ) -> dict[str, Any]:
        """Add or replace ``mesh`` as an instance of the mesh ``source`` of the same scene: it
        shares ``source``'s arrays, placed by a 4x4 row-major ``transform`` (default the
        identity), with its own ``mask`` (default all ones). Answers mesh info."""
        body: dict[str, Any] = {"instance_of": _seg(source, "source mesh")}
        if transform is not None:
            body["transform"] = np.asarray(_numbers(transform, "transform"), dtype=np.float64)
        params = {} if mask is None else {"mask": str(_mask_value(mask, "mask"))}
        return self.request(
            "PUT",
            f"/v1/scenes/{_seg(scene)}/meshes/{_seg(mesh, 'mesh')}",
            json=_json_ready(body),
            params=params,
        ).json()

    def set_mask(self, scene: str, mesh: str, mask: int) -> dict[str, Any]:
        """Set a mesh's 32-bit visibility mask alone; answers mesh info."""
        return self.request(
            "PUT",
            f"/v1/scenes/{_seg(scene)}/meshes/{_seg(mesh, 'mesh')}/mask",
            json={"mask": _mask_value(mask, "mask")},
        ).json()

    def set_material(
        self, scene: str, mesh: str, reflectivity: float | None = None, label: int | None = None
    ) -> dict[str, Any]:
        """Set a mesh's ``reflectivity`` (in [0, 1]) and/or ``label`` (uint32); answers mesh
        info."""
        body = {"reflectivity": reflectivity, "label": label}
        body = {key: value for key, value in body.items() if value is not None}
        return self.request(
            "PUT",
            f"/v1/scenes/{_seg(scene)}/meshes/{_seg(mesh, 'mesh')}/material",
            json=_json_ready(body),
        ).json()

    def delete(self, scene: str) -> None:
        self.request("DELETE", f"/v1/scenes/{_seg(scene)}")

    def delete_mesh(self, scene: str, mesh: str) -> None:
        self.request("DELETE", f"/v1/scenes/{_seg(scene)}/meshes/{_seg(mesh, 'mesh')}")

    # ---- queries

    def closest(
        self,
        scene: str,
        origins: Any,
        directions: Any = None,
        tmin: Any = None,
        tmax: Any = None,
        *,
        time: Any = None,
        **options: Any,
    ) -> Answer:
        """Nearest hit per ray: t, mesh, prim, u, v, normal (see ``query`` for the options)."""
        return self.query(scene, "closest", origins, directions, tmin, tmax, time=time, **options)

    def occluded(
        self,
        scene: str,
        origins: Any,
        directions: Any = None,
        tmin: Any = None,
        tmax: Any = None,
        *,
        time: Any = None,
        **options: Any,
    ) -> Answer:
        """Whether each ray hits anything in [tmin, tmax]: ``answer.occluded``."""
        return self.query(scene, "occluded", origins, directions, tmin, tmax, time=time, **options)

    def hits(
        self,
        scene: str,
        origins: Any,
        directions: Any = None,
        tmin: Any = None,
        tmax: Any = None,
        max_hits: int | None = None,
        *,
        time: Any = None,
        **options: Any,
    ) -> Answer:
        """Every hit of each ray, nearest first, at most ``max_hits`` (the server's default 16):
        CSR ``offsets`` (N+1) with t, mesh, prim, u, v, normal per hit, ``truncated`` per ray.
        The hits of ray i are ``answer.t[answer.offsets[i]:answer.offsets[i + 1]]``."""
        return self.query(
            scene,
            "hits",
            origins,
            directions,
            tmin,
            tmax,
            max_hits=max_hits,
            time=time,
            **options,
        )

    def count(
        self,
        scene: str,
        origins: Any,
        directions: Any = None,
        tmin: Any = None,
        tmax: Any = None,
        *,
        time: Any = None,
        **options: Any,
    ) -> Answer:
        """How many triangles each ray crosses in [tmin, tmax]: ``answer.count``, int32 (N,)."""
        return self.query(scene, "count", origins, directions, tmin, tmax, time=time, **options)

    def query(
        self,
        scene: str,
        query: str,
        origins: Any,
        directions: Any = None,
        tmin: Any = None,
        tmax: Any = None,
        *,
        fields: Any = None,
        strategy: str | None = None,
        stats: bool = False,
        cull: str = "none",
        mask: Any = None,
        max_hits: int | None = None,
        time: Any = None,
        answer: str = "npz",
    ) -> Answer:
        """A query (closest, occluded, hits or count) on a stored scene. ``origins`` may be a
        whole (N, 6|8) ray array when ``directions`` is None. ``cull`` is none, back or front.
        ``mask`` is one 32-bit mask for every ray (sent as ``?mask=``) or (N,) masks (sent in an
        .npz body). ``time`` is each ray's instant in the frame's interval, one value or (N,),
        in [0, 1] (default 0: the scene's start placements; sent in an .npz body), for meshes
        that move (``frame``'s ``transform_end``, ``vertices_end``). ``max_hits`` is for hits
        only. ``answer`` is npz, npy or json (the format the server writes)."""
        _choice(query, "query", QUERIES)
        rays = rays_array(origins, directions, tmin, tmax)
        params = _params(fields, strategy, stats, cull)
        if max_hits is not None:
            params["max_hits"] = str(max_hits)
        ray_masks = mask is not None and np.ndim(mask) != 0
        if mask is not None and not ray_masks:
            params["mask"] = str(_mask_value(mask, "mask"))
        body, fmt = {"rays": rays}, "npy"
        if ray_masks or time is not None:
            body, fmt = _ray_arrays(rays), "npz"  # an .npy ray array has no room for these
        if ray_masks:
            body["mask"] = _mask_array(mask, len(rays))
        if time is not None:
            body["time"] = _ray_time(time, len(rays))
        return self._query(
            f"/v1/scenes/{_seg(scene)}/{query}",  # one of QUERIES, checked above
            body,
            fmt,
            params=params,
            headers={"Accept": wire.MEDIA_TYPES[_choice(answer, "answer", ANSWERS)]},
        )

    def nearest(
        self,
        scene: str,
        points: Any,
        max_distance: float | None = None,
        *,
        sign: bool = False,
        nsamples: int = 1,
        mask: int | None = None,
        stats: bool = False,
        answer: str = "npz",
    ) -> Answer:
        """The closest point on the scene's triangles to each of ``points`` (N, 3), sent as
        .npy float32: ``answer.distance`` (N,) float32 (inf beyond ``max_distance``),
        ``point`` (N, 3), ``mesh``, ``prim`` (-1 for none), ``u``, ``v``; with ``sign`` also
        ``inside`` (bool, the majority of ``nsamples`` parities) and ``signed_distance``
        (negative inside). ``mask`` is one 32-bit mask for every point."""
        params: dict[str, str] = {}
        if max_distance is not None:
            params["max_distance"] = repr(float(max_distance))
        if sign:
            params["sign"] = "true"
        if nsamples != 1:
            params["nsamples"] = str(nsamples)
        if mask is not None:
            params["mask"] = str(_mask_value(mask, "mask"))
        if stats:
            params["stats"] = "true"
        points = np.ascontiguousarray(_numbers(points, "points"), dtype="<f4")
        return self._query(
            f"/v1/scenes/{_seg(scene)}/nearest",
            {"points": points},
            "npy",
            params=params,
            headers={"Accept": wire.MEDIA_TYPES[_choice(answer, "answer", ANSWERS)]},
        )

    # ---- sensors

    def render(self, scene: str, **body: Any) -> bytes:
        """The PNG of a look-at camera (``width``, ``height``, ``eye``, ``target``, ``up``,
        ``fov_deg``, ``shading``: the body of ``/render``, docs/sensors.md)."""
        return self.request(
            "POST", f"/v1/scenes/{_seg(scene)}/render", json=_json_ready(body)
        ).content

    def camera(
        self,
        scene: str,
        *,
        fields: Any = None,
        strategy: str | None = None,
        stats: bool = False,
        cull: str = "none",
        mask: int | None = None,
        **body: Any,
    ) -> Answer:
        """A depth image: ``body`` is the keys of ``/camera`` (a look-at camera, or ``fx``, ``fy``,
        ``cx``, ``cy`` and a 4x4 ``pose``; ``near``, ``far``); answers ``depth``, ``range``,
        ``mesh``, ``prim`` (H, W) and ``normal`` (H, W, 3)."""
        params = _sensor_params(fields, strategy, stats, cull, mask)
        return self._sensor(f"/v1/scenes/{_seg(scene)}/camera", body, params)

    def lidar(
        self,
        scene: str,
        *,
        fields: Any = None,
        strategy: str | None = None,
        stats: bool = False,
        cull: str = "none",
        mask: int | None = None,
        pcd: bool = False,
        **body: Any,
    ) -> Answer | bytes:
        """A lidar's points: ``body`` is the keys of ``/lidar`` (``pose``, ``model`` or
        ``vertical_angles_deg`` or ``pattern``, the physics: ``return_mode``, ``noise``, ...);
        answers ``xyz``, ``range``, ``ring``, ... ``intensity``, ``label``; with ``pcd`` the
        bytes of a binary PCD file instead."""
        params = _sensor_params(fields, strategy, stats, cull, mask)
        path = f"/v1/scenes/{_seg(scene)}/lidar"
        if pcd:
            headers = {"Accept": wire.PCD}
            return self.request(
                "POST", path, json=_json_ready(body), params=params, headers=headers
            ).content
        return self._sensor(path, body, params)

    def sensors(
        self,
        scene: str,
        sensors: Mapping[str, Mapping[str, Any]],
        *,
        fields: Any = None,
        strategy: str | None = None,
        stats: bool = False,
        cull: str = "none",
        mask: int | None = None,
    ) -> dict[str, Answer]:
        """A rig: ``{name: {"kind": "lidar" | "camera", ...its body}}`` traced as one batch on one
        scene version; answers ``{name: Answer}``, each with that version."""
        params = _sensor_params(fields, strategy, stats, cull, mask)
        whole = self._sensor(f"/v1/scenes/{_seg(scene)}/sensors", {"sensors": sensors}, params)
        answers: dict[str, dict[str, np.ndarray]] = {name: {} for name in sensors}
        for key, array in whole.arrays.items():
            name, _, part = key.rpartition(".")
            answers[name][part] = array
        return {
            name: Answer(arrays, whole.version, whole.timing, whole.stats)
            for name, arrays in answers.items()
        }

    def _sensor(self, path: str, body: Mapping[str, Any], params: dict[str, str]) -> Answer:
        response, content = self.fetch(
            "POST", path, json=_json_ready(body), params=params, headers={"Accept": wire.NPZ}
        )
        return _answer(response, content)

    # ---- scan patterns

    def put_pattern(
        self,
        name: str,
        azimuth_deg: Any,
        elevation_deg: Any,
        time_s: Any = None,
        channel: Any = None,
    ) -> dict[str, Any]:
        """Upload a scan pattern (M rays: azimuth and elevation in degrees, optional firing time
        in seconds and channel); answers its info."""
        arrays = {
            "azimuth_deg": np.asarray(azimuth_deg, dtype="<f8"),
            "elevation_deg": np.asarray(elevation_deg, dtype="<f8"),
        }
        if time_s is not None:
            arrays["time_s"] = np.asarray(time_s, dtype="<f8")
        if channel is not None:
            channels = np.asarray(channel)
            if channels.dtype.kind not in "iu":
                raise ValueError(f"channel must be integers, got dtype {channels.dtype}")
            if channels.size and not (0 <= channels.min() and channels.max() <= MAX_CHANNEL):
                raise ValueError(f"channel values must lie in [0, {MAX_CHANNEL}]")
            arrays["channel"] = channels.astype("<u2")
        return self._binary("PUT", f"/v1/patterns/{_seg(name, 'pattern')}", arrays).json()

    def pattern(self, name: str) -> dict[str, np.ndarray]:
        """A pattern's arrays, as uploaded."""
        return wire.read_npz(self.request("GET", f"/v1/patterns/{_seg(name, 'pattern')}").content)

    def patterns(self) -> list[dict[str, Any]]:
        return self.request("GET", "/v1/patterns").json()["patterns"]

    def delete_pattern(self, name: str) -> None:
        self.request("DELETE", f"/v1/patterns/{_seg(name, 'pattern')}")

    def trace(
        self,
        vertices: Any,
        faces: Any,
        origins: Any,
        directions: Any,
        tmin: Any = None,
        tmax: Any = None,
        *,
        query: str = "closest",
        fields: Any = None,
        strategy: str | None = None,
        stats: bool = False,
        cull: str = "none",
        mask: Any = None,
        max_hits: int | None = None,
        time: Any = None,
        answer: str = "npz",
    ) -> Answer:
        """A one-shot query on a mesh sent with the rays (nothing is stored); ``mask`` is one
        value or (N,) values, sent in the body, and ``time`` as ``query``'s (a one-shot mesh is
        static, so it changes no answer)."""
        origins, directions = _ray_rows(origins, directions)
        arrays = {
            "vertices": np.asarray(vertices, dtype="<f4"),
            "faces": _faces(faces),
            "origins": np.asarray(origins, dtype="<f4"),
            "directions": np.asarray(directions, dtype="<f4"),
        }
        for name, bound in (("tmin", tmin), ("tmax", tmax)):
            if bound is not None:
                arrays[name] = np.asarray(_ray_bound(bound, len(origins), name), dtype="<f4")
        if mask is not None:
            arrays["mask"] = _mask_array(mask, len(arrays["origins"]))
        if time is not None:
            arrays["time"] = _ray_time(time, len(origins))
        params = {
            "query": _choice(query, "query", QUERIES),
            **_params(fields, strategy, stats, cull),
        }
        if max_hits is not None:
            params["max_hits"] = str(max_hits)
        return self._query(
            "/v1/trace",
            arrays,
            "npz",
            params=params,
            headers={"Accept": wire.MEDIA_TYPES[_choice(answer, "answer", ANSWERS)]},
        )


#: The queries of ``Client.query``, and the formats an answer may come in.
QUERIES = ("closest", "occluded", "hits", "count")
ANSWERS = ("npz", "npy", "json")


def _seg(name: Any, what: str = "scene") -> str:
    """A scene, mesh or pattern name as one path segment, checked as the server checks it: a
    name holding ``/``, ``#`` or ``?`` would be another resource's path (the server decodes
    ``%2F`` before routing), so it is a ValueError here."""
    if not isinstance(name, str) or not NAME.fullmatch(name) or name in (".", ".."):
        raise ValueError(
            f"{what} name must be 1-64 characters of A-Z a-z 0-9 _ - . (and not '.' or '..'), "
            f"got {name!r}"
        )
    return name


def _choice(value: Any, what: str, choices) -> str:
    if value not in choices:
        raise ValueError(f"{what} must be one of {', '.join(choices)}, got {value!r}")
    return value


def _faces(faces: Any, what: str = "faces") -> np.ndarray:
    """Faces as little-endian int32, or ValueError naming ``what``: integers (floats only when
    whole), each within int32, so that no index is rounded or wrapped on the way."""
    if faces is None:
        raise ValueError(f"give {what}: (F, 3) vertex indices")
    array = np.asarray(faces)
    if array.dtype.kind not in "iuf" or (
        array.dtype.kind == "f" and not np.array_equal(array, np.trunc(array))
    ):
        raise ValueError(f"{what} must be integers (vertex indices), got dtype {array.dtype}")
    if array.size and not (-(2**31) <= array.min() and array.max() < 2**31):
        raise ValueError(f"{what} holds an index beyond int32 ({array.max()!r}): no such vertex")
    return np.asarray(array, dtype="<i4")


def _frame_part(part: str, value: Any, what: str) -> Any:
    """One part of a mesh in a frame as its wire value, checked as ``put_mesh``,
    ``set_transform``, ``set_mask`` and ``set_material`` check theirs (ValueError naming
    ``what``): arrays in their .npz dtypes, a mask or label as one uint32, a reflectivity as one
    float64, ``instance_of`` a mesh name (text)."""
    if part == "instance_of":
        return _seg(value, what)
    if part == "faces":
        return _faces(value, what)
    if part in ("mask", "label"):
        return np.asarray(_mask_value(value, what), dtype="<u4")
    array = _numbers(value, what)
    if part in ("vertices", "vertices_end"):
        return np.asarray(array, dtype="<f4")
    return np.asarray(array, dtype="<f8")  # transform, transform_end, reflectivity


def _ray_arrays(rays: np.ndarray) -> dict[str, np.ndarray]:
    """The .npz keys of an (N, 6|8) ray array: origins, directions (and tmin, tmax)."""
    arrays = {"origins": rays[:, 0:3], "directions": rays[:, 3:6]}
    if rays.shape[1] == 8:
        arrays["tmin"], arrays["tmax"] = rays[:, 6], rays[:, 7]
    return {key: np.ascontiguousarray(value) for key, value in arrays.items()}


def _mask_value(mask: Any, name: str) -> int:
    """One 32-bit mask as a Python int; ValueError outside [0, 2**32)."""
    if isinstance(mask, (bool, np.bool_)) or not isinstance(mask, (int, np.integer)):
        raise ValueError(f"{name} must be an integer, got {mask!r}")
    if not 0 <= int(mask) <= 0xFFFFFFFF:
        raise ValueError(f"{name} must lie in [0, 2**32), got {mask}")
    return int(mask)


def _mask_array(mask: Any, n_rays: int) -> np.ndarray:
    """Masks as little-endian uint32: () for one value, else (N,); ValueError outside uint32."""
    if np.ndim(mask) == 0:
        return np.asarray(_mask_value(mask, "mask"), dtype="<u4")
    masks = np.asarray(mask)
    if masks.dtype.kind not in "iu":
        raise ValueError(f"mask must be integers, got dtype {masks.dtype}")
    if masks.shape != (n_rays,):
        raise ValueError(f"mask must have shape ({n_rays},), one per ray, got {masks.shape}")
    if masks.dtype != np.uint32 and masks.size and (masks.min() < 0 or masks.max() > 0xFFFFFFFF):
        raise ValueError("mask values must lie in [0, 2**32)")
    return np.ascontiguousarray(masks, dtype="<u4")


def _slices(parts: list, size: int = 1 << 20) -> list[memoryview]:
    """The body as 1 MiB views: sent with Content-Length and no join into one big copy."""
    views = [memoryview(part).cast("B") for part in parts]
    return [view[i : i + size] for view in views for i in range(0, len(view), size)] or [
        memoryview(b"")
    ]


def _params(fields: Any, strategy: str | None, stats: bool, cull: str) -> dict[str, str]:
    params = {}
    if fields is not None:
        if not isinstance(fields, str) and not all(isinstance(name, str) for name in fields):
            raise ValueError(f"fields must be names (text), got {fields!r}")
        params["fields"] = fields if isinstance(fields, str) else ",".join(fields)
    if strategy is not None:
        params["strategy"] = strategy
    if stats:
        params["stats"] = "true"
    if cull != "none":
        params["cull"] = cull
    return params


def _sensor_params(
    fields: Any, strategy: str | None, stats: bool, cull: str, mask: int | None
) -> dict[str, str]:
    params = _params(fields, strategy, stats, cull)
    if mask is not None:
        params["mask"] = str(_mask_value(mask, "mask"))
    return params


def _json_ready(value: Any, key: str = "body") -> Any:
    """A body for JSON: NumPy arrays and scalars as lists and numbers; ValueError naming the key
    of a NaN or infinite number, which JSON cannot hold."""
    if isinstance(value, Mapping):
        prefix = "" if key == "body" else f"{key}."
        return {name: _json_ready(item, f"{prefix}{name}") for name, item in value.items()}
    if isinstance(value, (np.ndarray, np.generic)):
        value = value.tolist()
    if isinstance(value, (list, tuple)):
        return [_json_ready(item, f"{key}[{i}]") for i, item in enumerate(value)]
    if isinstance(value, float) and not math.isfinite(value):
        raise ValueError(f"{key} is {value}: JSON holds finite numbers only")
    return value


def _answer(response: httpx.Response, body: wire.Buffer) -> Answer:
    """A query's or a sensor's answer: its arrays, scene version, timing and stats; APIError
    (with the answer's status) when the body or a header cannot be read as the service's."""
    try:
        return Answer(
            read_answer(response, body),
            int(response.headers["x-scene-version"]),
            parse_server_timing(response.headers.get("server-timing", "")),
            json.loads(response.headers["x-trace-stats"])
            if "x-trace-stats" in response.headers
            else None,
        )
    except (ValueError, KeyError, TypeError, ServiceError) as exc:  # wire's BadBody, Invalid
        detail = f"the answer cannot be read: {type(exc).__name__}: {exc}"
        raise APIError(response.status_code, detail, response) from None


def _api_error(response: httpx.Response) -> APIError:
    try:
        detail = response.json()["detail"]
    except (ValueError, KeyError, TypeError):
        detail = response.text
    return APIError(response.status_code, str(detail), response)


def read_answer(response: httpx.Response, body: wire.Buffer | None = None) -> dict[str, np.ndarray]:
    """The arrays of an answer body (``body``, else ``response.content``), whatever its format
    (npz, npy, JSON), with the keys, dtypes, shapes and values of the .npz answer: a JSON null
    is NaN for ``NAN_KEYS`` and inf elsewhere (``-inf`` for the ``signed_distance`` of a point
    ``inside``), and a rig's ``{"NAME": {"KEY": ...}}`` is keys ``NAME.KEY``."""
    body = response.content if body is None else body
    media = response.headers.get("content-type", "").split(";")[0].strip()
    if media == wire.NPZ:
        return wire.read_npz(body)
    if media == wire.NPY:
        array = wire.read_npy(body, structured=True)
        if array.dtype.names:
            return {name: array[name] for name in array.dtype.names}
        # one array: the single ?fields= name, else the query's only key (occluded or count)
        params = response.request.url.params
        query = params.get("query") or response.request.url.path.rsplit("/", 1)[-1]
        return {params.get("fields") or query: array}
    return _from_json_document(wire.read_json(body, "the answer's fields"))


def _from_json_document(document: Mapping[str, Any], prefix: str = "") -> dict[str, np.ndarray]:
    """A JSON answer's arrays; a rig's sensors (objects) flattened to ``NAME.KEY``."""
    arrays: dict[str, np.ndarray] = {}
    for key, value in document.items():
        if isinstance(value, Mapping):
            arrays.update(_from_json_document(value, f"{prefix}{key}."))
        else:
            arrays[prefix + key] = _from_json(key, value)
    signed, inside = arrays.get(prefix + "signed_distance"), arrays.get(prefix + "inside")
    if signed is not None and inside is not None:
        # JSON writes -inf as null too: a point inside, beyond max_distance, is -inf
        signed[np.isinf(signed) & inside] = -np.inf
    return arrays


def _nulls_as(value: Any, fill: float) -> Any:
    """A JSON answer's list, rows too (a point's (N, 3)), with null made ``fill``."""
    if isinstance(value, list) and value and isinstance(value[0], list):
        return [_nulls_as(row, fill) for row in value]
    return wire.nulls_as(value, fill)


def _from_json(key: str, value: Any) -> np.ndarray:
    dtype = ANSWER_DTYPES.get(key, np.float64)
    if np.dtype(dtype).kind == "f":
        value = _nulls_as(value, np.nan if key in NAN_KEYS else np.inf)
    array = np.asarray(value, dtype=dtype)
    if key in ROW_KEYS and array.size == 0:
        array = array.reshape(0, 3)
    return array
