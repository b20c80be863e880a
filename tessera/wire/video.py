"""Video to the browser (issue 21): the binary message of one encoded video frame, and the codecs
a stream may use with the WebCodecs codec string each is decoded with.

Message ``TVID`` (all integers little-endian), mirrored in ``web/video_protocol.js``:
header ``<4sBBBBIIII``: magic, version (:data:`PROTOCOL_VERSION`), flags (bit 0
:data:`VIDEO_KEYFRAME`: the decoder may start here), codec (:class:`VideoCodec`), reserved,
frame_id, width, height, input_seq (as a TFRM frame's, at the same offset 20, so one viewer's copy is
made by :func:`tessera.wire.protocol.with_input_seq`); then one access unit: H.264 in Annex B with
SPS/PPS before every keyframe, VP9 as the encoder's packet.
"""

from __future__ import annotations

import enum
import struct
from dataclasses import dataclass

from tessera.wire.protocol import PROTOCOL_VERSION, ProtocolError

VIDEO_MAGIC = b"TVID"
VIDEO_KEYFRAME = 0x01
_VIDEO_HEADER = struct.Struct("<4sBBBBIIII")
VIDEO_HEADER_SIZE = _VIDEO_HEADER.size


class VideoCodec(enum.IntEnum):
    """A stream's codec; its name is what ``--stream`` and the viewer's ``stream_offer`` say."""

    H264 = 0
    VP9 = 1

    @property
    def label(self) -> str:
        return self.name.lower()

    @classmethod
    def parse(cls, name: str) -> VideoCodec:
        try:
            return cls[name.strip().upper()]
        except KeyError:
            raise ValueError(f"unknown video codec {name!r}; choose from "
                             f"{', '.join(c.label for c in cls)}") from None


#: H.264 levels (level_idc, largest frame in 16×16 macroblocks, macroblocks per second), Table A-1.
_H264_LEVELS = ((30, 1620, 40500), (31, 3600, 108000), (32, 5120, 216000), (40, 8192, 245760),
                (42, 8704, 522240), (50, 22080, 589824), (51, 36864, 983040), (52, 36864, 2073600),
                (60, 139264, 4177920))
#: VP9 levels (level × 10, largest frame in pixels, pixels per second), the VP9 levels table.
_VP9_LEVELS = ((10, 36864, 829440), (11, 73728, 2764800), (20, 122880, 4608000), (21, 245760, 9216000),
               (30, 552960, 20736000), (31, 983040, 36864000), (40, 2228224, 83558400),
               (41, 2228224, 160432128), (50, 8912896, 311951360), (51, 8912896, 588251136),
               (52, 8912896, 1176502272), (60, 35651584, 1176502272), (61, 35651584, 2353004544))


def codec_string(codec: VideoCodec, size: tuple[int, int], fps: float = 60.0) -> str:
    """The WebCodecs codec string of ``codec`` for frames of ``size`` (w, h px) at up to ``fps``:
    H.264 Main (``avc1.4d40LL``: CABAC), VP9 profile 0 8-bit (``vp09.00.LL.08``); the
    level is the smallest that holds the size and rate."""
    width, height = size
    if codec is VideoCodec.H264:
        blocks = -(-width // 16) * -(-height // 16)
        level = next((idc for idc, frame, rate in _H264_LEVELS if blocks <= frame and blocks * fps <= rate), 62)
        return f"avc1.4d40{level:02x}"
    pixels = width * height
    level = next((lvl for lvl, frame, rate in _VP9_LEVELS if pixels <= frame and pixels * fps <= rate), 62)
    return f"vp09.00.{level:02d}.08"


@dataclass(frozen=True)
class VideoFrame:
    """A parsed ``TVID`` message; ``data``: the access unit."""

    frame_id: int
    size: tuple[int, int]
    codec: VideoCodec
    keyframe: bool
    input_seq: int
    data: bytes


def pack_video(frame_id: int, size: tuple[int, int], codec: VideoCodec, keyframe: bool, data: bytes,
               input_seq: int = 0) -> bytes:
    """The ``TVID`` message of one access unit ``data`` of frame ``frame_id``."""
    flags = VIDEO_KEYFRAME if keyframe else 0
    return _VIDEO_HEADER.pack(VIDEO_MAGIC, PROTOCOL_VERSION, flags, int(codec), 0, frame_id, size[0], size[1],
                              input_seq) + data


def is_video(message: bytes) -> bool:
    """The binary viewer message is a ``TVID`` video frame (not a TFRM frame of tiles)."""
    return message[:4] == VIDEO_MAGIC


def video_frame_id(message: bytes) -> int:
    """The frame id of a packed ``TVID`` message (no checks: the coordinator's own messages)."""
    return int.from_bytes(message[8:12], "little")


def unpack_video(message: bytes) -> VideoFrame:
    """Parse a ``TVID`` message; ProtocolError on anything malformed."""
    if len(message) < VIDEO_HEADER_SIZE:
        raise ProtocolError("video message shorter than its header")
    magic, version, flags, codec, _, frame_id, width, height, input_seq = _VIDEO_HEADER.unpack_from(message)
    if magic != VIDEO_MAGIC or version != PROTOCOL_VERSION:
        raise ProtocolError(f"bad video magic/version {magic!r}/{version}")
    try:
        video_codec = VideoCodec(codec)
    except ValueError:
        raise ProtocolError(f"unknown video codec {codec}") from None
    if len(message) == VIDEO_HEADER_SIZE:
        raise ProtocolError("video message without an access unit")
    return VideoFrame(frame_id, (width, height), video_codec, bool(flags & VIDEO_KEYFRAME), input_seq,
                      bytes(message[VIDEO_HEADER_SIZE:]))
