"""Viewer fan-out: every viewer has a latest-frame slot and its own sender task, so a slow
browser only ever skips frames and never stalls the frame loop (websockets' broadcast pattern).
Control messages (hello, scene, errors) are queued in order, never dropped; a viewer that lets
:data:`MAX_QUEUED_CONTROL` pile up is not reading its socket and is closed (``behind``). Cameras
other viewers set have a latest-camera slot of their own, as frames do. Each viewer's copy of a
frame says which of that viewer's inputs it answers; each viewer reports its own input → display
latency.

A display wall's hub (issue 22) gives each cell viewer only its cell's tiles, rects relative to
the cell (the partition is cut at the cell edges: :mod:`tessera.decomposition.wall_cells`), built
once per cell and frame; whole-wall viewers get the whole frame. It holds the wall's frame lock
(:class:`FrameLock`): ``present`` goes to the cells once every live cell holds a frame.

Video (issue 21): a viewer that takes a video codec gets the session's stream in it
(:class:`server.video_stream.VideoStream`, one per codec, shared) instead of the interactive tiles,
and still frames (and the progressive still's refinements) as TFRM images. Its encoded frames wait
in a queue of their own (a decoder needs every frame since the last keyframe): when more than
:data:`MAX_VIDEO_QUEUED` wait, the socket cannot keep up, so the queue is emptied, the viewer skips
to the next keyframe and one is asked for; each window the viewers' links (their reports of the
newest frame received) set the stream's rate (:mod:`tessera.video.link_rate`)."""

from __future__ import annotations

import asyncio
import itertools
import time
from collections import deque
from collections.abc import Callable
from typing import Any, Protocol

from server.video_stream import EncodedFrame, VideoStream
from tessera.decomposition.wall_cells import WallLayout
from tessera.geometry import Rect
from tessera.scheduling.frame_lock import FrameLock
from tessera.video.budget import full_analysis
from tessera.video.link_rate import LinkReport
from tessera.video.quality_control import CrfLoop
from tessera.wire.codec import Codec
from tessera.wire.messages import CameraUpdate, Message
from tessera.wire.protocol import pack_frame, with_input_seq
from tessera.wire.stream_messages import StreamBitrate, StreamChoice, StreamReport
from tessera.wire.video import VideoCodec, video_frame_id
from tessera.wire.wall_messages import PresentFrame

#: Control messages a viewer may have waiting before it counts as not reading its socket.
MAX_QUEUED_CONTROL = 256
#: Encoded video frames a viewer may have waiting for its socket before it skips to a keyframe.
MAX_VIDEO_QUEUED = 3
#: Frames written to a video viewer whose receipt is remembered until it reports them (minutes at 60 fps).
MAX_UNACKNOWLEDGED = 8192


class ViewerMessages(Protocol):
    """A published frame as each viewer gets it (``PublishedFrame``)."""

    frame_id: int
    still: bool
    samples: int
    tiles: list[tuple[Rect, Codec, int, bytes]]

    def message_for(self, viewer_id: object) -> bytes: ...


def cell_message(frame: ViewerMessages, wall: WallLayout, cell: tuple[int, int]) -> bytes:
    """The TFRM message of ``frame``'s tiles inside ``cell`` (col, row) of ``wall``: a frame of the
    cell's size, rects relative to its top-left corner, the nodes' bytes as they are."""
    tiles = frame.tiles
    parts = [(rect, tiles[index][1], tiles[index][2], tiles[index][3])
             for index, rect in wall.in_cell([t[0] for t in tiles], *cell)]
    return pack_frame(frame.frame_id, wall.cell, parts, still=frame.still)


