"""One video encoder (PyAV: libx264, libvpx-vp9) of a stream (issue 21): yuv420p pictures in, one
access unit per picture out, at a target bitrate. Low latency: no B-frames, no look-ahead, one
picture in, its packet out. A new target takes a new encoder (and so a keyframe): neither libx264
nor libvpx-vp9, as PyAV drives them, follows a bitrate changed on an open encoder (measured: frame
sizes stayed the same for 20 frames after a tenfold cut).

The target is a rate at the stream's nominal frame rate: pictures are timed ``1/fps`` apart
whatever the nodes' real rate, so each gets ``bitrate / fps`` bits on average and the link never
carries more than the target (fewer frames, fewer bits). H.264 is x264 ``ultrafast`` +
``zerolatency`` with 4×4 intra partitions and the deblocking filter back on (:data:`X264_PARAMS`),
Constrained Baseline, constant quality (:data:`X264_CRF`) capped by the target under a VBV of
:data:`BUFFER_FRAMES` pictures (a keyframe too stays near a frame's share), SPS/PPS before every
keyframe (Annex B); VP9 is libvpx ``realtime`` at the fastest speed, tuned for screen content, at
the target bitrate under the same VBV. Both run on the caller's thread
(:data:`THREADS`), so its CPU time is the encoding's. Full-range BT.601 (the pictures of
:mod:`tessera.video.yuv_frame`) is written in the stream's colour description. libx264 is GPL;
libvpx (VP9) is BSD-licensed.
"""

from __future__ import annotations

from fractions import Fraction

import av
import numpy as np

from tessera.video.yuv_frame import coded_size
from tessera.wire.video import VideoCodec

_ENCODERS = {VideoCodec.H264: "libx264", VideoCodec.VP9: "libvpx-vp9"}
#: What x264 does beyond ``ultrafast``: 4×4 intra partitions and the deblocking filter (strength
#: 0:0). Measured at 720p on the default scene, frames of an orbit 18° apart (bench.stream's ~10 fps),
#: JPEG q88 tiles as the source, 0.08 bit per pixel, one thread: ultrafast 6.44 KB a frame, 39.31 dB
#: against the render, 2.7 ms CPU; + deblocking 39.74 dB; + i4x4 40.70 dB; both 40.94 dB (6.43 KB,
#: 2.9 ms); + subme 1 41.01 dB (3.5 ms); + trellis 41.19 dB (6.0 ms); ``superfast`` 41.08 dB
#: (3.7 ms); High profile (CABAC off under ultrafast) nothing. JPEG q60 tiles: 24.3 KB, 40.75 dB.
X264_PARAMS = "partitions=i4x4:deblock=0,0"
#: x264's constant rate factor, the target a cap over it (capped CRF): a picture gets the bits its
#: quality needs up to its share of the target, where the target alone (constant bitrate) spent every
#: frame's share. Measured live (``bench.stream``, 720p, default scene, 3 nodes; JPEG q60 tiles
#: 9.5 KB a frame on the wire, 43.4 dB against render-once): the default orbit (a turn in 2 s)
#: constant bitrate 7.5 KB 43.94 dB, CRF 26 6.0 KB 43.59 dB, CRF 28 5.1 KB 43.26 dB (under the
#: tiles); an orbit of a turn in 8 s: constant bitrate 7.3 KB 44.40 dB, CRF 24 6.3 KB 44.33 dB, CRF 28
#: 4.4 KB 43.59 dB. 26: the most bits saved at the tiles' PSNR or better on both.
X264_CRF = 26
_OPTIONS = {
    VideoCodec.H264: {"preset": "ultrafast", "tune": "zerolatency", "profile": "baseline", "forced-idr": "1",
                      "x264-params": X264_PARAMS, "crf": str(X264_CRF)},
    # tune-content screen: measured as above at 0.10 bit per pixel, 6.45 KB → 6.19 KB, 40.32 → 40.98 dB, same CPU
    VideoCodec.VP9: {"deadline": "realtime", "cpu-used": "8", "lag-in-frames": "0", "row-mt": "1",
                     "error-resilient": "0", "tune-content": "screen"},
}
#: The VBV buffer: this many pictures at the cap (short: a frame's size stays near its share).
BUFFER_FRAMES = 2.0
#: Encoder threads: one, the caller's (so the thread's CPU time is the encoding's, exactly: checked
#: against the process's). Measured at 720p, 20 orbit frames 18° apart, two runs at load 5: x264 (the
#: options above, 0.09 bit per pixel) 3.31–3.35 ms CPU a frame on one thread, 3.47–3.89 ms on two
#: (slices); libvpx-vp9 7.1–7.6 ms either way. A coordinator's cores are the nodes' too: CPU counts.
THREADS = 1


class VideoEncoder:
    """Encodes pictures of ``size`` (w, h px; the coded size is even) with ``codec`` at a target
    ``bitrate`` (bit/s at ``fps`` pictures per second; H.264: at most)."""

    def __init__(self, codec: VideoCodec, size: tuple[int, int], bitrate: float, fps: float) -> None:
        self.codec = codec
        self.size = size
        width, height = coded_size(size)
        context = av.CodecContext.create(_ENCODERS[codec], "w")
        context.width, context.height = width, height
        context.pix_fmt = "yuv420p"
        context.color_range = 2   # AVCOL_RANGE_JPEG: full range
        context.colorspace = 5    # AVCOL_SPC_BT470BG: BT.601
        context.time_base = Fraction(1, 1000)
        context.framerate = Fraction(round(fps))
        context.gop_size = 1 << 30   # keyframes only when asked for
        context.thread_count = THREADS
        context.bit_rate = 0 if codec is VideoCodec.H264 else int(bitrate)   # H.264: the CRF under the cap
        context.options = {**_OPTIONS[codec], "maxrate": str(int(bitrate)),
                           "bufsize": str(int(bitrate * BUFFER_FRAMES / fps))}
        context.open()
        self._context = context
        self._interval_ms = 1000.0 / fps
        self.bitrate = int(bitrate)
        self.pictures = 0

    def encode(self, planes: np.ndarray, keyframe: bool) -> list[tuple[bytes, bool]]:
        """``planes``: (H·3/2, W) uint8 yuv420p of the coded size; ``keyframe``: force one. The
        access units out, each with its keyframe flag."""
        picture = av.VideoFrame.from_ndarray(planes, format="yuv420p")
        picture.pts = round(self.pictures * self._interval_ms)
        picture.color_range = 2
        if keyframe or self.pictures == 0:
            picture.pict_type = av.video.frame.PictureType.I
        self.pictures += 1
        return [(bytes(packet), bool(packet.is_keyframe)) for packet in self._context.encode(picture)]
