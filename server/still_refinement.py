"""The progressive still on the coordinator (issue 20): each sample frame of a session's still is
decoded, added to the session's :class:`tessera.scheduling.refinement.Accumulator` and the running
mean encoded again as the frame's tiles, on one worker thread shared by the sessions (about 0.1 s
of CPU per 1280x720 sample: off the event loop, so input is read meanwhile). The service publishes
the result when nothing changed since: the last sample's as the still frame.

Why here and not in the viewer: the converged still must also be served as one image
(``GET /api/frame.png?still=true``), and old viewers that draw what they get show the improving
picture; accumulating in the page instead would send the same bytes (every sample's lossless tiles)
and spare the coordinator's encoding (about half of that CPU time, ``coordinator_cpu.still_ms``)
but not its decoding and summing for the API.
"""

from __future__ import annotations

import time
from concurrent.futures import Executor, Future

from tessera.geometry import Rect
from tessera.scheduling.refinement import Accumulator
from tessera.wire.codec import Codec, decode, encode

#: A frame's tiles as published: (rect, codec, node slot, payload).
Tiles = list[tuple[Rect, Codec, int, bytes]]


class StillRefiner:
    """One session's accumulated still. :meth:`submit` hands a sample's tiles to ``executor`` (one
    thread: samples are added in order) and gives a future of the mean's tiles (None: a sample
    came out of turn and was not added); ``pending`` counts those whose result the event loop has
    not taken yet (:meth:`taken`)."""

    def __init__(self, executor: Executor) -> None:
        self._executor = executor
        self._accumulator: Accumulator | None = None
        self.pending = 0
        #: CPU time of the worker thread spent on this session's samples, ms.
        self.cpu_ms = 0.0

    def submit(self, sample: int, size: tuple[int, int], tiles: Tiles, codec: Codec,
               quality: int) -> Future[Tiles | None]:
        """Add sample ``sample`` (0: a new still) of a ``size`` frame, its ``tiles``; the mean's
        tiles come encoded in ``codec`` (``quality``: JPEG only)."""
        self.pending += 1
        return self._executor.submit(self._add, sample, size, tiles, codec, quality)

    def taken(self) -> None:
        """The event loop took a sample's result."""
        self.pending -= 1

    def _add(self, sample: int, size: tuple[int, int], tiles: Tiles, codec: Codec, quality: int) -> Tiles | None:
        started = time.thread_time()
        try:
            if sample == 0:
                self._accumulator = Accumulator(size)
            accumulator = self._accumulator
            if accumulator is None or accumulator.size != size or accumulator.count != sample:
                return None
            for rect, tile_codec, _, payload in tiles:
                accumulator.add(decode(payload, tile_codec, rect.w, rect.h), rect.x, rect.y)
            accumulator.finish_sample()
            return [(rect, codec, slot, encode(accumulator.mean(rect.x, rect.y, rect.w, rect.h), codec, quality))
                    for rect, _, slot, _ in tiles]
        finally:
            self.cpu_ms += (time.thread_time() - started) * 1e3