class ViewerSlot:
    """One viewer's queue; ``cell``: the wall cell (col, row) it shows (None: the whole frame)."""

    def __init__(self, viewer_id: int = 0, cell: tuple[int, int] | None = None) -> None:
        self.viewer_id = viewer_id
        self.cell = cell
        self.frame: bytes | None = None
        self.control: deque[str] = deque()
        self.camera: str | None = None
        self.behind = False
        self.ready = asyncio.Event()
        self.frames_dropped = 0
        self.frames_sent = 0
        self.latency: dict[str, float] = {}
        #: Set by :meth:`close`: the close code and reason the sender closes the socket with.
        self.closing: tuple[int, str] | None = None
        #: The video codec this viewer takes (None: tiles), its encoded frames waiting, whether it
        #: waits for a keyframe, its last report and this window's figures.
        self.video_codec: VideoCodec | None = None
        self.video: deque[bytes] = deque()
        self.needs_keyframe = False
        self.report: StreamReport | None = None
        self._reported_dropped = 0.0
        self._window = (time.monotonic(), 0, 0, 0)   # start, bytes written, frames dropped, most waiting
        #: Video bytes written to the socket in all, and (frame id, that total once it was written)
        #: for the newest frames the viewer has not said it received yet (bounded: a viewer that
        #: never reports must not grow it frame after frame).
        self.video_written = 0
        #: Video frames written to the socket in all, and the newest one's frame id (None: none yet).
        self.video_frames_written = 0
        self.newest_video_written: int | None = None
        self._written_at: deque[tuple[int, int, float]] = deque(maxlen=MAX_UNACKNOWLEDGED)   # and when (s)
        self._acknowledged = (time.monotonic(), 0)   # when the viewer last said, and the total it had then
        self._received_bps: float | None = None
        #: At the viewer's last report, how long the oldest frame written and not received yet had
        #: been on its way (s): the link's queue delay.
        self._queue_s = 0.0

    def put_video(self, message: bytes, keyframe: bool) -> bool:
        """Queue an encoded video frame; True when the viewer lost one (its queue overflowed) and
        now waits for a keyframe, which the stream is to send."""
        if self.needs_keyframe and not keyframe:
            self.frames_dropped += 1
            return False
        if keyframe:
            self.needs_keyframe = False
        elif len(self.video) >= MAX_VIDEO_QUEUED:
            lost = len(self.video) + 1
            self.frames_dropped += lost
            self.video.clear()
            self.needs_keyframe = True
            self._count(dropped=lost)
            return True
        self.video.append(message)
        self._count(waiting=len(self.video))
        self.ready.set()
        return False

    def _count(self, written: int = 0, dropped: int = 0, waiting: int = 0) -> None:
        start, total, lost, most = self._window
        self._window = (start, total + written, lost + dropped, max(most, waiting))

    def take_report(self, report: StreamReport, now: float) -> None:
        """The viewer's report at ``now``: what it received up to ``report.frame`` is no longer on its
        way; the oldest frame written after it has been on its way since it was written."""
        self.report = report
        received = None
        while self._written_at and report.frame is not None and self._written_at[0][0] <= report.frame:
            received = self._written_at.popleft()[1]
        self._queue_s = now - self._written_at[0][2] if self._written_at and report.frame is not None else 0.0
        if received is not None:
            self._received_bps = (received - self._acknowledged[1]) * 8.0 / max(now - self._acknowledged[0], 1e-3)
            self._acknowledged = (now, received)

    def link_report(self, now: float) -> LinkReport:
        """This viewer's link over the window since the last call (then a new window starts)."""
        start, written, dropped, most = self._window
        self._window = (now, 0, 0, len(self.video))
        delivered = written * 8.0 / max(now - start, 1e-3)
        viewer_dropped, in_flight_s = 0.0, 0.0
        if self.report is not None:
            viewer_dropped = max(0.0, self.report.frames_dropped - self._reported_dropped)
            self._reported_dropped = self.report.frames_dropped
        if self.report is not None and self.report.frame is not None:
            in_flight_s = self._queue_s
            delivered = self._received_bps if self._received_bps is not None else delivered
        return LinkReport(delivered_bps=delivered, dropped=dropped + int(viewer_dropped),
                          decode_queue=self.report.decode_queue if self.report else 0.0, backlog=most,
                          in_flight_s=in_flight_s)

    def put_frame(self, message: bytes) -> None:
        if self.frame is not None:
            self.frames_dropped += 1
        self.frame = message
        self.ready.set()

    def put_control(self, message: Message, text: str | None = None) -> None:
        """Queue ``message`` (``text``: its JSON when already encoded); a camera replaces one not
        sent yet. A full queue sets ``behind``."""
        if text is None:
            text = message.to_text()
        if isinstance(message, CameraUpdate):
            self.camera = text
        elif len(self.control) >= MAX_QUEUED_CONTROL:
            self.behind = True
        else:
            self.control.append(text)
        self.ready.set()

    def close(self, code: int, reason: str) -> None:
        """The viewer is to be disconnected with ``code`` and ``reason`` (its session was closed)."""
        self.closing = (code, reason)
        self.ready.set()

    async def next_message(self) -> str | bytes | None:
        """The next control message if any, else the newest camera, else the oldest video frame
        waiting, else the newest frame (waits for one); None once :meth:`close` was called."""
        while True:
            if self.closing is not None:
                return None
            if self.control:
                return self.control.popleft()
            if self.camera is not None:
                camera, self.camera = self.camera, None
                return camera
            if self.video:
                self.frames_sent += 1
                video = self.video.popleft()
                self._count(written=len(video))
                self.video_written += len(video)
                self.video_frames_written += 1
                self.newest_video_written = video_frame_id(video)
                self._written_at.append((self.newest_video_written, self.video_written, time.monotonic()))
                return video
            if self.frame is not None:
                frame, self.frame = self.frame, None
                self.frames_sent += 1
                return frame
            self.ready.clear()
            await self.ready.wait()

    def describe(self) -> dict[str, Any]:
        """This viewer in ``/api/stats``: frames sent and skipped, and the input → display latency
        it measured itself (``p50_ms``, ``p90_ms``, ``samples``, ``interval_ms``; empty until it reports)."""
        return {"id": self.viewer_id, "frames_sent": self.frames_sent, "frames_dropped": self.frames_dropped,
                "input_latency": dict(self.latency), "cell": None if self.cell is None else list(self.cell),
                "transport": self.video_codec.label if self.video_codec is not None else "tiles",
                "stream_report": self.report.model_dump() if self.report else None}


