"""One session's video stream in one codec (issue 21): complete frames in, one encoded access unit
per frame out to every viewer that takes the stream.

One encoder serves all the stream's viewers. Composing (decoding the tiles) and encoding run on the
stream's own thread, never on the event loop (Pillow and PyAV release the GIL); a frame that arrives
while one is encoding waits in a one-frame slot, newest wins, and the frame rate cap of the link's
rate control (:class:`tessera.video.link_rate.LinkRate`) holds a frame back until its time. A
keyframe comes when a viewer joins or lost a frame (:meth:`request_keyframe`), and whenever the
encoder is made anew: a new frame size, a new target bitrate, or a new CRF. An H.264 stream's CRF
is held where its video's PSNR matches the tiles' (issue 37): a probe (:mod:`server.video_quality`)
decodes the stream on a thread of its own and measures both every few frames, and
:func:`tessera.video.quality_control.observe` moves the CRF. Still frames are not encoded:
viewers get them as images (TFRM) over the video.
"""

from __future__ import annotations

import asyncio
import functools
import logging
import math
import statistics
import time
from collections import deque
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any, Protocol

from server.video_encoder import VideoEncoder, default_crf
from server.video_quality import Measurement, QualityProbe
from tessera.geometry import Rect
from tessera.video.budget import full_analysis
from tessera.video.link_rate import LinkRate
from tessera.video.quality_control import HISTORY, CrfLoop, observe, restarted
from tessera.video.yuv_frame import compose_yuv420
from tessera.wire.codec import Codec
from tessera.wire.video import VideoCodec, codec_string, pack_video

#: JPEG quality of the nodes' interactive tiles while a session streams video: they are the
#: encoder's source (4:2:0, as the video is; q90 and above switch to 4:4:4, which the video drops).
#: Measured at 720p, three tiles a frame, H.264 at the default bitrate, PSNR against the render:
#: q80 29.6 KB a frame on the LAN, 41.1 dB; q88 34.0 KB, 42.2 dB; q95 (4:4:4) 61.6 KB, 42.6 dB;
#: PNG 74.0 KB, 43.0 dB (and 64 ms to decode). q88 loses 0.8 dB to lossless tiles at half their bytes.
VIDEO_SOURCE_QUALITY = 88
#: Default target bitrate per codec: bits per pixel of a picture at the nominal frame rate, within
#: --max-bitrate (720p at 60 fps: H.264 4.7 Mbit/s, 9.8 KB a frame at most; 1080p60: the 8 Mbit/s
#: cap). Both encoders stay under their target (x264 by ~25 %, libvpx-vp9 by ~45 %). Measured on the
#: default scene at 720p, frames of an orbit 18° apart (bench.stream's ~10 fps), PSNR against the
#: render, JPEG q60 tiles 24.3 KB 40.75 dB: H.264 0.08 → 6.6 KB 41.2 dB, 0.09 → 7.4 KB 41.7 dB,
#: 0.10 → 8.4 KB 42.0 dB; VP9 0.10 → 6.9 KB 41.6 dB, **0.11 → 7.5 KB 41.8 dB**, 0.12 → 8.0 KB
#: 42.0 dB (6° apart: 0.4–0.7 dB more at the same bytes). Live (bench.stream, 720p, 3 nodes, two runs
#: each, tiles 23.4 KB 43.4 dB): H.264 0.09 → 7.8 KB (tiles / 3.0), 0.5–0.6 dB above the tiles;
#: **0.085** → 7.4 KB (tiles / 3.2), 0.5–0.6 dB above.
BITS_PER_PIXEL = {VideoCodec.H264: 0.085, VideoCodec.VP9: 0.11}
#: H.264 frames smaller than this (pixels) get more bits a pixel: a small frame's blocks hold more
#: detail each. Offline (bench.stream's random cameras at 640x360, the default scene, the CRF loop
#: running): at 0.085 bit a pixel the loop reached its lowest CRF (19) with the video still 0.88 dB
#: under the JPEG q60 tiles, the cap binding; at twice that, +0.25 dB at CRF 27.
SMALL_FRAME_PIXELS = 1280 * 720
#: Figures kept for the mean and median encode times.
TIMINGS_KEPT = 240
#: Measurements of the video's and the tiles' PSNR kept for ``/api/stats`` (as many as the CRF loop decides on).
MEASUREMENTS_KEPT = HISTORY
log = logging.getLogger("tessera.server")


