"""``PUT /api/sessions/{id}/mesh`` (issue 33): a session shows a mesh sent as arrays
(:mod:`tessera.wire.mesh_update`) from a given frame on, without the library, its upload check or
the nodes' scene cache: the fast path of a simulation pushing a new mesh each step."""

from __future__ import annotations

import asyncio
from typing import Any

from fastapi import APIRouter, Depends, HTTPException, Request

from server.mesh_updates import SessionGone
from server.routes.deps import get_service, get_session, require_token
from server.service import RenderService
from server.sessions import Session
from tessera.wire.mesh_update import MAX_MESH_BYTES, MeshError, unpack_mesh

router = APIRouter(tags=["sessions"], dependencies=[Depends(require_token)])

MESH_BODY = {"requestBody": {"required": True, "content": {"application/octet-stream": {"schema": {
    "type": "string", "format": "binary",
    "description": "TMSH, a u32 header length, a JSON header {vertices, faces, normals, colors}, then the arrays "
                   "(positions N×3 float32, faces F×3 uint32, normals N×3 float32, colors N×4 uint8), "
                   "little-endian: tessera.wire.mesh_update"}}}}}


def mesh_limit(service: RenderService) -> int:
    """The most bytes a mesh body may have: ``--max-upload-mb``, at most what a node's socket takes."""
    return min(service.settings.max_upload_mb << 20, MAX_MESH_BYTES)


async def read_body(request: Request, limit: int) -> bytes:
    """The request's body, or 413 as soon as it is over ``limit`` bytes."""
    refusal = HTTPException(status_code=413, detail=f"mesh over the limit of {limit / (1 << 20):g} MiB "
                                                     "(--max-upload-mb, at most 60 MiB)")
    declared = request.headers.get("content-length", "")
    if declared.isdigit() and int(declared) > limit:
        raise refusal
    chunks, received = [], 0
    async for chunk in request.stream():
        received += len(chunk)
        if received > limit:
            raise refusal
        chunks.append(chunk)
    return b"".join(chunks)


@router.put("/api/sessions/{session_id}/mesh", openapi_extra=MESH_BODY)
async def put_mesh(request: Request, session: Session = Depends(get_session),
                   service: RenderService = Depends(get_service)) -> dict[str, Any]:
    """Show the mesh of the body (``application/octet-stream``, the layout of
    :mod:`tessera.wire.mesh_update`) from now on, in place of the session's scene or mesh, its
    camera kept: ``frame`` is the first frame id that shows it on every tile (until it is published,
    viewers keep the frame before). While the mesh before is not shown yet, the answer waits for it
    (at most 10 s); a newer mesh sent meanwhile takes this one's place, and both answers give the
    frame id from which the newer one shows. A body that is not a mesh, of
    the wrong size, with values that are not finite or indices out of range is 422 with the reason;
    over ``--max-upload-mb`` 413; the default session shows ``--scene`` (409)."""
    if session is service.default:
        raise HTTPException(status_code=409, detail="the default session shows --scene; open a session to "
                                                    "show meshes (POST /api/sessions)")
    body = await read_body(request, mesh_limit(service))
    try:
        _, mesh = await asyncio.to_thread(unpack_mesh, body)
    except MeshError as exc:
        raise HTTPException(status_code=422, detail=str(exc)) from None
    if service.find_session(session.id) is not session:
        raise HTTPException(status_code=404, detail="no such session")
    try:
        frame = await service.meshes.update(session, body)
    except SessionGone:
        raise HTTPException(status_code=404, detail="no such session") from None
    return {"frame": frame, "vertices": len(mesh.positions), "faces": len(mesh.faces)}
