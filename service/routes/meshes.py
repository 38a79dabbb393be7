"""Meshes and the scenes that hold them: upload, instance, deform, place, mask, material, frame,
inspect, delete."""

from __future__ import annotations

import json
from collections.abc import Callable
from functools import partial
from typing import Any

import numpy as np
from anyio.to_thread import run_sync
from fastapi import APIRouter, Depends, Request, Response

from .. import footprint, openapi, wire
from ..deps import SettingsDep, StoreDep, read_change, reject_unknown_query, require_token
from ..errors import BadBody, Invalid, NotFound
from ..params import FrameFormat, Mask, MeshFormat, MeshName, SceneName, VertexFormat
from ..store import Snapshot, Store, check_name

router = APIRouter(
    prefix="/v1/scenes",
    tags=["scenes"],
    dependencies=[Depends(require_token), Depends(reject_unknown_query)],
)


MESH_BODY = openapi.request_body(
    wire.MESH_FORMATS,
    {"anyOf": [openapi.MESH_JSON, openapi.INSTANCE_JSON]},
    "a mesh: .npz, JSON or a mesh file (OBJ, PLY, STL, GLB, OFF); or, in JSON, an instance of "
    "another mesh of the scene: {instance_of, transform}",
)
TRANSFORM_BODY = openapi.request_body(
    ("json",), openapi.TRANSFORM_JSON, "the mesh's placement: a 4x4 row-major affine matrix"
)
MASK_BODY = openapi.request_body(
    ("json",), openapi.MASK_JSON, "the mesh's visibility mask: a uint32, decimal or 0x hex"
)
MATERIAL_BODY = openapi.request_body(
    ("json",), openapi.MATERIAL_JSON, "the mesh's material: reflectivity, label, or both"
)
VERTICES_BODY = openapi.request_body(
    wire.VERTEX_FORMATS, openapi.VERTICES_JSON, "vertex positions, as many as the mesh has"
)
FRAME_BODY = openapi.request_body(
    wire.FRAME_FORMATS,
    openapi.FRAME_JSON,
    "MESH.vertices (and MESH.faces), MESH.transform, MESH.mask, MESH.reflectivity, MESH.label "
    "(and, in JSON, MESH.instance_of) for several meshes",
)
CHANGE_ERRORS = openapi.errors(400, 401, 404, 408, 409, 413, 415, 422, 503, 507)
READ_ERRORS = openapi.errors(401, 404, 422)
MESH_ANSWER = {200: openapi.json_answer("the mesh's info", openapi.MESH_INFO)}
SCENE_ANSWER = {200: openapi.json_answer("the scene's info", openapi.SCENE_INFO)}


@router.put(
    "/{scene}/meshes/{mesh}",
    openapi_extra=MESH_BODY,
    status_code=200,
    responses={
        200: openapi.json_answer("a replaced mesh: its info", openapi.MESH_INFO),
        201: openapi.json_answer("a new mesh: its info", openapi.MESH_INFO),
        **CHANGE_ERRORS,
    },
)
async def put_mesh(
    scene: SceneName,
    mesh: MeshName,
    request: Request,
    response: Response,
    settings: SettingsDep,
    store: StoreDep,
    format: MeshFormat = None,
    mask: Mask = None,
) -> dict:
    """Add or replace a mesh (201 new / 200 replaced); creates the scene if needed. A JSON body
    ``{"instance_of": MESH, "transform": 4x4}`` makes it an instance of another mesh of the
    scene, sharing its arrays."""
    check_name("scene", scene), check_name("mesh", mesh)
    mask_value = None if mask is None else wire.parse_mask(mask, "?mask")
    body, fmt = await read_change(request, settings, format, wire.MESH_FORMATS)
    decoded = await run_sync(partial(_decode_mesh_or_instance, body, fmt, settings.max_body_bytes))
    if isinstance(decoded, wire.MeshArrays):
        stored, created = await run_sync(store.put_mesh, scene, mesh, decoded, mask_value)
    else:
        source, transform = decoded
        put = partial(store.put_instance, scene, mesh, source, transform, mask_value)
        stored, created = await run_sync(put)
    response.status_code = 201 if created else 200
    return stored.info(scene)


