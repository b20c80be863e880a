"""Rate control of one video stream over its viewers' links (issue 21): the encoder keeps a
constant quality (CRF) under a bitrate cap, and the cap follows the link — additive increase,
multiplicative decrease, as TCP-friendly senders and Selkies' and Pixel Streaming's congestion
control do. When the link cannot carry even the lowest cap, the frame rate comes down next.

A report window is congested when a viewer dropped frames (its decoder's queue overflowed, or its
socket held frames back so long the coordinator dropped them), when frames wait in its decoder, when
frames waited to be written to its socket, or when a frame written but not yet received had been
on its way more than :data:`MAX_IN_FLIGHT_S` (the viewer says which frame it received last: the
buffers of a slow link fill, and delay every frame, long before the coordinator's socket does).
The cap is a rate at the stream's nominal frame rate (the encoder gives each picture ``cap / max_fps``
bits, :mod:`server.video_encoder`), so what got through a congested window is taken at that rate
too: the bits a picture delivered times ``max_fps``. A stream whose nodes drew fewer pictures (a
large scene, a loaded machine) delivers fewer bits at the same bits a picture; taken as they came,
one congested window of 720p frames at 2 a second (5 KB each, 80 kbit/s) brought the cap from
4.7 Mbit/s to the 200 kbit/s floor, 420 bytes a picture, which decodes to about 10 dB.
Pure: the clock comes in as ``now`` (s)."""

from __future__ import annotations

from dataclasses import dataclass

#: Lowest bitrate cap (bit/s) before the frame rate comes down.
MIN_BITRATE = 200_000
#: Lowest frame rate cap (fps).
MIN_FPS = 4.0
#: On congestion the cap becomes this share of the smaller of the cap and the rate delivered (at
#: the nominal frame rate: the bits a picture delivered times ``max_fps``).
DECREASE = 0.7
#: :data:`CLEAN_WINDOWS` clean windows in a row raise the cap by this factor (the frame rate first,
#: up to the session's cap). Each new bitrate takes a new encoder and a keyframe, so steps are few.
INCREASE = 1.25
CLEAN_WINDOWS = 3
#: Frames waiting in a viewer's decoder that count as congestion.
MAX_DECODE_QUEUE = 3
#: Frames waiting for a viewer's socket at once that count as congestion.
MAX_BACKLOG = 2
#: Seconds a frame has been on its way to a viewer (written, not received) that count as congestion.
MAX_IN_FLIGHT_S = 0.3
#: Shortest time (s) between two changes: a report window.
WINDOW_S = 1.0


@dataclass
class LinkReport:
    """One viewer's window: ``delivered_bps`` (bit/s it received, or written to its socket when
    it does not say), ``dropped`` frames (the viewer's and the coordinator's), ``decode_queue``
    frames waiting in its decoder (its last report), ``backlog`` the most frames waiting for its
    socket at once, ``in_flight_s`` how long the oldest frame written but not received had been on its
    way at its last report (s: the link's queue delay)."""

    delivered_bps: float
    dropped: int
    decode_queue: float
    backlog: int
    in_flight_s: float = 0.0

    @property
    def congested(self) -> bool:
        return (self.dropped > 0 or self.decode_queue > MAX_DECODE_QUEUE or self.backlog >= MAX_BACKLOG
                or self.in_flight_s > MAX_IN_FLIGHT_S)


class LinkRate:
    """The stream's bitrate cap (bit/s) and frame rate cap (fps), within ``max_bitrate`` and ``max_fps``."""

    def __init__(self, max_bitrate: float, max_fps: float) -> None:
        self.max_bitrate = max(float(max_bitrate), MIN_BITRATE)
        self.max_fps = max(float(max_fps), MIN_FPS)
        self.bitrate = self.max_bitrate
        self.fps = self.max_fps
        self.window_start = float("-inf")
        self.decreases = 0
        self.clean = 0
        #: Pictures the stream encoded since the window began (:meth:`picture`).
        self.pictures = 0

    def picture(self) -> None:
        """The stream encoded a picture (counted for the window's picture rate)."""
        self.pictures += 1

    def due(self, now: float) -> bool:
        """A report window ended at ``now``: the viewers' reports are wanted."""
        return now - self.window_start >= WINDOW_S

    def update(self, reports: list[LinkReport], now: float) -> bool:
        """Follow the viewers' ``reports`` of the window ending ``now`` (the worst link rules:
        one encoder serves them all); True when a cap changed."""
        if not reports or not self.due(now):
            return False
        before = (self.bitrate, self.fps)
        congested = [r for r in reports if r.congested]
        self.clean = 0 if congested else self.clean + 1
        if congested:
            delivered = min((r.delivered_bps for r in congested if r.delivered_bps > 0), default=self.bitrate)
            pictures_per_s = self.pictures / (now - self.window_start) if now > self.window_start else 0.0
            if pictures_per_s > 0.0:   # at the nominal rate: the bits a picture delivered times max_fps
                delivered *= max(1.0, self.max_fps / pictures_per_s)
            if self.bitrate > MIN_BITRATE:
                self.bitrate = max(MIN_BITRATE, DECREASE * min(self.bitrate, delivered))
            else:
                self.fps = max(MIN_FPS, DECREASE * self.fps)
            self.decreases += 1
        elif self.clean >= CLEAN_WINDOWS and self.fps < self.max_fps:
            self.fps, self.clean = min(self.max_fps, INCREASE * self.fps), 0
        elif self.clean >= CLEAN_WINDOWS:
            self.bitrate, self.clean = min(self.max_bitrate, INCREASE * self.bitrate), 0
        self.window_start, self.pictures = now, 0
        return (self.bitrate, self.fps) != before

    def set_ceiling(self, max_bitrate: float) -> None:
        """A new highest cap (bit/s: the stream's frames changed size); a cap the link brought down stays down."""
        self.max_bitrate = max(float(max_bitrate), MIN_BITRATE)
        self.bitrate = min(self.max_bitrate, self.bitrate) if self.decreases else self.max_bitrate
