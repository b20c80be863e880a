"""Viewer fan-out: every viewer has a latest-frame slot and its own sender task, so a slow
browser only ever skips frames and never stalls the frame loop (websockets' broadcast pattern).
Control messages (camera, scene) are queued, never dropped."""

from __future__ import annotations

import asyncio
from collections import deque
from typing import Any

from tessera.protocol import encode_json


class ViewerSlot:
    def __init__(self) -> None:
        self.frame: bytes | None = None
        self.control: deque[str] = deque()
        self.ready = asyncio.Event()
        self.frames_dropped = 0
        self.frames_sent = 0

    def put_frame(self, message: bytes) -> None:
        if self.frame is not None:
            self.frames_dropped += 1
        self.frame = message
        self.ready.set()

    def put_control(self, message: dict[str, Any]) -> None:
        self.control.append(encode_json(message))
        self.ready.set()

    async def next_message(self) -> str | bytes:
        """The next control message if any, else the newest frame (waits for one)."""
        while True:
            if self.control:
                return self.control.popleft()
            if self.frame is not None:
                frame, self.frame = self.frame, None
                self.frames_sent += 1
                return frame
            self.ready.clear()
            await self.ready.wait()


class ViewerHub:
    def __init__(self) -> None:
        self.slots: set[ViewerSlot] = set()
        self.bytes_published = 0

    def join(self) -> ViewerSlot:
        slot = ViewerSlot()
        self.slots.add(slot)
        return slot

    def leave(self, slot: ViewerSlot) -> None:
        self.slots.discard(slot)

    def publish_frame(self, message: bytes) -> None:
        for slot in self.slots:
            slot.put_frame(message)
        if self.slots:
            self.bytes_published += len(message)

    def broadcast(self, message: dict[str, Any], exclude: ViewerSlot | None = None) -> None:
        for slot in self.slots:
            if slot is not exclude:
                slot.put_control(message)