def _decode_mesh_or_instance(
    body: memoryview, fmt: str, max_bytes: int
) -> wire.MeshArrays | tuple[str, np.ndarray | None]:
    """A mesh, or (source, transform or None) of an instance: ``{"instance_of", "transform"}``."""
    if fmt != "json":
        return wire.decode_mesh(body, fmt, max_bytes)
    doc = wire.read_json(body, "vertices, faces (or instance_of and transform)")
    if "instance_of" not in doc:
        wire.check_keys(doc, ("vertices", "faces"))
        return wire.mesh_arrays(doc["vertices"], doc["faces"])
    wire.check_keys(doc, ("instance_of",), ("transform",))
    source = doc["instance_of"]
    if not isinstance(source, str):
        raise Invalid(f"instance_of must be a mesh name (a string), not {type(source).__name__}")
    transform = doc.get("transform")
    return source, None if transform is None else wire.check_matrix(transform, "transform")


@router.put(
    "/{scene}/meshes/{mesh}/vertices",
    openapi_extra=VERTICES_BODY,
    responses={**MESH_ANSWER, **CHANGE_ERRORS},
)
async def put_vertices(
    scene: SceneName,
    mesh: MeshName,
    request: Request,
    settings: SettingsDep,
    store: StoreDep,
    format: VertexFormat = None,
) -> dict:
    """New vertex positions for a mesh, same count (409 otherwise); faces are kept."""
    check_name("scene", scene), check_name("mesh", mesh)
    store.snapshot(scene).mesh(mesh)  # 404 before reading the body
    body, fmt = await read_change(request, settings, format, wire.VERTEX_FORMATS)
    vertices = await run_sync(partial(wire.decode_vertices, body, fmt, settings.max_body_bytes))
    stored = await run_sync(store.update_vertices, scene, mesh, vertices)
    return stored.info(scene)


@router.put(
    "/{scene}/meshes/{mesh}/transform",
    openapi_extra=TRANSFORM_BODY,
    responses={**MESH_ANSWER, **CHANGE_ERRORS},
)
async def put_transform(
    scene: SceneName, mesh: MeshName, request: Request, settings: SettingsDep, store: StoreDep
) -> dict:
    """Place a mesh in the scene by a 4x4 row-major affine matrix; its arrays are kept."""
    check_name("scene", scene), check_name("mesh", mesh)
    store.snapshot(scene).mesh(mesh)  # 404 before reading the body
    doc = await _json_body(request, settings, "matrix")
    matrix = wire.check_matrix(doc["matrix"], "matrix")
    return (await run_sync(store.set_transform, scene, mesh, matrix)).info(scene)


@router.put(
    "/{scene}/meshes/{mesh}/mask",
    openapi_extra=MASK_BODY,
    responses={**MESH_ANSWER, **CHANGE_ERRORS},
)
async def put_mask(
    scene: SceneName, mesh: MeshName, request: Request, settings: SettingsDep, store: StoreDep
) -> dict:
    """Set a mesh's visibility mask; everything else is kept."""
    check_name("scene", scene), check_name("mesh", mesh)
    store.snapshot(scene).mesh(mesh)  # 404 before reading the body
    doc = await _json_body(request, settings, "mask")
    value = wire.parse_mask(doc["mask"], "mask")
    return (await run_sync(store.set_mask, scene, mesh, value)).info(scene)


@router.put(
    "/{scene}/meshes/{mesh}/material",
    openapi_extra=MATERIAL_BODY,
    responses={**MESH_ANSWER, **CHANGE_ERRORS},
)
async def put_material(
    scene: SceneName, mesh: MeshName, request: Request, settings: SettingsDep, store: StoreDep
) -> dict:
    """Set a mesh's reflectivity and label (either alone keeps the other); everything else is
    kept."""
    check_name("scene", scene), check_name("mesh", mesh)
    store.snapshot(scene).mesh(mesh)  # 404 before reading the body
    doc = await _json_body(request, settings, (), ("reflectivity", "label"))
    if not doc:
        raise BadBody("the body names no material key; give reflectivity, label or both")
    material = (
        wire.parse_reflectivity(doc["reflectivity"], "reflectivity")
        if "reflectivity" in doc
        else None,
        wire.parse_label(doc["label"], "label") if "label" in doc else None,
    )
    return (await run_sync(store.set_material, scene, mesh, *material)).info(scene)