class VideoFrameSource(Protocol):
    """A published frame as the stream reads it (``PublishedFrame``)."""

    frame_id: int
    size: tuple[int, int]
    still: bool
    inputs: dict[object, int]
    tiles: list[tuple[Rect, Codec, int, bytes]]


@dataclass
class EncodedFrame:
    """One frame's access units (bytes, keyframe) and what they cost: ms of the stream thread's
    CPU (``*_cpu_ms``: all of it, as the decoders and encoders run on that thread alone) and of
    the wall clock."""

    frame: VideoFrameSource
    units: list[tuple[bytes, bool]]
    compose_ms: float
    encode_ms: float
    compose_cpu_ms: float
    encode_cpu_ms: float
    new_encoder: bool
    #: The CRF it was encoded at (H.264; None: VP9).
    crf: float | None = None


def default_bitrate(codec: VideoCodec, size: tuple[int, int], fps: float, max_bitrate: float) -> float:
    """The target (bit/s) of ``codec`` frames of ``size`` at ``fps``: :data:`BITS_PER_PIXEL`, within
    ``max_bitrate``; H.264 frames under :data:`SMALL_FRAME_PIXELS` get √(that / their pixels) times more
    a pixel (a cap its constant quality reaches only when the picture needs it)."""
    pixels = size[0] * size[1]
    scale = math.sqrt(max(1.0, SMALL_FRAME_PIXELS / pixels)) if codec is VideoCodec.H264 else 1.0
    return min(max_bitrate, BITS_PER_PIXEL[codec] * scale * pixels * fps)


