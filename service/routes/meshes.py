"""Meshes and the scenes that hold them: upload, deform, frame, inspect, delete."""

from __future__ import annotations

from functools import partial

from anyio.to_thread import run_sync
from fastapi import APIRouter, Depends, Request, Response

from .. import openapi, wire
from ..deps import SettingsDep, StoreDep, read_body, reject_unknown_query, require_token
from ..errors import Invalid
from ..params import FrameFormat, Mask, MeshFormat, MeshName, SceneName, VertexFormat
from ..store import check_name

router = APIRouter(
    prefix="/v1/scenes",
    tags=["scenes"],
    dependencies=[Depends(require_token), Depends(reject_unknown_query)],
)


MESH_BODY = openapi.request_body(
    wire.MESH_FORMATS,
    openapi.MESH_JSON,
    "a mesh: .npz, JSON or a mesh file (OBJ, PLY, STL, GLB, OFF)",
)
VERTICES_BODY = openapi.request_body(
    wire.VERTEX_FORMATS, openapi.VERTICES_JSON, "vertex positions, as many as the mesh has"
)
FRAME_BODY = openapi.request_body(
    wire.FRAME_FORMATS, openapi.FRAME_JSON, "MESH.vertices (and MESH.faces) for several meshes"
)
CHANGE_ERRORS = openapi.errors(400, 401, 404, 408, 409, 413, 415, 422)
READ_ERRORS = openapi.errors(401, 404, 422)


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
    """Add or replace a mesh (201 new / 200 replaced); creates the scene if needed."""
    check_name("scene", scene), check_name("mesh", mesh)
    if mask is not None:
        raise Invalid("?mask= (visibility masks) is not supported by this server yet")
    body = await read_body(request, settings.max_body_bytes)
    fmt = wire.resolve_format(
        request.headers.get("content-type"),
        format,
        wire.MESH_FORMATS,
        body,
        "PUT /v1/scenes/{scene}/meshes/{mesh}",
    )
    arrays = await run_sync(partial(wire.decode_mesh, body, fmt, settings.max_body_bytes))
    stored, created = await run_sync(store.put_mesh, scene, mesh, arrays)
    response.status_code = 201 if created else 200
    return stored.info(scene)


@router.put("/{scene}/meshes/{mesh}/vertices", openapi_extra=VERTICES_BODY, responses=CHANGE_ERRORS)
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
    body = await read_body(request, settings.max_body_bytes)
    fmt = wire.resolve_format(
        request.headers.get("content-type"),
        format,
        wire.VERTEX_FORMATS,
        body,
        "PUT /v1/scenes/{scene}/meshes/{mesh}/vertices",
    )
    vertices = await run_sync(partial(wire.decode_vertices, body, fmt, settings.max_body_bytes))
    stored = await run_sync(store.update_vertices, scene, mesh, vertices)
    return stored.info(scene)


@router.post("/{scene}/frame", openapi_extra=FRAME_BODY, responses=CHANGE_ERRORS)
async def post_frame(
    scene: SceneName,
    request: Request,
    settings: SettingsDep,
    store: StoreDep,
    format: FrameFormat = None,
) -> dict:
    """Change several meshes in one version, atomically."""
    check_name("scene", scene)
    body = await read_body(request, settings.max_body_bytes)
    fmt = wire.resolve_format(
        request.headers.get("content-type"),
        format,
        wire.FRAME_FORMATS,
        body,
        "POST /v1/scenes/{scene}/frame",
    )
    frame = await run_sync(partial(wire.decode_frame, body, fmt, settings.max_body_bytes))
    snapshot = await run_sync(store.apply_frame, scene, frame)
    return snapshot.info()


@router.get("", responses=openapi.errors(401, 422))
async def list_scenes(store: StoreDep) -> dict:
    return {"scenes": [s.info() for s in store.snapshots()]}


@router.get("/{scene}", responses=READ_ERRORS)
async def get_scene(scene: SceneName, store: StoreDep) -> dict:
    return store.snapshot(check_name("scene", scene)).info()


@router.get("/{scene}/meshes/{mesh}", responses=READ_ERRORS)
async def get_mesh(scene: SceneName, mesh: MeshName, store: StoreDep) -> dict:
    check_name("scene", scene), check_name("mesh", mesh)
    return store.snapshot(scene).mesh(mesh).info(scene)


@router.delete("/{scene}", status_code=204, responses=READ_ERRORS)
async def delete_scene(scene: SceneName, store: StoreDep) -> Response:
    store.delete_scene(check_name("scene", scene))
    return Response(status_code=204)


@router.delete("/{scene}/meshes/{mesh}", status_code=204, responses=READ_ERRORS)
async def delete_mesh(scene: SceneName, mesh: MeshName, store: StoreDep) -> Response:
    check_name("scene", scene), check_name("mesh", mesh)
    store.delete_mesh(scene, mesh)
    return Response(status_code=204)
