"""``WS /ws/view``: browsers. Each viewer gets a latest-frame slot and its own sender task;
it sends camera JSON back (with its input sequence number) and reports the input → display
latency it measured. Invalid input gets an ``error`` message, never a crash. Pages of other origins,
viewers over ``--max-viewers`` and sockets over their message size or rate are refused
(``server/routes/guards.py``).

``?session=ID`` joins session ``ID`` (none: the default session); ``?session=KEY&watch=1`` watches
the session whose watch key is ``KEY``: frames come, camera and size messages are refused with the
reason. A session's driving viewer sends its size (canvas × devicePixelRatio): the session's
frames follow it, fitted to ``--max-size``; the default session keeps ``--size`` (everyone who
opens the bare page shares it). An unknown session closes the socket with 4404, as does closing
the session.

A display wall's session: ``&cell=COL,ROW`` makes the viewer one screen of the wall. It
gets its cell's tiles only (a frame of the cell's size), steers nothing (camera and size are
refused with the reason), and is frame-locked: it says which frame it holds (``have``), presents
on ``present`` at the time it names, and reports when (``presented``, on the coordinator's clock, which ``ping`` →
``pong`` lets it estimate). A cell outside the wall, or a cell of a session that is no wall,
closes the socket with 4422 and the reason. A wall's whole-wall viewer (the driver) steers as any;
the wall's size is fixed, so its size messages are ignored.

Video: a viewer gets tiles until it offers the codecs it decodes (``stream_offer``);
the coordinator answers ``stream`` with the transport ``--stream`` allows (a video codec, or tiles
with the reason; a wall's cells keep their tiles). A video viewer asks for a keyframe when its
decoder lost a frame (``keyframe``) and reports its link each second (``stream_report``). Feedback
no page sends (:mod:`tessera.video.feedback`: absurd reports, a keyframe flood, malformed messages
again and again from a video viewer) closes the socket with 1008 and the reason before it reaches
the stream the session's other viewers share."""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable

from fastapi import APIRouter, WebSocket, WebSocketDisconnect

from server.routes import guards
from server.routes.balancer import BALANCERS
from server.routes.deps import presented_token, token_ok
from server.service import RenderService
from server.sessions import fit_size
from server.video_stream import VIDEO_SOURCE_QUALITY
from server.viewers import MAX_QUEUED_CONTROL, ViewerSlot
from tessera.decomposition.wall_cells import WallError, parse_cell
from tessera.video.feedback import FeedbackGuard
from tessera.video.transport import choose_transport
from tessera.wire.codec import Codec
from tessera.wire.messages import (
    FROM_VIEWER,
    CameraUpdate,
    LatencyReport,
    ViewerError,
    ViewerHello,
    ViewerSize,
    parse,
)
from tessera.wire.protocol import ProtocolError
from tessera.wire.stream_messages import FROM_STREAM_VIEWER, KeyframeRequest, StreamChoice, StreamOffer, StreamReport
from tessera.wire.wall_messages import FROM_WALL_VIEWER, ClockPing, ClockPong, FramePresented, HaveFrame, WallHello

router = APIRouter()
NOT_READING = f"not reading its socket: {MAX_QUEUED_CONTROL} control messages waiting"
log = logging.getLogger("tessera.server")


#: Close code for a session that does not exist (any more).
CLOSE_NO_SESSION = 4404
#: Close code for a wall cell that is not one (outside the wall, or the session is no wall).
CLOSE_BAD_CELL = 4422
#: What a wall cell's camera or size message is told.
CELLS_DO_NOT_STEER = "this viewer is one cell of a wall: it steers nothing (the wall's driver opens ?session=ID)"
#: What the viewer socket accepts.
ACCEPTED = FROM_VIEWER + FROM_WALL_VIEWER + FROM_STREAM_VIEWER
#: What a wall cell's stream offer is told.
CELLS_TAKE_TILES = "this viewer is one cell of a wall: it gets its cell's tiles, frame-locked"
#: What a watcher's camera message is told.
WATCHERS_DO_NOT_STEER = "this viewer watches the session (a watch link): it cannot steer the camera or the size"


