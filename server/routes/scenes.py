"""The scene library (issue 19): ``GET /api/scenes``, ``GET /api/scenes/{name}/file`` (the bytes, for
nodes on hosts without the folders) and ``POST /api/scenes`` (an upload, multipart field ``file``).
Names and storage: :mod:`server.scene_library`."""

from __future__ import annotations

import asyncio
from typing import Any

from fastapi import APIRouter, Depends, HTTPException, Request
from fastapi.responses import FileResponse, Response

from server.multipart_file import FileField, MultipartRefused
from server.routes.deps import require_token
from server.scene_library import (
    BadSceneName,
    NotAScene,
    PendingUpload,
    SceneExists,
    SceneLibrary,
    SceneRefused,
    TooLargeToLoad,
    UnknownScene,
    UnsupportedFormat,
    UploadsUnavailable,
    UploadTooLarge,
)
from server.upload_check import checked_triangles

router = APIRouter(tags=["scenes"], dependencies=[Depends(require_token)])

STATUS: dict[type[SceneRefused], int] = {
    UnknownScene: 404, BadSceneName: 422, UnsupportedFormat: 415, SceneExists: 409, UploadTooLarge: 413,
    TooLargeToLoad: 413, NotAScene: 422, UploadsUnavailable: 503,
}
#: Room for the multipart framing around the file (boundaries, part headers, other small fields).
MULTIPART_OVERHEAD = 64 << 10
#: Longest check of an upload; the check's process is killed then. Loading the 990k-triangle scan
#: (an 18.8 MB PLY) as a node does took 1.0–1.5 s on the 2-core CI machine (3.5 s while other jobs
#: shared it), so a PLY at the default 512 MB limit takes 30–100 s.
CHECK_TIMEOUT_S = 300.0
#: The OpenAPI description of the upload's body (read from the stream, not declared as a parameter).
UPLOAD_BODY = {"requestBody": {"required": True, "content": {"multipart/form-data": {"schema": {
    "type": "object", "required": ["file"], "properties": {"file": {"type": "string", "format": "binary"}}}}}}}


class UploadChecks:
    """Loads uploads to check them, one at a time (CPU heavy), each in a child process with at most
    ``memory_mb`` MiB of address space for at most :data:`CHECK_TIMEOUT_S` (:mod:`server.upload_check`).
    A check whose request went away keeps its turn until its process ends, so checks never pile up."""

    def __init__(self, memory_mb: int) -> None:
        self.memory_mb = memory_mb
        self._turn = asyncio.Lock()

    async def triangles(self, upload: PendingUpload) -> int:
        """The upload's triangles; raises :class:`NotAScene` or :class:`TooLargeToLoad`."""
        await self._turn.acquire()
        check = asyncio.ensure_future(asyncio.to_thread(
            checked_triangles, upload.temporary, upload.name, self.memory_mb, CHECK_TIMEOUT_S))
        check.add_done_callback(self._checked)
        return await asyncio.shield(check)

    def _checked(self, check: asyncio.Future[int]) -> None:
        self._turn.release()
        if not check.cancelled():
            check.exception()  # retrieved: a check that outlived its request has no one to tell


async def get_library(request: Request) -> SceneLibrary:
    return request.app.state.scenes


def refused(exc: SceneRefused) -> HTTPException:
    return HTTPException(status_code=STATUS[type(exc)], detail=str(exc))


@router.get("/api/scenes")
async def list_scenes(library: SceneLibrary = Depends(get_library)) -> list[dict[str, Any]]:
    """Every scene a session may show: ``name`` (``builtin:NAME``, ``library/PATH``, ``upload/FILE``),
    ``format`` (``builtin`` or the file suffix) and ``bytes``."""
    return [entry.to_json() for entry in await asyncio.to_thread(library.entries)]


@router.get("/api/library")
async def describe_library(library: SceneLibrary = Depends(get_library)) -> dict[str, Any]:
    """What the viewer's scene picker offers: the library's ``folder``, its ``library_scenes`` and a
    ``library_hint`` saying how to add some when it has none; ``uploads`` on or off (``uploads_off``:
    how to turn them on), ``max_upload_mb``, the ``formats`` a scene file may have."""
    return await asyncio.to_thread(library.describe)


@router.get("/api/scenes/{name:path}/file")
async def scene_file(name: str, library: SceneLibrary = Depends(get_library)) -> Response:
    """The scene file's bytes (a library ``.gltf`` with separate files: made self-contained),
    header ``X-Sha256`` their content hash; 404 for an unknown name or a built-in scene."""
    try:
        entry = library.find(name)
    except UnknownScene as exc:
        raise refused(exc) from None
    if entry.path is None:
        raise HTTPException(status_code=404, detail=f"{name!r} is built in: it has no file")
    try:
        sha256 = await asyncio.to_thread(library.content_hash, entry)
    except FileNotFoundError:
        raise HTTPException(status_code=404, detail=f"{name!r} is gone") from None
    packed = await asyncio.to_thread(library.packed_gltf, entry)
    if packed is not None:
        return Response(packed, media_type="application/octet-stream", headers={
            "X-Sha256": sha256, "Content-Disposition": f'attachment; filename="{entry.path.name}"'})
    return FileResponse(entry.path, media_type="application/octet-stream", filename=entry.path.name,
                        headers={"X-Sha256": sha256})


@router.post("/api/scenes", status_code=201, openapi_extra=UPLOAD_BODY)
async def upload_scene(request: Request, library: SceneLibrary = Depends(get_library)) -> dict[str, Any]:
    """Store the file of multipart field ``file`` as ``upload/FILENAME`` once it loads as a scene:
    ``name``, ``sha256``, ``bytes``, ``triangles``. A name taken 409, too large to send or to load
    within ``--upload-check-memory-mb`` 413, an unsupported suffix 415, a bad name or a file that does
    not load 422 (with the loader's reason), uploads off 503."""
    limit = library.max_upload_bytes + MULTIPART_OVERHEAD
    declared = request.headers.get("content-length", "")
    upload = None
    received_all = False
    try:
        if declared.isdigit() and int(declared) > limit:
            raise library.too_large()
        form = FileField(request.headers.get("content-type", ""), "file")
        received = 0
        async for chunk in request.stream():
            received += len(chunk)
            if received > limit:
                raise library.too_large()
            data = form.feed(chunk)
            if upload is None and form.filename is not None:  # refused as soon as the name is known
                upload = library.begin_upload(form.filename)
            for piece in data:  # the file's bytes come after its name
                assert upload is not None
                upload.write(piece)
        received_all = True
        form.finish()
        assert upload is not None, "finish() refuses a body without the file"
        await asyncio.to_thread(upload.finish)
        triangles = await request.app.state.upload_checks.triangles(upload)
        entry = await asyncio.to_thread(upload.commit)
        return {"name": entry.name, "sha256": upload.digest.hexdigest(), "bytes": entry.bytes, "triangles": triangles}
    except (SceneRefused, MultipartRefused) as exc:
        status = 422 if isinstance(exc, MultipartRefused) else STATUS[type(exc)]
        # Refused before the body was all read: closing the connection stops the rest coming.
        headers = None if received_all else {"Connection": "close"}
        raise HTTPException(status_code=status, detail=str(exc), headers=headers) from None
    finally:
        if upload is not None:
            upload.close()
