"""JSON control messages of video to the browser (issue 21), in the catalogue's style
(:mod:`tessera.wire.messages`).

viewer → coordinator: ``stream_offer`` :class:`StreamOffer` (the video codecs the viewer's
``VideoDecoder`` can decode, sent after ``hello``; none: it takes tiles), ``keyframe``
:class:`KeyframeRequest` (its decoder lost a frame: it waits for a keyframe),
``stream_report`` :class:`StreamReport` (what it received and decoded over its last report window).

coordinator → viewer: ``stream`` :class:`StreamChoice` (the transport this viewer gets: a video
codec with its WebCodecs codec string, or ``tiles``, with the reason when it is not the one asked
for), ``bitrate`` :class:`StreamBitrate` (the stream's target after a change, for the viewer's panel).
"""

from __future__ import annotations

from typing import Annotated

from pydantic import Field, StrictInt

from tessera.wire.messages import Message, NonNegative, Text

#: Longest list of codec names a viewer may offer.
MAX_OFFERED = 8
CodecLabel = Annotated[Text, Field(max_length=16)]


class StreamOffer(Message):
    """The codecs (``h264``, ``vp9``) this viewer decodes, best first."""

    kind = "stream_offer"
    codecs: Annotated[tuple[CodecLabel, ...], Field(max_length=MAX_OFFERED)]


class StreamChoice(Message):
    """``transport``: a codec name or ``tiles``; ``codec``: the WebCodecs codec string (None for
    tiles); ``reason``: why the viewer gets tiles, or another codec than it named first."""

    kind = "stream"
    transport: Text
    codec: Text | None = None
    reason: Text | None = None


class KeyframeRequest(Message):
    """The viewer's decoder lost a frame: it waits for a keyframe."""

    kind = "keyframe"


class StreamReport(Message):
    """Over the viewer's last report window: bytes received per second, frames decoded and
    painted per second, frames waiting in its decoder now, frames it dropped in all, and the
    newest video frame id it received (None: none yet) — what the coordinator wrote after that
    frame is still on its way."""

    kind = "stream_report"
    bytes_per_s: NonNegative
    decoded_fps: NonNegative
    decode_queue: NonNegative
    frames_dropped: NonNegative
    frame: Annotated[StrictInt, Field(ge=0, le=2**32 - 1)] | None = None


class StreamBitrate(Message):
    """The stream's target bitrate (bit/s) and frame rate cap (fps) now."""

    kind = "bitrate"
    bitrate: NonNegative
    max_fps: NonNegative


#: What the coordinator accepts from a viewer for its video stream.
FROM_STREAM_VIEWER = (StreamOffer, KeyframeRequest, StreamReport)
