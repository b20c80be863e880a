"""``GET /api/frame.png?after=K``: the first complete frame with id ≥ K, composited, lossless PNG."""

from __future__ import annotations

import asyncio

from fastapi import APIRouter, Depends, HTTPException, Query
from fastapi.responses import Response

from server.frame_store import PublishedFrame, encode_frame_png
from server.routes.deps import get_session, require_token
from server.sessions import Session
from server.still_refinement import reported_estimate
from tessera.wire.codec import CodecError

router = APIRouter(tags=["frames"], dependencies=[Depends(require_token)])


@router.get("/frame.png", response_class=Response,
            responses={200: {"content": {"image/png": {}}}, 422: {"description": "a bad or unreachable ``after``"},
                       504: {"description": "no such frame in time"}})
async def frame_png(after: int | None = Query(None, ge=0), timeout: float | None = Query(None, gt=0, le=300),
                    still: bool = Query(False), session: Session = Depends(get_session)) -> Response:
    """The first complete frame with id ≥ ``after``; without ``after``, the newest frame (at rest:
    the still frame), or with ``still=true`` the newest state's still frame. Waits up to ``timeout``
    seconds (default ``--frame-wait-s``); a frame is rendered for the request when none is kept or
    on its way (frames render on demand). With ``still=true`` and ``after``, the first *still*
    frame with id ≥ K: the one rendered with ``--still-codec`` once nothing changed.
    The still is progressive (issues 20, 37; unless ``--still-samples 1``): the frames refining it
    are not still frames; the still frame is the converged one.
    Header ``X-Frame-Id``; ``X-Frame-Still`` 1 or 0; ``X-Frame-Samples``, the samples a progressive
    still's frame holds (0: a frame that is not accumulated); ``X-Frame-Estimated-Psnr``, a still's
    estimated PSNR against its converged image in dB (absent when not estimated); for a scene with
    objects, ``X-State-Version`` and ``X-Scene-Time`` (s, ``repr`` of the float: exact) of the frame's scene state, and
    ``X-Tile-States``, the state tag each tile's node reported (tile order). The image is lossless PNG of the tiles as
    received: an interactive frame with ``--codec jpeg`` carries the JPEG tiles' loss.
    ``X-Composite-Ms``: CPU time to decode and paste the tiles; ``X-Png-Encode-Ms``: PNG encoding.
    ``after`` beyond the next frame to start (no id the API handed out) → 422: no frame is on its way."""
    upcoming = session.next_frame_id()
    if after is None:
        newest = session.store.newest(still)
        after = newest.frame_id if newest is not None else max(session.store.last_id + 1, 0)
    if after > upcoming:
        shown = str(after) if after < 10**20 else f"{str(after)[:20]}…"
        raise HTTPException(status_code=422, detail=f"after={shown} is beyond the next frame, {upcoming}: "
                                                    "no such frame is on its way")
    if session.store.first_at_or_after(after, still) is None:
        session.request_frame()
    session.frame_waits += 1   # a long wait (a big scene's still) keeps the session open
    try:
        frame = await session.store.wait_for(after, timeout or session.service.settings.frame_wait_s, still)
    finally:
        session.frame_waits -= 1
        session.touch()
    if frame is None:
        kind = "still frame" if still else "complete frame"
        raise HTTPException(status_code=504, detail=f"no {kind} with id >= {after} in time")
    try:
        png, decode_ms, encode_ms = await asyncio.to_thread(encode_frame_png, frame)
    except CodecError as exc:  # tiles are decoded on arrival: only a peer's crafted tile gets here
        raise HTTPException(status_code=502, detail=f"frame {frame.frame_id} cannot be composited: {exc}") from None
    return Response(png, media_type="image/png", headers={
        "X-Frame-Id": str(frame.frame_id), "X-Tile-Codec": frame.tiles[0][1].name.lower() if frame.tiles else "",
        "X-Frame-Still": "1" if frame.still else "0", "X-Frame-Samples": str(frame.samples), **state_headers(frame),
        **({} if frame.estimate_db is None else {"X-Frame-Estimated-Psnr": str(reported_estimate(frame.estimate_db))}),
        "X-Composite-Ms": f"{decode_ms:.3f}", "X-Png-Encode-Ms": f"{encode_ms:.3f}", "Cache-Control": "no-store"})


def state_headers(frame: PublishedFrame) -> dict[str, str]:
    """The frame's scene state headers (none for a frame without one)."""
    if frame.state_version is None:
        return {}
    return {"X-State-Version": str(frame.state_version), "X-Scene-Time": repr(frame.scene_time),
            "X-Tile-States": ",".join(map(str, frame.tile_states))}