class VideoStream:
    """The video of one session in ``codec``, of frames of ``size`` (w, h px; it follows the
    frames), up to ``max_bitrate`` (bit/s) at up to ``max_fps``; ``deliver(stream, encoded)``
    hands each encoded frame to the viewers (on the event loop); ``tiles_quality()``: the JPEG
    quality a viewer on tiles would get now (None: its tiles are not JPEG, and nothing is measured);
    ``crf_loop``: an H.264 stream's CRF loop to go on with (a former stream's of the session,
    on frames of the same options; None: a new one from :func:`server.video_encoder.default_crf`)."""

    def __init__(self, codec: VideoCodec, size: tuple[int, int], max_bitrate: float, max_fps: float,
                 deliver: Callable[[VideoStream, EncodedFrame], None],
                 tiles_quality: Callable[[], int | None] = lambda: None, crf_loop: CrfLoop | None = None) -> None:
        self.codec = codec
        self.size = size
        self.max_bitrate = max_bitrate
        self.rate = LinkRate(default_bitrate(codec, size, max_fps, max_bitrate), max_fps)
        self._deliver = deliver
        self._loop = asyncio.get_running_loop()
        self._thread = ThreadPoolExecutor(max_workers=1, thread_name_prefix=f"video-{codec.label}")
        self._encoder: VideoEncoder | None = None
        self._busy = False
        self._pending: VideoFrameSource | None = None
        self._timer: asyncio.TimerHandle | None = None
        self._keyframe_due = True
        self._last_start = float("-inf")
        self._closed = False
        #: The codec string the stream's viewers were last told (a new size may change its level).
        self.announced = self.codec_string
        self.frames_encoded = 0
        self.keyframes = 0
        self.bytes = 0
        self.encoders_made = 0
        #: The tile codecs of the newest frame encoded (``raw`` from local nodes while every viewer
        #: takes video; ``jpeg`` otherwise; None before the first).
        self.source: str | None = None
        #: Per frame: (compose, encode) ms of the wall clock, and of the stream thread's CPU.
        self._timings: deque[tuple[float, float, float, float]] = deque(maxlen=TIMINGS_KEPT)
        self._tiles_quality = tiles_quality
        self.probe = QualityProbe(codec)
        #: The CRF loop (H.264 only: libvpx-vp9 streams run at their target bitrate).
        self.crf_loop = (crf_loop or CrfLoop(default_crf(size))) if codec is VideoCodec.H264 else None
        #: The last measurements, each with the CRF its frame was encoded at (None: VP9).
        self.measurements: deque[tuple[Measurement, float | None]] = deque(maxlen=MEASUREMENTS_KEPT)

    @property
    def codec_string(self) -> str:
        """The WebCodecs codec string of the stream's frames."""
        return codec_string(self.codec, self.size, self.rate.max_fps)

    def request_keyframe(self) -> None:
        """The next frame encoded is a keyframe."""
        self._keyframe_due = True

    def submit(self, frame: VideoFrameSource) -> None:
        """Encode ``frame`` (an interactive frame) when the thread is free and the frame rate cap allows."""
        if self._closed:
            return
        self._pending = frame
        self._pump()

    def _pump(self) -> None:
        if self._busy or self._pending is None or self._closed:
            return
        wait = self._last_start + 1.0 / self.rate.fps - time.monotonic()
        if wait > 0:
            if self._timer is None:
                self._timer = self._loop.call_later(wait, self._on_timer)
            return
        frame, self._pending = self._pending, None
        keyframe, self._keyframe_due = self._keyframe_due, False
        self._busy = True
        self._last_start = time.monotonic()
        if frame.size != self.size:
            if self.crf_loop is not None:   # other options: start again; other frames: measure again
                other_options = full_analysis(frame.size) != full_analysis(self.size)
                self.crf_loop = CrfLoop(default_crf(frame.size)) if other_options else restarted(self.crf_loop)
            self.measurements.clear()
            self.size = frame.size
            self.rate.set_ceiling(default_bitrate(self.codec, frame.size, self.rate.max_fps, self.max_bitrate))
        crf = self.crf_loop.crf if self.crf_loop is not None else None
        task = self._loop.run_in_executor(self._thread, self._encode, frame, keyframe, self.rate.bitrate, crf)
        task.add_done_callback(self._done)

    def _on_timer(self) -> None:
        self._timer = None
        self._pump()

    def _encode(self, frame: VideoFrameSource, keyframe: bool, bitrate: float, crf: float | None) -> EncodedFrame:
        """On the stream's thread: compose ``frame``'s picture and encode it (a new encoder for a
        new size, bitrate or CRF)."""
        started, started_cpu = time.perf_counter(), time.thread_time()
        planes = compose_yuv420(frame.size, frame.tiles)
        composed, composed_cpu = time.perf_counter(), time.thread_time()
        encoder = self._encoder
        new_encoder = (encoder is None or encoder.size != frame.size or encoder.bitrate != int(bitrate)
                       or encoder.crf != crf)
        if new_encoder:
            encoder = self._encoder = VideoEncoder(self.codec, frame.size, bitrate, self.rate.max_fps, crf)
        assert encoder is not None
        units = encoder.encode(planes, keyframe)
        return EncodedFrame(frame, units, (composed - started) * 1000.0, (time.perf_counter() - composed) * 1000.0,
                            (composed_cpu - started_cpu) * 1000.0, (time.thread_time() - composed_cpu) * 1000.0,
                            new_encoder, encoder.crf)

    def _done(self, task: asyncio.Future[EncodedFrame]) -> None:
        self._busy = False
        if self._closed or task.cancelled():
            return
        if (error := task.exception()) is not None:
            log.warning("%s stream: a frame could not be encoded (skipped): %s", self.codec.label, error)
            self._keyframe_due = True
            self._pump()
            return
        encoded = task.result()
        self.frames_encoded += 1
        self.rate.picture()
        self.encoders_made += encoded.new_encoder
        self.keyframes += sum(key for _, key in encoded.units)
        self.bytes += sum(len(unit) for unit, _ in encoded.units)
        self._timings.append((encoded.compose_ms, encoded.encode_ms, encoded.compose_cpu_ms, encoded.encode_cpu_ms))
        self.source = "+".join(sorted({codec.name.lower() for _, codec, _, _ in encoded.frame.tiles}))
        self._deliver(self, encoded)
        self._probe(encoded)
        self._pump()

    def _probe(self, encoded: EncodedFrame) -> None:
        """Hand ``encoded`` to the probe, which measures it if one is due."""
        if not encoded.units:
            return
        quality = self._tiles_quality()
        measured = self.probe.due(encoded.units[0][1], time.monotonic()) and quality is not None
        task = self.probe.submit(encoded.units, encoded.frame.tiles if measured else None, encoded.frame.size, quality)
        if measured:
            task.add_done_callback(functools.partial(self._measured, encoded.crf))

    def _measured(self, crf: float | None, task: asyncio.Future[Measurement | None]) -> None:
        """A measurement of a frame encoded at ``crf`` came back (on the event loop): kept for the
        stats, and it steers the CRF."""
        if self._closed or task.cancelled() or task.exception() is not None:
            if not task.cancelled() and (error := task.exception()) is not None:
                log.warning("%s stream: a frame could not be measured: %s", self.codec.label, error)
            return
        measurement = task.result()
        if measurement is None:
            return
        self.measurements.append((measurement, crf))
        if self.crf_loop is not None and crf is not None:
            self.crf_loop = observe(self.crf_loop, measurement.video_db, measurement.tiles_db, crf)

    def messages(self, encoded: EncodedFrame) -> list[tuple[bytes, bool]]:
        """``encoded``'s TVID messages (input number 0), each with its keyframe flag."""
        frame = encoded.frame
        return [(pack_video(frame.frame_id, frame.size, self.codec, key, unit), key) for unit, key in encoded.units]

    def close(self) -> None:
        """No viewer takes the stream any more: stop encoding."""
        self._closed = True
        if self._timer is not None:
            self._timer.cancel()
        self._thread.shutdown(wait=False, cancel_futures=True)
        self.probe.close()

    def describe(self) -> dict[str, Any]:
        """This stream in ``/api/stats`` ``video``: codec, size, frames encoded, encode and compose
        times per frame (ms of the stream thread's CPU, ``*_cpu_ms_*``, and of the wall clock, over
        the last :data:`TIMINGS_KEPT` frames), target bitrate (bit/s), frame rate cap, the tile
        codecs it was fed last (``source``), and what viewers see: the mean PSNR (dB, 100: exact) of
        the decoded video and of the tiles' JPEG at ``tiles_quality`` against the encoder's source
        over the last :data:`MEASUREMENTS_KEPT` measurements (H.264: of frames at the CRF in use, those
        its loop decides on; None before one), the measurements
        taken, the CRF in use (H.264), its changes and whether the loop holds it (``crf_settled``: its
        last decision kept it, within the band or at a bound), and the probe's CPU ms a frame."""
        loop = self.crf_loop
        measured = [m for m, crf in self.measurements if loop is None or crf == loop.crf]
        compose, encode, compose_cpu, encode_cpu = ([timing[i] for timing in self._timings] for i in range(4))

        def mean(values: list[float]) -> float | None:
            return round(statistics.fmean(values), 3) if values else None

        return {
            "codec": self.codec.label,
            "size": list(self.size),
            "frames_encoded": self.frames_encoded,
            "encode_cpu_ms_mean": mean(encode_cpu),
            "encode_cpu_ms_p50": round(statistics.median(encode_cpu), 3) if encode_cpu else None,
            "compose_cpu_ms_mean": mean(compose_cpu),
            "encode_ms_mean": mean(encode),
            "encode_ms_p50": round(statistics.median(encode), 3) if encode else None,
            "compose_ms_mean": mean(compose),
            "bitrate": round(self.rate.bitrate),
            "max_fps": round(self.rate.fps, 2),
            "keyframes": self.keyframes,
            "encoders_made": self.encoders_made,
            "bytes": self.bytes,
            "source": self.source,
            "psnr_video_db": _mean_db([m.video_db for m in measured]),
            "psnr_tiles_db": _mean_db([m.tiles_db for m in measured]),
            "tiles_quality": self.measurements[-1][0].quality if self.measurements else None,
            "quality_measured": self.crf_loop.measured if self.crf_loop is not None else len(self.measurements),
            "crf": loop.crf if loop is not None else None,
            "crf_changes": loop.changes if loop is not None else None,
            "crf_settled": loop.settled if loop is not None else None,
            "probe_cpu_ms_mean": round(self.probe.cpu_ms / self.probe.followed, 3) if self.probe.followed else None,
        }


def _mean_db(values: list[float]) -> float | None:
    """The mean of PSNRs in dB, each at most 100 (exact), to 0.01 dB; None for none."""
    return round(statistics.fmean(min(v, 100.0) for v in values), 2) if values else None
