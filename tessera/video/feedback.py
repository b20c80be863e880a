"""A video viewer's feedback, checked before it steers the stream it shares (issue 21).

One encoder serves every viewer of a session's stream: a viewer's ``stream_report`` s set that
encoder's bitrate and frame rate (the worst link rules, :mod:`tessera.video.link_rate`), and its
``keyframe`` requests make everyone's next frame a keyframe. So feedback no page sends is refused,
and the viewer closed with the reason, before any of it reaches the stream:

* a report no decoder can make: a decoder queue longer than :data:`MAX_DECODE_QUEUE`, more frames
  dropped than were sent to it, a dropped count that went down, a newest frame never sent to it
  (values that are not numbers, negative or infinite never parse: they are malformed);
* keyframe requests faster than losses come (a page asks once per loss and waits for the keyframe):
  over :data:`KEYFRAME_RATE` a second, :data:`KEYFRAME_BURST` at once;
* malformed messages again and again: the :data:`MAX_MALFORMED` th (each before it gets an error).

Pure: the clock comes in as ``now`` (s).
"""

from __future__ import annotations

from tessera.wire.stream_messages import StreamReport
from tessera.wire.token_bucket import TokenBucket

#: The longest decoder queue a report may name (a page drops delta frames once 4 wait).
MAX_DECODE_QUEUE = 64
#: Keyframe requests a second a viewer may send, and at once.
KEYFRAME_RATE = 4.0
KEYFRAME_BURST = 8
#: Malformed messages from a video viewer that close it.
MAX_MALFORMED = 3


class FeedbackGuard:
    """One video viewer's feedback since it joined (at ``now``, s); each check gives the reason to
    close the viewer, or None."""

    def __init__(self, now: float) -> None:
        self._keyframes = TokenBucket(KEYFRAME_RATE, KEYFRAME_BURST, now)
        self._dropped = 0.0
        self.malformed = 0

    def report(self, report: StreamReport, frames_sent: int, newest_sent: int | None) -> str | None:
        """``report``, from a viewer sent ``frames_sent`` video frames so far, the newest
        ``newest_sent`` (frame id; None: none)."""
        if report.decode_queue > MAX_DECODE_QUEUE:
            return (f"stream_report: decode_queue {report.decode_queue:g} is longer than any decoder's "
                    f"(at most {MAX_DECODE_QUEUE})")
        if report.frames_dropped < self._dropped:
            return f"stream_report: frames_dropped went down, from {self._dropped:g} to {report.frames_dropped:g}"
        if report.frames_dropped > frames_sent:
            return (f"stream_report: frames_dropped {report.frames_dropped:g} is more than the {frames_sent} "
                    "video frames sent to this viewer")
        if report.frame is not None and (newest_sent is None or report.frame > newest_sent):
            return f"stream_report: frame {report.frame} was never sent to this viewer (newest sent: {newest_sent})"
        self._dropped = report.frames_dropped
        return None

    def keyframe(self, now: float) -> str | None:
        """A keyframe request at ``now``."""
        if self._keyframes.take(now):
            return None
        return (f"keyframe requests faster than {KEYFRAME_RATE:g} a second ({KEYFRAME_BURST} at once): "
                "a decoder asks once per lost frame")

    def malformed_message(self) -> str | None:
        """A message that did not parse (it got an ``error``)."""
        self.malformed += 1
        return f"{self.malformed} malformed messages" if self.malformed >= MAX_MALFORMED else None
