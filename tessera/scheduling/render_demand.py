"""Render on demand (trame's and TurboVNC's habit, DESIGN "Render on demand"): which kind of frame
the state asks for. A frame is owed when something changed since the newest frame started, while
an animation plays, for at most ``settle_frames`` more frames after a change while the partition
still moves, and once, in the still codec, after nothing changed for ``still_delay_s``. Pure: the
clock comes in as ``now`` (s)."""

from __future__ import annotations

INTERACTIVE = "interactive"
STILL = "still"


class RenderDemand:
    """Versions of the state: ``version`` rises with every change (at ``changed_at``); the newest
    version a frame started with, a still frame showed, a published frame showed."""

    def __init__(self, settle_frames: int, still_delay_s: float, still_frames: bool) -> None:
        self.settle_frames, self.still_delay_s, self.still_frames = settle_frames, still_delay_s, still_frames
        self.version = 0
        self.changed_at = 0.0
        self._started = 0
        self._still = 0
        self._published = 0
        self._settle_left = 0

    def changed(self, now: float) -> None:
        """Something that needs a new frame changed at ``now``."""
        self.version += 1
        self.changed_at = now
        self._settle_left = self.settle_frames

    def owed(self, now: float, animating: bool, partition_moving: bool, frames_in_flight: bool,
             ignore_quiet: bool = False) -> str | None:
        """:data:`INTERACTIVE`, :data:`STILL` or None: the kind of frame owed at ``now``
        (``ignore_quiet``: as if the still frame's quiet time had passed)."""
        if self.version > self._started or animating:
            return INTERACTIVE
        if self._settle_left > 0 and partition_moving:
            return INTERACTIVE
        quiet = ignore_quiet or now >= self.quiet_until
        if self.still_frames and self._still < self.version and quiet and not frames_in_flight:
            return STILL
        return None

    @property
    def settling(self) -> bool:
        """Settle frames are left: whether the partition still moves matters."""
        return self._settle_left > 0

    @property
    def quiet_until(self) -> float:
        """When the still frame is due if nothing changes (s)."""
        return self.changed_at + self.still_delay_s

    def started(self, still: bool) -> None:
        """A frame of the current version started."""
        if still:
            self._still, self._settle_left = self.version, 0
            return
        if self._started == self.version:
            self._settle_left -= 1
        self._started = self.version

    def published(self, version: int) -> bool:
        """A frame of ``version`` was published; True when it is the first to show that version."""
        first = version > self._published
        self._published = max(self._published, version)
        return first