class ViewerHub:
    """The viewers of one session; ``wall``: the session's display wall, whose cell viewers get
    their cells' tiles and are frame-locked by ``lock``."""

    def __init__(self, wall: WallLayout | None = None) -> None:
        self.slots: set[ViewerSlot] = set()
        self.bytes_published = 0
        self._ids = itertools.count(1)
        self.wall = wall
        self.lock = FrameLock()
        #: The session's video streams, by codec, while a viewer takes one.
        self.streams: dict[VideoCodec, VideoStream] = {}
        #: The CRF loop of the session's last stream in each codec, and whether its frames had the
        #: fuller analysis: the next stream of frames like those starts where that one left off.
        self._crf_loops: dict[VideoCodec, tuple[bool, CrfLoop]] = {}

    def join(self, cell: tuple[int, int] | None = None, now: float = 0.0) -> ViewerSlot:
        """A new viewer, of wall cell ``cell`` (None: the whole frame); a cell joins the frame lock."""
        slot = ViewerSlot(next(self._ids), cell)
        self.slots.add(slot)
        if cell is not None:
            self.lock.join(slot.viewer_id, now)
        return slot

    def leave(self, slot: ViewerSlot) -> None:
        self.slots.discard(slot)
        self.lock.leave(slot.viewer_id)
        self.stop_video(slot)

    def start_video(self, slot: ViewerSlot, codec: VideoCodec, size: tuple[int, int], max_bitrate: float,
                    max_fps: float, tiles_quality: Callable[[], int | None] = lambda: None) -> StreamChoice:
        """``slot`` takes the session's stream in ``codec`` (made for frames of ``size`` if none
        is running; ``tiles_quality``: :class:`VideoStream`'s) from its next keyframe; the
        ``stream`` message that tells it so."""
        self.stop_video(slot)
        stream = self.streams.get(codec)
        if stream is None:
            analysis, loop = self._crf_loops.get(codec, (None, None))
            stream = self.streams[codec] = VideoStream(codec, size, max_bitrate, max_fps, self._deliver, tiles_quality,
                                                       loop if analysis == full_analysis(size) else None)
        slot.video_codec, slot.needs_keyframe = codec, True
        stream.request_keyframe()
        return StreamChoice(transport=codec.label, codec=stream.codec_string)

    def stop_video(self, slot: ViewerSlot) -> None:
        """``slot`` takes tiles again; a stream no viewer takes stops."""
        codec, slot.video_codec = slot.video_codec, None
        slot.video.clear()
        if codec is not None and not any(s.video_codec is codec for s in self.slots):
            stream = self.streams.pop(codec)
            stream.close()
            if stream.crf_loop is not None:
                self._crf_loops[codec] = (full_analysis(stream.size), stream.crf_loop)

    def request_keyframe(self, slot: ViewerSlot) -> None:
        """``slot``'s decoder lost a frame: it skips to the next keyframe, which its stream sends."""
        if slot.video_codec is not None:
            slot.needs_keyframe = True
            slot.video.clear()
            self.streams[slot.video_codec].request_keyframe()

    def _deliver(self, stream: VideoStream, encoded: EncodedFrame) -> None:
        """Hand ``stream``'s encoded frame to its viewers (each with its input number); a stream
        whose codec string changed (a new size) tells them first; then the link's window."""
        takers = [slot for slot in self.slots if slot.video_codec is stream.codec]
        messages = stream.messages(encoded)
        if stream.codec_string != stream.announced:
            stream.announced = stream.codec_string
            choice = StreamChoice(transport=stream.codec.label, codec=stream.announced)
            for slot in takers:
                slot.put_control(choice)
        inputs = encoded.frame.inputs
        for slot in takers:
            for message, keyframe in messages:
                if slot.put_video(with_input_seq(message, inputs.get(slot.viewer_id, 0)), keyframe):
                    stream.request_keyframe()
        self.bytes_published += sum(len(message) for message, _ in messages)
        now = time.monotonic()
        if takers and stream.rate.due(now) and stream.rate.update(
                [slot.link_report(now) for slot in takers], now):
            update = StreamBitrate(bitrate=float(stream.rate.bitrate), max_fps=float(stream.rate.fps))
            for slot in takers:
                slot.put_control(update)

    def message_for(self, frame: ViewerMessages, slot: ViewerSlot) -> bytes:
        """``frame`` as ``slot`` gets it: its cell's part, or the whole frame with its input number."""
        if slot.cell is None or self.wall is None:
            return frame.message_for(slot.viewer_id)
        return cell_message(frame, self.wall, slot.cell)

    def publish_frame(self, frame: ViewerMessages) -> None:
        """Put ``frame`` in every slot (a cell's part built once per cell); ``bytes_published``
        counts each whole frame once and each cell's part once."""
        length = 0
        parts: dict[tuple[int, int], bytes] = {}
        image = frame.still or frame.samples > 0   # the still and its refinements stay exact images
        for slot in self.slots:
            if slot.video_codec is not None and not image:
                continue
            if slot.cell is not None and self.wall is not None:
                if slot.cell not in parts:
                    parts[slot.cell] = cell_message(frame, self.wall, slot.cell)
                slot.put_frame(parts[slot.cell])
            else:
                message = frame.message_for(slot.viewer_id)
                slot.put_frame(message)
                length = len(message)
        self.bytes_published += length + sum(len(part) for part in parts.values())
        if not image:
            for stream in self.streams.values():
                stream.submit(frame)

    def check_lock(self, now: float) -> None:
        """Tell the wall's cells to present the frame every live one holds, if a newer one is due
        (or a cell that joined since the frame presented last, once it holds it), at the lock's
        time for it (a lead ahead of ``now``, s, the coordinator's monotonic clock: time for the
        message to reach every cell)."""
        due = self.lock.due(now)
        if not due:
            return
        messages: dict[int, tuple[PresentFrame, str]] = {}
        for slot in self.slots:
            frame_id = due.get(slot.viewer_id)
            if frame_id is not None:
                if frame_id not in messages:
                    message = PresentFrame(frame=frame_id, at_ms=self.lock.at_ms)
                    messages[frame_id] = (message, message.to_text())
                slot.put_control(*messages[frame_id])

    def broadcast(self, message: Message, exclude: ViewerSlot | None = None) -> None:
        """Queue ``message`` for every viewer but ``exclude``, encoded once (not at all when no
        one else watches: a lone viewer's camera messages, 60 a second, are not echoed)."""
        others = [slot for slot in self.slots if slot is not exclude]
        if others:
            text = message.to_text()
            for slot in others:
                slot.put_control(message, text)

    def describe(self) -> list[dict[str, Any]]:
        return [slot.describe() for slot in sorted(self.slots, key=lambda s: s.viewer_id)]

    def describe_video(self) -> list[dict[str, Any]]:
        """The session's video streams in ``/api/stats`` ``video``."""
        return [stream.describe() for stream in self.streams.values()]
