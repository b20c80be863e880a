"""Render on demand (trame's and TurboVNC's habit, DESIGN "Render on demand"): which kind of frame
the state asks for. A frame is owed when something changed since the newest frame started, while
an animation plays, for at most ``settle_frames`` more frames after a change while the partition
still moves, and, in the still codec, after nothing changed for ``still_delay_s`` and no
interactive frame is in flight: the progressive still's samples one frame after the other
(:mod:`tessera.scheduling.refinement`: a fixed count, or an adaptive still's until the coordinator
says it converged, :meth:`RenderDemand.still_converged`); a sample may start while the one before
is in flight (the frame scheduler caps how many), so that no node idles between them. A point
cloud's still that left points in view out (issue 36: too many in view, drawn down to a spacing on
screen; :meth:`RenderDemand.points_left_out`) is refined in a second pass once it converged: a still
of every point, of the same plan, whose samples start from the first again
(:attr:`RenderDemand.every_point`). Pure: the clock comes in as ``now`` (s)."""

from __future__ import annotations

from tessera.scheduling.refinement import RefinementPlan, StillPlan

INTERACTIVE = "interactive"
STILL = "still"
#: A settle frame waits this long after the last change (s): input that comes in bursts (the
#: notebook's comm sends the newest camera as each frame comes back) would otherwise find the
#: node taken by a settle frame of the camera before it, and wait a whole frame more.
SETTLE_GRACE_S = 0.05


class RenderDemand:
    """Versions of the state: ``version`` rises with every change (at ``changed_at``); the newest
    version a frame started with, whose still's every sample started, whose still is being
    refined (:attr:`refinement`: its samples started), a published frame showed, whose still
    left points out (a converged one is then followed by a still of every point: :attr:`every_point`
    while that pass is refined)."""

    def __init__(self, settle_frames: int, still_delay_s: float, still_frames: bool,
                 still_samples: StillPlan | int = 1) -> None:
        self.settle_frames, self.still_delay_s, self.still_frames = settle_frames, still_delay_s, still_frames
        self.refinement = RefinementPlan(still_samples)
        self.version = 0
        self.changed_at = 0.0
        self._started = 0
        self._still = 0
        self._refining = 0
        self._published = 0
        self._settle_left = 0
        self._left_out = 0
        #: The still being refined is a point cloud's still of every point (issue 36).
        self.every_point = False

    def changed(self, now: float) -> None:
        """Something that needs a new frame changed at ``now``."""
        self.version += 1
        self.changed_at = now
        self._settle_left = self.settle_frames
        self.every_point = False

    def rest(self) -> None:
        """No settle frames and no still for the current version: only its frame, if not started."""
        self._settle_left = 0
        self._still = self.version

    def still_dropped(self, version: int) -> None:
        """A still frame of ``version`` was dropped: when nothing changed since (e.g. the nodes'
        data partition did), that still starts again from its first sample."""
        if version == self.version and not (self._refining == version and self.refinement.finished):
            self._still = min(self._still, version - 1)
            self.refinement.restart()

    def still_converged(self, version: int) -> bool:
        """The coordinator found the still of ``version`` converged (an adaptive still's estimate
        reached its target): no more samples are owed, or, where that still left points out, the
        still of every point's are, from its first. False when that still is not the one being
        refined (the state changed since) or was already done."""
        if version != self.version or self._refining != version or self.refinement.finished:
            return False
        if self._left_out == version and not self.every_point:
            self.every_point = True
            self.refinement.restart()
            self._still = min(self._still, version - 1)
            return True
        self.refinement.finish()
        self._still = version
        return True

    def points_left_out(self, version: int) -> None:
        """A sample of the still of ``version`` left points in view out (a node said so)."""
        if not self.every_point:
            self._left_out = max(self._left_out, version)

    def owed(self, now: float, animating: bool, partition_moving: bool, interactive_in_flight: bool,
             ignore_quiet: bool = False) -> str | None:
        """:data:`INTERACTIVE`, :data:`STILL` or None: the kind of frame owed at ``now``
        (``interactive_in_flight``: an interactive frame is in flight, which the still waits for;
        ``ignore_quiet``: as if the still frame's quiet time had passed)."""
        if self.version > self._started or animating:
            return INTERACTIVE
        if self._settle_left > 0 and partition_moving and (ignore_quiet or now >= self.settle_from):
            return INTERACTIVE
        quiet = ignore_quiet or now >= self.quiet_until
        if self.still_frames and self._still < self.version and quiet and not interactive_in_flight:
            return STILL
        return None

    @property
    def settling(self) -> bool:
        """Settle frames are left: whether the partition still moves matters."""
        return self._settle_left > 0

    @property
    def settle_from(self) -> float:
        """When a settle frame may start if nothing changes (s)."""
        return self.changed_at + SETTLE_GRACE_S

    def due(self, now: float, owed: str) -> float:
        """When the frame of kind ``owed`` (:meth:`owed` with ``ignore_quiet``) may start: a still
        once quiet, a settle frame after its grace, a frame of a change at once."""
        if owed == STILL:
            return self.quiet_until
        return now if self.version > self._started else max(now, self.settle_from)

    @property
    def quiet_until(self) -> float:
        """When the still frame is due if nothing changes (s)."""
        return self.changed_at + self.still_delay_s

    def started(self, still: bool) -> int:
        """A frame of the current version started; returns its sample of the still (0 for an
        interactive frame)."""
        if still:
            if self._refining != self.version:
                self._refining = self.version
                self.refinement.restart()
            sample = self.refinement.start()
            if not self.refinement.owed:
                self._still = self.version
            self._settle_left = 0
            return sample
        if self._started == self.version:
            self._settle_left -= 1
        self._started = self.version
        return 0

    @property
    def still_plan(self) -> StillPlan:
        """How a still is sampled."""
        return self.refinement.plan

    @property
    def shown(self) -> bool:
        """A published frame showed the current version."""
        return self._published >= self.version

    @property
    def published_any(self) -> bool:
        """A frame of any version was published."""
        return self._published > 0

    def published(self, version: int) -> bool:
        """A frame of ``version`` was published; True when it is the first to show that version."""
        first = version > self._published
        self._published = max(self._published, version)
        return first