async def _send(ws: WebSocket, slot: ViewerSlot) -> None:
    while True:
        message = await slot.next_message()
        if message is None:
            assert slot.closing is not None
            await guards.close(ws, *slot.closing)
            return
        if isinstance(message, str):
            await ws.send_text(message)
        else:
            await ws.send_bytes(message)


async def _refuse_feedback(ws: WebSocket, slot: ViewerSlot, reason: str) -> None:
    """Close a viewer whose feedback would steer its stream wrongly (:mod:`tessera.video.feedback`)."""
    log.warning("viewer %d closed: %s", slot.viewer_id, reason)
    await guards.close(ws, 1008, reason)


def _video_source(session) -> None:
    """While a viewer takes the session as video, its interactive tiles are the encoder's source:
    near-lossless (:data:`VIDEO_SOURCE_QUALITY`), or raw from local nodes while every viewer takes
    video (none would get the tiles themselves)."""
    frames = session.service.scheduler.sessions.get(session.id)   # None once the session was closed
    if frames is not None:
        viewers = session.viewers
        frames.video_source_quality = VIDEO_SOURCE_QUALITY if viewers.streams else None
        frames.video_only = bool(viewers.slots) and all(slot.video_codec is not None and slot.cell is None
                                                        for slot in viewers.slots)


def _tiles_quality(session) -> Callable[[], int | None]:
    """The JPEG quality a viewer of ``session`` on tiles would get now (None: its interactive
    tiles are not JPEG, or the session is closed): what its video's PSNR is held to."""
    def quality() -> int | None:
        frames = session.service.scheduler.sessions.get(session.id)
        if frames is None or frames.config.codec is not Codec.JPEG:
            return None
        return int(frames.config.interactive_quality)
    return quality