async def _json_body(
    request: Request,
    settings: SettingsDep,
    keys: str | tuple[str, ...],
    optional: tuple[str, ...] = (),
) -> dict:
    """The JSON object of a small body with ``keys`` (and ``optional`` ones); 415 for another
    Content-Type."""
    keys = (keys,) if isinstance(keys, str) else keys
    body, _ = await read_change(request, settings, None, ("json",))
    doc = wire.read_json(body, ", ".join(keys + optional))
    wire.check_keys(doc, keys, optional)
    return doc


@router.post(
    "/{scene}/frame", openapi_extra=FRAME_BODY, responses={**SCENE_ANSWER, **CHANGE_ERRORS}
)
async def post_frame(
    scene: SceneName,
    request: Request,
    settings: SettingsDep,
    store: StoreDep,
    format: FrameFormat = None,
) -> Response:
    """Change several meshes in one version, atomically: their vertices, faces, transforms and
    masks, and new instances."""
    check_name("scene", scene)
    max_meshes = settings.max_meshes_per_scene

    def estimate(n_body: int, fmt: str | None) -> int:
        return footprint.frame_bytes(n_body, fmt, _mesh_count(store, scene), max_meshes)

    body, fmt = await read_change(request, settings, format, wire.FRAME_FORMATS, estimate)
    decode = partial(wire.decode_frame, body, fmt, settings.max_body_bytes, max_meshes)
    frame = await run_sync(decode)
    snapshot = await run_sync(store.apply_frame, scene, frame)
    return await run_sync(_json_answer, snapshot.info)


@router.get(
    "",
    responses={
        200: openapi.json_answer("every scene's info", openapi.SCENE_LIST),
        **openapi.errors(401, 422),
    },
)
async def list_scenes(request: Request, store: StoreDep) -> Response:
    snapshots = store.snapshots()
    await _hold_infos(request, snapshots)
    return await run_sync(_json_answer, lambda: {"scenes": [s.info() for s in snapshots]})


@router.get("/{scene}", responses={**SCENE_ANSWER, **READ_ERRORS})
async def get_scene(scene: SceneName, request: Request, store: StoreDep) -> Response:
    snapshot = store.snapshot(check_name("scene", scene))
    await _hold_infos(request, [snapshot])
    return await run_sync(_json_answer, snapshot.info)


def _mesh_count(store: Store, scene: str) -> int:
    """The meshes scene ``scene`` of ``store`` holds now (0 before it exists)."""
    try:
        return len(store.snapshot(scene).meshes)
    except NotFound:
        return 0


async def _hold_infos(request: Request, snapshots: list[Snapshot]) -> None:
    """Hold the request's ticket for the scene info answer of ``snapshots``."""
    n_meshes = sum(len(snapshot.meshes) for snapshot in snapshots)
    what = f"{request.method} {request.url.path} of {n_meshes} meshes' info"
    await request.state.ticket.hold(footprint.scene_info_bytes(n_meshes), what)


def _json_answer(make: Callable[[], Any]) -> Response:
    """The JSON answer of ``make()``, written as FastAPI writes a returned dict; routes call it
    off the event loop, since a scene of many meshes takes a while."""
    text = json.dumps(make(), ensure_ascii=False, allow_nan=False, separators=(",", ":"))
    return Response(text.encode(), media_type="application/json")


@router.get("/{scene}/meshes/{mesh}", responses={**MESH_ANSWER, **READ_ERRORS})
async def get_mesh(scene: SceneName, mesh: MeshName, store: StoreDep) -> dict:
    check_name("scene", scene), check_name("mesh", mesh)
    return store.snapshot(scene).mesh(mesh).info(scene)


@router.delete("/{scene}", status_code=204, responses=openapi.errors(401, 404, 422, 503, 507))
async def delete_scene(scene: SceneName, store: StoreDep) -> Response:
    await run_sync(store.delete_scene, check_name("scene", scene))  # fsyncs off the event loop
    return Response(status_code=204)


@router.delete(
    "/{scene}/meshes/{mesh}",
    status_code=204,
    responses=openapi.errors(401, 404, 409, 422, 503, 507),
)
async def delete_mesh(scene: SceneName, mesh: MeshName, store: StoreDep) -> Response:
    check_name("scene", scene), check_name("mesh", mesh)
    await run_sync(store.delete_mesh, scene, mesh)  # 409 while it has instances
    return Response(status_code=204)
