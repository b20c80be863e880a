"""Published frames: a short ring of the newest complete frames, waiters for ``frame ≥ K``, and
the numpy compositor used when someone asks for a whole image (``GET /api/frame.png``).

Frames are kept as the nodes' encoded tiles; the viewer message is their concatenation
(no re-encoding) and the composite is only built on request.
"""

from __future__ import annotations

import asyncio
import time
from collections import OrderedDict
from dataclasses import dataclass, field

import numpy as np

from tessera.codec import Codec, decode, encode_png
from tessera.geometry import Camera, Rect
from tessera.protocol import pack_frame


@dataclass
class PublishedFrame:
    """A complete frame: every tile of one camera. ``tiles`` = (rect, codec, node_id, payload)."""

    frame_id: int
    camera: Camera
    size: tuple[int, int]
    tiles: list[tuple[Rect, Codec, int, bytes]]
    published_at: float
    _viewer_message: bytes | None = field(default=None, repr=False)

    @property
    def viewer_message(self) -> bytes:
        if self._viewer_message is None:
            self._viewer_message = pack_frame(
                self.frame_id, self.size, ((r, c, node & 0xFF, p) for r, c, node, p in self.tiles))
        return self._viewer_message


def composite(frame: PublishedFrame) -> np.ndarray:
    """Decode and paste every tile: (height, width, 3) uint8."""
    width, height = frame.size
    image = np.empty((height, width, 3), dtype=np.uint8)
    for rect, codec, _, payload in frame.tiles:
        image[rect.y:rect.y1, rect.x:rect.x1] = decode(payload, codec, rect.w, rect.h)
    return image


def composite_png(frame: PublishedFrame) -> tuple[bytes, float, float]:
    """PNG of the composite, with the thread CPU milliseconds spent compositing and encoding."""
    started = time.thread_time()
    image = composite(frame)
    composed = time.thread_time()
    png = encode_png(image)
    return png, (composed - started) * 1000.0, (time.thread_time() - composed) * 1000.0


class FrameStore:
    """The newest ``capacity`` published frames, in id order."""

    def __init__(self, capacity: int = 16) -> None:
        self._frames: OrderedDict[int, PublishedFrame] = OrderedDict()
        self._capacity = capacity
        self._changed = asyncio.Condition()

    @property
    def latest(self) -> PublishedFrame | None:
        return next(reversed(self._frames.values()), None)

    @property
    def last_id(self) -> int:
        latest = self.latest
        return latest.frame_id if latest else -1

    async def add(self, frame: PublishedFrame) -> None:
        self._frames[frame.frame_id] = frame
        while len(self._frames) > self._capacity:
            self._frames.popitem(last=False)
        async with self._changed:
            self._changed.notify_all()

    def first_at_or_after(self, frame_id: int) -> PublishedFrame | None:
        for frame in self._frames.values():
            if frame.frame_id >= frame_id:
                return frame
        return None

    async def wait_for(self, frame_id: int, timeout: float) -> PublishedFrame | None:
        """The first kept frame with id ≥ ``frame_id``, waiting up to ``timeout`` seconds."""
        kept = self.first_at_or_after(frame_id)
        if kept is not None:
            return kept
        async with self._changed:
            try:
                await asyncio.wait_for(
                    self._changed.wait_for(lambda: self.first_at_or_after(frame_id) is not None), timeout)
            except TimeoutError:
                return None
        return self.first_at_or_after(frame_id)
