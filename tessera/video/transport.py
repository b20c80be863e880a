"""Which transport a viewer gets (issue 21, ``--stream``): a video codec both the coordinator
allows and the viewer's ``VideoDecoder`` decodes, else the nodes' tiles, with the reason."""

from __future__ import annotations

from collections.abc import Sequence

from tessera.wire.video import VideoCodec

#: ``--stream`` values: ``auto`` (the first codec of :data:`AUTO_ORDER` the viewer decodes), one codec, or tiles.
STREAM_MODES = ("auto", *(codec.label for codec in VideoCodec), "tiles")
#: ``auto``'s preference: H.264 (hardware decoding nearly everywhere), then VP9.
AUTO_ORDER = (VideoCodec.H264, VideoCodec.VP9)


def choose_transport(mode: str, offered: Sequence[str]) -> tuple[VideoCodec | None, str | None]:
    """The codec a viewer that decodes ``offered`` (codec names) gets under ``--stream mode``
    (None: tiles), and why it gets tiles or not the codec it named first (None: no reason needed)."""
    names = [name.strip().lower() for name in offered]
    if mode == "tiles":
        return None, "the coordinator sends tiles (--stream tiles)"
    allowed = AUTO_ORDER if mode == "auto" else (VideoCodec.parse(mode),)
    for codec in allowed:
        if codec.label in names:
            reason = None if names[0] == codec.label else f"the coordinator sends {codec.label} (--stream {mode})"
            return codec, reason
    if not names:
        return None, "the viewer decodes no video (no WebCodecs)"
    wanted = " or ".join(codec.label for codec in allowed)
    return None, f"the viewer decodes {', '.join(names)}, not {wanted} (--stream {mode})"
