"""What a video stream's viewers see, measured as it runs (issue 37): a decoder follows the stream's
access units on a thread of its own, and as often as :data:`MEASURE_SHARE` of a core allows the
decoded picture and the tiles' JPEG at the session's quality (what a viewer on tiles gets) are
compared with the encoder's source, the tiles as received (raw from local nodes up to 1280x720;
above it JPEG q88, and then the figures are against those). The pairs steer the H.264 stream's CRF
(:class:`tessera.video.quality_control.CrfControl`) and go to ``/api/stats``.

The decoded picture is taken back to RGB as JFIF, rounded (:func:`tessera.video.yuv_frame.rgb_of_yuv420`),
not by FFmpeg's conversion, whose truncation cost the video up to 10 dB on a lossless stream (and
so steered the CRF down to spend bytes on the measurement's loss).

The decoder costs about 2 ms of CPU a 720p frame, a measurement about 15 ms more; both on the
probe's thread, never the event loop's or the encoder's. Measurements are paced by their CPU time,
not by frames: a slow stream (a few frames a second) is measured nearly every frame, so its CRF
settles in seconds, and a fast one no more than the share allows.
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
from tessera.video.yuv_frame import decoded_planes, rgb_of_yuv420
from tessera.wire.codec import Codec, encode, paste_into
from tessera.wire.video import VideoCodec

_DECODERS = {VideoCodec.H264: "h264", VideoCodec.VP9: "vp9"}
#: The share of one core the measurements may take, over time (the decoding not counted).
MEASURE_SHARE = 0.1
#: The CPU ms a measurement is taken to cost before the first says (a 720p frame's, about).
FIRST_COST_MS = 15.0
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
    """Follows one stream in ``codec``: :meth:`submit` each frame's access units in order (on the
    event loop), after asking :meth:`due` whether to measure it."""

    def __init__(self, codec: VideoCodec) -> None:
        self._loop = asyncio.get_running_loop()
        self._thread = ThreadPoolExecutor(max_workers=1, thread_name_prefix=f"video-quality-{codec.label}")
        self._codec = codec
        self._decoder: VideoCodecContext | None = None
        self._since_keyframe = 0
        #: CPU ms the measurements may still spend, as of ``_credit_at`` (monotonic s), and what one costs.
        self._credit_ms = self.cost_ms = FIRST_COST_MS
        self._credit_at = time.monotonic()
        #: Frames handed to the thread and not yet followed (counted on the event loop).
        self.waiting = 0
        #: CPU ms of the probe's thread, decoding and measuring, and the frames it followed.
        self.cpu_ms = 0.0
        self.followed = 0

    def due(self, keyframe: bool, now: float) -> bool:
        """Whether the next frame (``keyframe``: it starts with one), at ``now`` (monotonic s), is
        to be measured: not just after a keyframe, not while frames wait, and within the CPU share."""
        self._since_keyframe = 0 if keyframe else self._since_keyframe + 1
        self._credit_ms = min(self._credit_ms + (now - self._credit_at) * 1000.0 * MEASURE_SHARE, 2.0 * self.cost_ms)
        self._credit_at = now
        if self._since_keyframe < SETTLE_FRAMES or self.waiting > MAX_WAITING or self._credit_ms < self.cost_ms:
            return False
        self._credit_ms -= self.cost_ms
        return True

    def submit(self, units: list[tuple[bytes, bool]], tiles: list[tuple[Rect, Codec, int, bytes]] | None,
               size: tuple[int, int], quality: int | None) -> asyncio.Future[Measurement | None]:
        """Decode ``units`` (one frame's) on the probe's thread; with ``tiles`` and a JPEG ``quality``,
        measure that frame too. A future (on the event loop) of its :class:`Measurement` (None: not measured)."""
        self.waiting += 1
        task = self._loop.run_in_executor(self._thread, self._follow, units, tiles, size, quality)
        task.add_done_callback(self._followed)
        return task

    def _followed(self, task: asyncio.Future[Measurement | None]) -> None:
        self.waiting -= 1
        if not task.cancelled() and task.exception() is None and (measurement := task.result()) is not None:
            self.cost_ms = max(measurement.cpu_ms, 1.0)

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
            picture = rgb_of_yuv420(decoded_planes(pictures[0]), size)
            video_db, tiles_db = measure(picture, tiles, size, quality)
            return Measurement(video_db, tiles_db, quality, (time.thread_time() - started) * 1000.0)
        finally:
            self.cpu_ms += (time.thread_time() - started) * 1000.0

    def close(self) -> None:
        self._thread.shutdown(wait=False, cancel_futures=True)
