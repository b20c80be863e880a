"""Viewer fan-out: every viewer has a latest-frame slot and its own sender task, so a slow
browser only ever skips frames and never stalls the frame loop (websockets' broadcast pattern).
Control messages (hello, scene, errors) are queued in order, never dropped; a viewer that lets
:data:`MAX_QUEUED_CONTROL` pile up is not reading its socket and is closed (``behind``). Cameras
other viewers set have a latest-camera slot of their own, as frames do. Each viewer's copy of a
frame says which of that viewer's inputs it answers; each viewer reports its own input → display
latency."""

from __future__ import annotations

import asyncio
import itertools
from collections import deque
from typing import Any, Protocol

from tessera.wire.messages import CameraUpdate, Message

#: Control messages a viewer may have waiting before it counts as not reading its socket.
MAX_QUEUED_CONTROL = 256


class ViewerMessages(Protocol):
    """A published frame as each viewer gets it (``PublishedFrame``)."""

    def message_for(self, viewer_id: object) -> bytes: ...


class ViewerSlot:
    def __init__(self, viewer_id: int = 0) -> None:
        self.viewer_id = viewer_id
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
        """The next control message if any, else the newest camera, else the newest frame (waits
        for one); None once :meth:`close` was called."""
        while True:
            if self.closing is not None:
                return None
            if self.control:
                return self.control.popleft()
            if self.camera is not None:
                camera, self.camera = self.camera, None
                return camera
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
                "input_latency": dict(self.latency)}


class ViewerHub:
    def __init__(self) -> None:
        self.slots: set[ViewerSlot] = set()
        self.bytes_published = 0
        self._ids = itertools.count(1)

    def join(self) -> ViewerSlot:
        slot = ViewerSlot(next(self._ids))
        self.slots.add(slot)
        return slot

    def leave(self, slot: ViewerSlot) -> None:
        self.slots.discard(slot)

    def publish_frame(self, frame: ViewerMessages) -> None:
        """Put ``frame`` in every slot; ``bytes_published`` counts each frame once."""
        length = 0
        for slot in self.slots:
            message = frame.message_for(slot.viewer_id)
            slot.put_frame(message)
            length = len(message)
        self.bytes_published += length

    def broadcast(self, message: Message, exclude: ViewerSlot | None = None) -> None:
        """Queue ``message`` for every viewer but ``exclude``, encoded once."""
        text = message.to_text()
        for slot in self.slots:
            if slot is not exclude:
                slot.put_control(message, text)

    def describe(self) -> list[dict[str, Any]]:
        return [slot.describe() for slot in sorted(self.slots, key=lambda s: s.viewer_id)]
