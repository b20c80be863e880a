"""What a video stream's viewers see, measured as it runs (issue 37): a decoder follows the stream's
access units on a thread of its own, and every :data:`MEASURE_EVERY` th frame the decoded picture
and the tiles' JPEG at the session's quality (what a viewer on tiles gets) are compared with the
encoder's source, the tiles as received (raw from local nodes up to 1280x720; above it JPEG q88,
then the figures are against those). The pairs steer the H.264 stream's CRF
(:class:`tessera.video.quality_control.CrfControl`) and go to ``/api/stats``.

The decoder costs about 2 ms of CPU a 720p frame, a measurement about 15 ms; both on the probe's
thread, never the event loop's or the encoder's.
"""

from __future__ import annotations

import asyncio
import math
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import av
import numpy as np
from av.video.codeccontext import VideoCodecContext

from tessera.geometry import Rect
from tessera.wire.codec import Codec, encode, paste_into
from tessera.wire.video import VideoCodec

_DECODERS = {VideoCodec.H264: "h264", VideoCodec.VP9: "vp9"}
#: Frames between two measurements.
MEASURE_EVERY = 4
#: Frames after a keyframe not measured: a keyframe stays near a frame's share of the bitrate, and
#: the frames after it build the picture back up (the loop holds the picture in between).
SETTLE_FRAMES = 4
#: Frames waiting for the probe's thread beyond which it measures nothing (it decodes still).
MAX_WAITING = 4


@dataclass
class Measurement:
    """One frame's PSNR (dB, inf: exact) of the decoded video and of the tiles' JPEG at ``quality``,
    both against the encoder's source, and the probe thread's CPU ms for it."""

    video_db: float
    tiles_db: float
    quality: int
    cpu_ms: float


def psnr_db(image: np.ndarray, reference: np.ndarray) -> float:
    """PSNR (dB, inf when equal) of two uint8 arrays of one shape, over every value."""
    difference = (image.astype(np.float32) - reference).ravel()
    squared = float(np.dot(difference, difference))
    return math.inf if squared == 0.0 else 10.0 * math.log10(255.0 ** 2 * difference.size / squared)


def measure(picture: np.ndarray, tiles: list[tuple[Rect, Codec, int, bytes]], size: tuple[int, int],
            quality: int) -> tuple[float, float]:
    """PSNR (dB) of ``picture`` (the decoded video, (≥h, ≥w, 3) uint8) and of ``tiles`` coded as
    the nodes code a tile viewer's (JPEG at ``quality``, each tile on its own), both against
    ``tiles`` as they are, over the frame of ``size`` (w, h)."""
    width, height = size
    source = paste_into(np.zeros((height, width, 3), np.uint8), tiles)
    jpeg = paste_into(np.zeros_like(source), [
        (rect, Codec.JPEG, slot, encode(np.ascontiguousarray(source[rect.y:rect.y1, rect.x:rect.x1]), Codec.JPEG,
                                        quality)) for rect, _, slot, _ in tiles])
    return psnr_db(picture[:height, :width], source), psnr_db(jpeg, source)


class QualityProbe:
    """Follows one stream in ``codec``: :meth:`follow` each frame's access units in order."""

    def __init__(self, codec: VideoCodec) -> None:
        self._loop = asyncio.get_running_loop()
        self._thread = ThreadPoolExecutor(max_workers=1, thread_name_prefix=f"video-quality-{codec.label}")
        self._codec = codec
        self._decoder: VideoCodecContext | None = None
        self._since_keyframe = 0
        self._since_measured = 0
        #: Frames handed to the thread and not yet followed (counted on the event loop).
        self.waiting = 0
        #: CPU ms of the probe's thread, decoding and measuring, and the frames it followed.
        self.cpu_ms = 0.0
        self.followed = 0

    def due(self, keyframe: bool) -> bool:
        """Whether the next frame (``keyframe``: it starts with one) is to be measured."""
        self._since_keyframe = 0 if keyframe else self._since_keyframe + 1
        self._since_measured += 1
        if self._since_keyframe < SETTLE_FRAMES or self._since_measured < MEASURE_EVERY or self.waiting > MAX_WAITING:
            return False
        self._since_measured = 0
        return True

    def submit(self, units: list[tuple[bytes, bool]], tiles: list[tuple[Rect, Codec, int, bytes]] | None,
               size: tuple[int, int], quality: int | None) -> asyncio.Future[Measurement | None]:
        """Decode ``units`` (one frame's) on the probe's thread; with ``tiles`` and a JPEG ``quality``,
        measure that frame too. A future (on the event loop) of its :class:`Measurement` (None: not measured)."""
        self.waiting += 1
        task = self._loop.run_in_executor(self._thread, self._follow, units, tiles, size, quality)
        task.add_done_callback(self._followed)
        return task

    def _followed(self, _task: asyncio.Future[Measurement | None]) -> None:
        self.waiting -= 1

    def _follow(self, units: list[tuple[bytes, bool]], tiles: list[tuple[Rect, Codec, int, bytes]] | None,
                size: tuple[int, int], quality: int | None) -> Measurement | None:
        started = time.thread_time()
        try:
            pictures = []
            for unit, keyframe in units:
                if keyframe or self._decoder is None:
                    if not keyframe:
                        return None   # no keyframe since the stream (or the decoder) began
                    decoder = av.CodecContext.create(_DECODERS[self._codec], "r")
                    assert isinstance(decoder, VideoCodecContext)
                    decoder.thread_count = 1   # one thread: the probe's
                    self._decoder = decoder
                try:
                    pictures = self._decoder.decode(av.Packet(unit))
                except av.error.FFmpegError:
                    self._decoder = None   # wait for the next keyframe
                    return None
            self.followed += 1
            if tiles is None or quality is None or len(pictures) != 1:
                return None
            picture = pictures[0].to_ndarray(format="rgb24")
            video_db, tiles_db = measure(picture, tiles, size, quality)
            return Measurement(video_db, tiles_db, quality, (time.thread_time() - started) * 1000.0)
        finally:
            self.cpu_ms += (time.thread_time() - started) * 1000.0

    def close(self) -> None:
        self._thread.shutdown(wait=False, cancel_futures=True)
