"""One video encoder (PyAV: libx264, libvpx-vp9) of a stream: yuv420p pictures in, one
access unit per picture out, at a target bitrate. Low latency: no B-frames, no look-ahead, one
picture in, its packet out. A new target or CRF takes a new encoder (and so a keyframe): neither
libx264 nor libvpx-vp9, as PyAV drives them, follows a rate option changed on an open encoder (PyAV
sets codec options only when it opens one).

The target is a rate at the stream's nominal frame rate: pictures are timed ``1/fps`` apart whatever
the nodes' real rate, so each gets ``bitrate / fps`` bits on average and the link never carries more
than the target (fewer frames, fewer bits). H.264 is x264 ``ultrafast`` + ``zerolatency`` with what
pays for itself on top (:data:`X264_PARAMS`: CABAC, 8×8 inter partitions, sub-pixel refinement,
trellis), Main profile, constant quality (a CRF: :data:`X264_CRF` at first, then where the
stream's loop holds it, :mod:`tessera.video.quality_control`) capped by the target under a VBV of
:data:`BUFFER_FRAMES` pictures (a keyframe too stays near a frame's share), SPS/PPS before every
keyframe (Annex B); VP9 is libvpx ``realtime`` at the fastest speed, tuned for screen content, at
the target bitrate under the same VBV. Both run on the caller's thread (:data:`THREADS`), so its CPU
time is the encoding's. Full-range BT.601 (the pictures of :mod:`tessera.video.yuv_frame`) is
written in the stream's colour description. libx264 is GPL; libvpx (VP9) is BSD-licensed.
"""

from __future__ import annotations

from fractions import Fraction

import av
import numpy as np

from tessera.video.budget import full_analysis
from tessera.video.yuv_frame import coded_size
from tessera.wire.video import VideoCodec

_ENCODERS = {VideoCodec.H264: "libx264", VideoCodec.VP9: "libvpx-vp9"}
#: What x264 does beyond ``ultrafast`` (and so the Main profile: CABAC): 4×4 intra and 8×8 inter
#: partitions, deblocking at 1:1, CABAC, sub-pixel refinement 2, a hexagon search, trellis and a
#: chroma QP offset of −4 (chroma costs PSNR more than bits). Each option chosen by its PSNR per
#: byte and per millisecond at 720p, the offset by the bytes at the tiles' PSNR over random
#: cameras (``bench.video_rd``): see the design notes.
X264_PARAMS = "partitions=i4x4,p8x8:deblock=1,1:cabac=1:subme=2:me=hex:trellis=1:chroma-qp-offset=-4"
#: x264's constant rate factor a stream starts at, the target a cap over it (capped CRF): a picture
#: gets the bits its quality needs up to its share of the target, where the target alone (constant
#: bitrate) would spend every frame's share. 28.5: the fewest bits that stay above the JPEG q60
#: tiles' PSNR on the default scene (``bench.stream``: see the design notes); the stream's loop
#: moves it from there.
X264_CRF = 28.5
#: Frames larger than :data:`tessera.video.budget.FULL_ANALYSIS_PIXELS`, encoded from JPEG q88 tiles:
#: ``ultrafast`` with 4×4 intra partitions, the deblocking filter and CABAC, at CRF 26.
X264_LIGHT_PARAMS = "partitions=i4x4:deblock=0,0:cabac=1"
X264_LIGHT_CRF = 26
_OPTIONS = {
    VideoCodec.H264: {"preset": "ultrafast", "tune": "zerolatency", "profile": "main", "forced-idr": "1",
                      "x264-params": X264_PARAMS},
    # tune-content screen: fewer bytes and more dB on rendered frames at the same CPU (see the design notes)
    VideoCodec.VP9: {"deadline": "realtime", "cpu-used": "8", "lag-in-frames": "0", "row-mt": "1",
                     "error-resilient": "0", "tune-content": "screen"},
}
#: The VBV buffer: this many pictures at the cap (short: a frame's size stays near its share).
BUFFER_FRAMES = 2.0
#: Encoder threads: one, the caller's (so the thread's CPU time is the encoding's, exactly). A second
#: thread (slices) cost as much CPU a frame or more (see the design notes), and a coordinator's cores
#: are the nodes' too: CPU counts.
THREADS = 1


def default_crf(size: tuple[int, int]) -> float:
    """The CRF an H.264 stream of frames of ``size`` (w, h px) starts at."""
    return X264_CRF if full_analysis(size) else X264_LIGHT_CRF


class VideoEncoder:
    """Encodes pictures of ``size`` (w, h px; the coded size is even) with ``codec`` at a target
    ``bitrate`` (bit/s at ``fps`` pictures per second; H.264: at most, at constant quality ``crf``,
    None: :func:`default_crf`); ``extra_params``: x264 options appended to the H.264 ones (``:``-separated,
    for measurements: ``bench.video_rd``); ``options``: the encoder's options as opened (H.264: the
    fuller analysis up to 1280×720, :mod:`tessera.video.budget`)."""

    def __init__(self, codec: VideoCodec, size: tuple[int, int], bitrate: float, fps: float,
                 crf: float | None = None, extra_params: str = "") -> None:
        self.codec = codec
        self.size = size
        self.crf = (default_crf(size) if crf is None else float(crf)) if codec is VideoCodec.H264 else None
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
        options = dict(_OPTIONS[codec])
        if codec is VideoCodec.H264:
            options["crf"] = f"{self.crf:g}"
            if not full_analysis(size):
                options["x264-params"] = X264_LIGHT_PARAMS
            if extra_params:
                options["x264-params"] += ":" + extra_params
        context.options = self.options = {**options, "maxrate": str(int(bitrate)),
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