@router.websocket("/ws/view")
async def viewer_socket(ws: WebSocket) -> None:
    service: RenderService = ws.app.state.service
    settings = ws.app.state.settings
    if not await guards.admit_origin(ws, "viewer"):
        return
    await ws.accept()
    if not token_ok(settings.token, presented_token(ws)):
        await ws.close(4401, "wrong token")
        return
    watching = ws.query_params.get("watch") in ("1", "true")
    key = ws.query_params.get("session")
    session = service.default if key is None and not watching else service.find_session(key or "", watching)
    if session is None:
        await guards.close(ws, CLOSE_NO_SESSION, "no such session (closed, or a wrong link)")
        return
    cell = None
    if (cell_text := ws.query_params.get("cell")) is not None:
        try:
            if session.wall is None:
                raise WallError("this session is not a wall: it has no cells")
            cell = parse_cell(cell_text)
            session.wall.check_cell(*cell)
        except WallError as exc:
            await guards.close(ws, CLOSE_BAD_CELL, str(exc))
            return
    viewers = sum(len(s.viewers.slots) for s in service.sessions.values())
    if full := guards.viewers_full(viewers, settings.max_viewers):
        log.warning("viewer from %s refused: %s", guards.peer(ws), full)
        await guards.close(ws, 1008, full)
        return
    limits = guards.limits_for(ws, "viewer")
    slot = session.viewers.join(cell, time.monotonic())
    _video_source(session)   # a viewer of tiles until it takes video
    session.touch()
    slot.put_control(ViewerHello(
        size=session.size if cell is None or session.wall is None else session.wall.cell, viewer=slot.viewer_id,
        camera=session.camera, bounds=session.bounds.tolist() if session.bounds is not None else None,
        balancer=session.balancer.name, balancers=tuple(sorted(BALANCERS)), frame=session.store.last_id,
        still_samples=session.frames.demand.still_plan.most if settings.still_codec is not None else None,
        still_adaptive=settings.still_codec is not None and session.frames.demand.still_plan.adaptive))
    if session.wall is not None:
        slot.put_control(WallHello(wall=session.wall.to_json(), cell=cell))
    if session.store.latest is not None:
        slot.put_frame(session.viewers.message_for(session.store.latest, slot))
    sender = asyncio.create_task(_send(ws, slot))
    feedback = FeedbackGuard(time.monotonic())
    try:
        while True:
            message = await guards.receive(ws, limits, f"viewer {slot.viewer_id}")
            if message is None:
                break
            try:
                if message.get("text") is None:
                    raise ProtocolError("a viewer sends JSON text messages, not binary ones")
                request = parse(message["text"], ACCEPTED)
            except ProtocolError as exc:
                log.info("viewer sent invalid input: %s", exc)
                slot.put_control(ViewerError(message=str(exc)))
                if slot.behind:
                    log.warning("viewer %d closed: %s", slot.viewer_id, NOT_READING)
                    await guards.close(ws, 1008, NOT_READING)
                    break
                if slot.video_codec is not None and (refused := feedback.malformed_message()) is not None:
                    await _refuse_feedback(ws, slot, refused)
                    break
                continue
            match request:
                case ClockPing():
                    slot.put_control(ClockPong(t0=request.t0, clock_ms=time.monotonic() * 1000.0))
                    session.viewers.lock.heard(slot.viewer_id, time.monotonic())
                    session.viewers.check_lock(time.monotonic())
                case HaveFrame() if request.frame > session.store.last_id:
                    slot.put_control(ViewerError(message=f"frame {request.frame} was not published yet"))
                case HaveFrame():
                    session.viewers.lock.have(slot.viewer_id, request.frame, time.monotonic())
                    session.viewers.check_lock(time.monotonic())
                case FramePresented():
                    session.viewers.lock.report(slot.viewer_id, request.frame, request.at_ms)
                case CameraUpdate() | ViewerSize() if cell is not None:
                    slot.put_control(ViewerError(message=CELLS_DO_NOT_STEER))
                case StreamOffer() if cell is not None:
                    slot.put_control(StreamChoice(transport="tiles", reason=CELLS_TAKE_TILES))
                case StreamOffer():
                    codec, reason = choose_transport(settings.stream, request.codecs)
                    if codec is None:
                        session.viewers.stop_video(slot)
                        slot.put_control(StreamChoice(transport="tiles", reason=reason))
                    else:
                        choice = session.viewers.start_video(slot, codec, session.size, settings.max_bitrate,
                                                             settings.max_fps, _tiles_quality(session))
                        slot.put_control(choice.model_copy(update={"reason": reason}))
                    _video_source(session)
                case KeyframeRequest():
                    if (refused := feedback.keyframe(time.monotonic())) is not None:
                        await _refuse_feedback(ws, slot, refused)
                        break
                    session.viewers.request_keyframe(slot)
                case StreamReport():
                    refused = feedback.report(request, slot.video_frames_written, slot.newest_video_written)
                    if refused is not None:
                        await _refuse_feedback(ws, slot, refused)
                        break
                    slot.take_report(request, time.monotonic())
                case LatencyReport():
                    slot.latency = {name: round(value, 3) for name, value in request.model_dump().items()}
                case CameraUpdate() | ViewerSize() if watching:
                    slot.put_control(ViewerError(message=WATCHERS_DO_NOT_STEER))
                case ViewerSize() if session is not service.default and session.wall is None:
                    fitted = fit_size(request.size, settings.max_size)
                    if fitted != session.size:
                        session.resize(fitted)
                case CameraUpdate():
                    session.set_camera(request.camera, slot.viewer_id, request.seq)
                    session.viewers.broadcast(CameraUpdate(camera=request.camera), exclude=slot)
    except (WebSocketDisconnect, RuntimeError):
        pass
    finally:
        sender.cancel()
        session.viewers.leave(slot)
        _video_source(session)
        if cell is not None:   # the cell that held the others back may be this one
            session.viewers.check_lock(time.monotonic())
        session.viewer_left(slot.viewer_id)
        session.touch()
