"""Published frames: a short ring of the newest complete frames, waiters for ``frame ≥ K``, and
the numpy compositor used when someone asks for a whole image (``GET /api/frame.png``).

Frames are kept as the nodes' encoded tiles; the viewer message is their concatenation
(no re-encoding; each viewer's copy differs only in the input number it answers) and the
composite is only built on request.
"""

from __future__ import annotations

import asyncio
import time
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from tessera.geometry import Camera, Rect
from tessera.wire.codec import Codec, encode_png, paste_into
from tessera.wire.protocol import pack_frame, with_input_seq


@dataclass
class PublishedFrame:
    """A complete frame: every tile of one camera and one scene state. ``tiles`` = (rect, codec,
    node slot, payload); ``still``: the lossless frame after motion stopped; ``inputs``: viewer id →
    the newest input sequence number of that viewer the frame accounts for; ``state_version`` and
    ``scene_time`` (s): its scene state (None: the base pose); ``tile_states``: the state each
    tile's node says it rendered (the tile header's tag); ``samples``: the samples a progressive
    still's frame holds (issue 20; 0: a frame not accumulated), ``still`` then meaning the
    converged one; ``estimate_db``: a still's estimated PSNR against its converged image (issue 37;
    None: not estimated)."""

    frame_id: int
    camera: Camera
    size: tuple[int, int]
    tiles: list[tuple[Rect, Codec, int, bytes]]
    published_at: float
    still: bool = False
    inputs: dict[object, int] = field(default_factory=dict)
    state_version: int | None = None
    scene_time: float | None = None
    tile_states: tuple[int, ...] = ()
    samples: int = 0
    estimate_db: float | None = None
    _viewer_message: bytes | None = field(default=None, repr=False)

    @property
    def viewer_message(self) -> bytes:
        """The TFRM message (input number 0)."""
        if self._viewer_message is None:
            self._viewer_message = pack_frame(self.frame_id, self.size, self.tiles, still=self.still,
                                              samples=self.samples)
        return self._viewer_message

    def message_for(self, viewer_id: object) -> bytes:
        """The TFRM message as viewer ``viewer_id`` gets it: with its own input number."""
        return with_input_seq(self.viewer_message, self.inputs.get(viewer_id, 0))


def paste_tiles(frame: PublishedFrame) -> np.ndarray:
    """Decode and paste every tile: (height, width, 3) uint8."""
    width, height = frame.size
    return paste_into(np.empty((height, width, 3), dtype=np.uint8), frame.tiles)


def encode_frame_png(frame: PublishedFrame) -> tuple[bytes, float, float]:
    """PNG of the frame (:func:`paste_tiles`), with the thread CPU milliseconds spent compositing and encoding."""
    started = time.thread_time()
    image = paste_tiles(frame)
    composed = time.thread_time()
    png = encode_png(image)
    return png, (composed - started) * 1000.0, (time.thread_time() - composed) * 1000.0


class FrameStore:
    """The newest ``capacity`` published frames, in id order; :meth:`add` is synchronous, so a frame
    is visible (and ``last_id`` current) the moment it is published."""

    def __init__(self, capacity: int = 16) -> None:
        self._frames: OrderedDict[int, PublishedFrame] = OrderedDict()
        self._capacity = capacity
        self._waiters: list[tuple[Callable[[PublishedFrame], bool], asyncio.Future[PublishedFrame]]] = []

    @property
    def latest(self) -> PublishedFrame | None:
        return next(reversed(self._frames.values()), None)

    @property
    def last_id(self) -> int:
        latest = self.latest
        return latest.frame_id if latest else -1

    def add(self, frame: PublishedFrame) -> None:
        """Keep ``frame`` (ids increase) and wake the waiters it satisfies."""
        if frame.frame_id <= self.last_id:
            raise ValueError(f"frame {frame.frame_id} published after frame {self.last_id}")
        self._frames[frame.frame_id] = frame
        while len(self._frames) > self._capacity:
            self._frames.popitem(last=False)
        waiting = []
        for wanted, future in self._waiters:
            if future.done():
                continue
            if wanted(frame):
                future.set_result(frame)
            else:
                waiting.append((wanted, future))
        self._waiters = waiting

    def newest(self, still: bool = False) -> PublishedFrame | None:
        """The newest kept frame; with ``still``, only when it is a still frame (the newest state's
        still, not an older one)."""
        latest = self.latest
        return latest if latest is not None and (latest.still or not still) else None

    def first_at_or_after(self, frame_id: int, still: bool = False) -> PublishedFrame | None:
        """The first kept frame with id ≥ ``frame_id`` (and, with ``still``, a still frame)."""
        for frame in self._frames.values():
            if frame.frame_id >= frame_id and (frame.still or not still):
                return frame
        return None

    async def wait_for(self, frame_id: int, timeout: float, still: bool = False) -> PublishedFrame | None:
        """The first frame with id ≥ ``frame_id`` (a still frame with ``still``), waiting up to
        ``timeout`` seconds for it to be published; None when none came in time."""
        kept = self.first_at_or_after(frame_id, still)
        if kept is not None:
            return kept
        future: asyncio.Future[PublishedFrame] = asyncio.get_running_loop().create_future()
        self._waiters.append((lambda f: f.frame_id >= frame_id and (f.still or not still), future))
        try:
            return await asyncio.wait_for(future, timeout)
        except TimeoutError:
            return None
